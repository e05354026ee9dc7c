"""``run_tree``: every artefact, run.json's names, the station rule, and the parameters
(presets, TOML, flat settings, the hash)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import pytest

from tests.run.conftest import (
    PINNED_DBH_ROUNDING_M,
    README_DBH_ROUNDING_M,
    README_SAPLING_DBH_M,
    SAPLING0_DRAFT_DBH_M,
    sapling_cloud,
)
from treesim.errors import InputFormatError, InvalidParameterError
from treesim.models import generate_tree
from treesim.params import RUN_PRESETS as PRESETS
from treesim.params import (
    RunParams,
    apply_settings,
    load_config,
    params_hash,
    to_toml,
)
from treesim.params import run_preset as preset
from treesim.run import STAGES, run_tree
from treesim.scan import station_distance_m

ARTEFACTS = (
    "tree.ply",
    "cylinders.csv",
    "tree.json",
    "scan.laz",
    "scan.json",
    "vs_mesh/comparison.json",
    "vs_mesh/report.html",
    "vs_mesh/cloud_distances.laz",
    "vs_mesh/reference_distances.laz",
    "vs_field/comparison.json",
    "vs_field/report.html",
    "report.html",
    "run.json",
)


@pytest.fixture(scope="module")
def sapling_run(saplings, sapling0_qsm, quick, tmp_path_factory):
    """The one run of these tests that draws its plots (small ones)."""
    out = tmp_path_factory.mktemp("run") / "sapling"
    seen = []
    drawn = replace(quick, report=replace(quick.report, plots=True, dpi=50, max_plot_points=5000))
    result = run_tree(
        saplings["sapling0"],
        drawn,
        out,
        reference_qsm=sapling0_qsm,
        progress=lambda f, m: seen.append(f),
    )
    return result, seen


def test_run_tree_writes_every_artefact(sapling_run):
    result, seen = sapling_run
    for name in ARTEFACTS:
        assert (result.outdir / name).is_file(), name
    assert result.report_html == result.outdir / "report.html"
    assert seen[0] == 0.0 and seen[-1] == 1.0
    assert all(b >= a for a, b in zip(seen, seen[1:], strict=False))


def test_run_json_uses_the_names_of_tree_json_and_comparison_json(sapling_run):
    result, _ = sapling_run
    run = json.loads(result.run_json.read_text())
    assert run == result.summary
    assert {"parameters", "software", "timings_s", "reconstruction", "vs_mesh", "vs_field"} <= set(
        run
    )
    assert set(STAGES) | {"total"} == set(run["timings_s"])
    assert all(v >= 0 for v in run["timings_s"].values())
    assert run["parameters"] == result.summary["parameters"]
    assert run["parameters"]["preset"] == "draft"
    assert {"treesim", "numpy", "open3d", "pymeshlab"} <= set(run["software"])
    tree = json.loads((result.outdir / "tree.json").read_text())
    for key, value in run["reconstruction"].items():
        assert key in tree, key
        assert tree[key] == value, key
    for key in ("vs_mesh", "vs_field"):
        comp = json.loads((result.outdir / key / "comparison.json").read_text())
        assert run[key], key
        for name, value in run[key].items():
            assert comp[name] == value, (key, name)
        assert {"accuracy", "completeness", "coverage", "chamfer_m", "hausdorff_m"} <= set(run[key])


def test_the_simulated_cloud_lies_on_the_mesh_and_near_the_field_cloud(sapling_run):
    result, _ = sapling_run
    vs_mesh, vs_field = result.vs_mesh, result.vs_field
    # every hit is on the scanned mesh (the scanner refines hits onto the hit triangle's
    # plane; at a triangle's edge a grazing hit can sit a few µm beyond it)
    assert vs_mesh["accuracy"]["p99_m"] < 1e-6
    assert vs_mesh["accuracy"]["max_m"] < 1e-4
    assert vs_mesh["coverage"] > 0.5
    assert vs_mesh["by_station"].keys() == {"0", "1", "2"}
    assert vs_mesh["reference"]["kind"] == "mesh"
    assert vs_field["reference"]["kind"] == "cloud"
    assert vs_field["accuracy"]["p95_m"] < 0.02  # a sapling modelled within 2 cm
    rec = result.reconstruction
    # deterministic: the draft preset's DBH on this fixture, to its pinned 0.01 mm
    assert rec["dbh_m"] == pytest.approx(SAPLING0_DRAFT_DBH_M, abs=PINNED_DBH_ROUNDING_M)


def test_the_sapling_truth_is_the_readme_figure():
    tree, _ = sapling_cloud(0)
    assert tree.truth(16)["dbh_m"] == pytest.approx(README_SAPLING_DBH_M, abs=README_DBH_ROUNDING_M)


def test_stations_follow_the_size_rule(sapling_run):
    result, _ = sapling_run
    rule = result.summary["scan"]["station_rule"]
    expected = max(5.0, 1.5 * rule["crown_diameter_m"], 0.5 * rule["height_m"])
    assert rule["distance_m"] == pytest.approx(expected)
    stations = result.summary["scan"]["stations"]
    assert len(stations) == 3
    xy = [s["position_m"][:2] for s in stations]
    d = [math.dist(a, b) for a, b in zip(xy, xy[1:] + xy[:1], strict=True)]
    assert d == pytest.approx([math.sqrt(3) * expected] * 3)  # 120° apart on the ring


def test_run_page_presents_both_comparisons(sapling_run):
    result, _ = sapling_run
    page = result.report_html.read_text()
    for link in ("vs_mesh/report.html", "vs_field/report.html", "run.json", "tree.ply"):
        assert f'href="{link}"' in page
    assert 'src="http' not in page and 'href="http' not in page  # works offline


def test_one_tolerance_from_the_field_cloud_serves_both_comparisons(sapling_run, saplings):
    from treesim.frame import LocalFrame
    from treesim.geometry import point_spacing
    from treesim.io import read_cloud

    result, _ = sapling_run
    field = read_cloud(saplings["sapling0"]).points
    spacing = point_spacing(LocalFrame.around(field).to_local(field), subsample=50_000, seed=0)
    tol = result.summary["tolerance"]
    assert tol["tolerance_m"] == pytest.approx(3.0 * spacing, rel=1e-12)
    assert tol["field_point_spacing_m"] == pytest.approx(spacing, rel=1e-12)
    for key in ("vs_mesh", "vs_field"):
        assert result.summary[key]["tolerance_m"] == tol["tolerance_m"], key
        rep = json.loads((result.outdir / key / "report.json").read_text())
        assert rep["figures"]["tolerance_m"] == tol["tolerance_m"]
        assert "field cloud's median point spacing" in rep["parameters"]["tolerance_rule"]
    # not the simulated cloud's spacing, which the stand-alone comparison would use
    assert result.vs_mesh["point_spacing_m"] * 3.0 != pytest.approx(tol["tolerance_m"], rel=0.05)


def test_a_reference_qsm_is_set_beside_the_reconstruction(sapling_run, sapling0_qsm):
    result, _ = sapling_run
    ref = result.summary["reference_qsm"]
    truth = generate_tree("sapling", seed=0, leaves=False).cylinders.summary()
    assert ref["figures"]["dbh_m"] == pytest.approx(README_SAPLING_DBH_M, abs=README_DBH_ROUNDING_M)
    for key in ("dbh_m", "height_m", "volume_total_m3", "volume_stem_m3", "n_cylinders"):
        assert ref["figures"][key] == truth[key], key
        assert ref["difference"][key] == pytest.approx(result.reconstruction[key] - truth[key])
    assert ref["relative"]["volume_total_m3"] == pytest.approx(
        result.reconstruction["volume_total_m3"] / truth["volume_total_m3"] - 1.0
    )
    assert not Path(ref["path"]).is_absolute()
    assert (result.outdir / ref["path"]).resolve() == sapling0_qsm.resolve()
    page = result.report_html.read_text()
    assert "Reconstruction vs the reference QSM" in page
    assert f"{truth['dbh_m'] * 100:.3g} cm" in page  # the reference's DBH, in the table


def test_a_bad_reference_qsm_fails_before_the_run(saplings, quick, tmp_path):
    bad = tmp_path / "qsm.csv"
    bad.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(InputFormatError, match="matches no known cylinder table"):
        run_tree(saplings["sapling0"], quick, tmp_path / "out", reference_qsm=bad)
    assert not (tmp_path / "out" / "tree.ply").exists()


def test_station_distance_rule():
    assert station_distance_m(1.0, 4.0) == 5.0
    assert station_distance_m(6.0, 10.0) == 9.0
    assert station_distance_m(2.0, 30.0) == 15.0
    assert station_distance_m(1.0, 2.0, min_distance_m=2.0) == 2.0


def test_run_tree_refuses_a_missing_file(tmp_path, quick):
    with pytest.raises(InputFormatError, match="not found"):
        run_tree(tmp_path / "nope.laz", quick, tmp_path / "out")


# -- parameters ------------------------------------------------------------------------
def test_presets_grow_finer():
    d, s, f = PRESETS["draft"], PRESETS["standard"], PRESETS["fine"]
    res = [p.scan.scanner.horizontal_resolution_deg for p in (d, s, f)]
    assert res == sorted(res, reverse=True)
    assert d.reconstruct.facets < s.reconstruct.facets < f.reconstruct.facets
    assert preset("standard") == s
    with pytest.raises(InvalidParameterError, match="draft, standard, fine"):
        preset("ultra")


def test_toml_round_trip(tmp_path):
    for name, p in PRESETS.items():
        cfg = tmp_path / f"{name}.toml"
        cfg.write_text(to_toml(p))
        assert load_config(cfg) == p


def test_config_overrides_its_preset(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        'preset = "draft"\n[reconstruct]\nmethod = "poisson"\n'
        "[scan]\nn_stations = 4\ndistance_m = 7.5\n[scan.scanner]\n"
        "horizontal_resolution_deg = 0.3\nvertical_fov_deg = [-30, 80]\n"
        '[reconstruct.prepare]\nvoxel_size_m = "none"\n'
    )
    p = load_config(cfg)
    assert p.preset == "draft"
    assert p.reconstruct.method == "poisson"
    assert p.reconstruct.facets == PRESETS["draft"].reconstruct.facets
    assert p.reconstruct.prepare.voxel_size_m is None
    assert (p.scan.n_stations, p.scan.distance_m) == (4, 7.5)
    assert p.scan.scanner.horizontal_resolution_deg == 0.3
    assert p.scan.scanner.vertical_fov_deg == (-30, 80)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[scan]\nstations = 3\n", "unknown setting 'stations' in \\[scan\\]"),
        ("[scan]\nn_stations = 0\n", "n_stations must be a whole number in \\[1, 64\\]"),
        ("[scan]\nn_stations = 'three'\n", "must be a number"),
        ("[scan]\nn_stations = 2.5\n", "n_stations must be a whole number in \\[1, 64\\], got 2.5"),
        ("[scan]\nn_stations = inf\n", "n_stations must be a whole number in \\[1, 64\\], got inf"),
        ("[scan]\nmax_rays = nan\n", "max_rays must be a whole number >= 1, got nan"),
        ("[scan.scanner]\nhorizontal_resolution_deg = -1\n", "must be a number in \\(0, 45\\]"),
        ("scan = 3\n", "must be a table"),
        ('preset = "ultra"\n', "unknown preset"),
        ("[scan\n", "not valid TOML"),
    ],
)
def test_bad_configs_say_what_is_wrong(tmp_path, text, match):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    with pytest.raises((InvalidParameterError, InputFormatError), match=match):
        load_config(cfg)


def test_flat_settings_map_to_nested_fields():
    p = apply_settings(
        preset("standard"),
        {"method": "bpa", "resolution_deg": "0.1", "stations": "5", "voxel_m": "0", "facets": 8},
    )
    assert p.reconstruct.method == "bpa"
    assert p.scan.scanner.horizontal_resolution_deg == p.scan.scanner.vertical_resolution_deg == 0.1
    assert p.scan.n_stations == 5
    assert p.reconstruct.prepare.voxel_size_m is None
    assert p.reconstruct.facets == 8
    with pytest.raises(InvalidParameterError, match="unknown setting 'colour'"):
        apply_settings(p, {"colour": "red"})
    with pytest.raises(InvalidParameterError, match="row 3: stations: cannot read"):
        apply_settings(p, {"stations": "many"}, where="row 3: ")


def test_the_hash_covers_results_not_threads():
    p = preset("draft")
    assert params_hash(p) == params_hash(p.with_threads(7))
    assert params_hash(p) == params_hash(replace(p, preset="renamed"))
    assert params_hash(p) != params_hash(apply_settings(p, {"resolution_deg": 0.2}))
    assert params_hash(p) != params_hash(apply_settings(p, {"method": "poisson"}))
    with pytest.raises(InvalidParameterError):
        RunParams(threads=-1)


def test_params_are_frozen():
    p = preset("draft")
    with pytest.raises(AttributeError):
        p.threads = 3  # type: ignore[misc]


def test_lod_auto_scans_a_qsm_mesh_with_facets_from_the_projected_size(sapling_run):
    # the run's QSM mesh for the scan: no more facets than the scanner resolves at the
    # nearest station (and never more than asked for); run.json and the page say why
    result, _ = sapling_run
    run = json.loads(result.run_json.read_text())
    lod = run["scan"]["lod"]
    assert lod["mode"] == "auto" and "why" in lod["rays"] and "why" in lod["geometry"]
    facets = lod["facets"]
    asked = run["parameters"]["reconstruct"]["facets"]
    counts = [int(k) for k in facets["facets_histogram"]]
    assert min(counts) >= 8 and max(counts) <= asked
    assert facets["max_sagitta_over_spacing"] <= 0.1 + 1e-9
    assert facets["n_triangles"] < facets["n_triangles_uniform"]
    scan = json.loads((result.outdir / "scan.json").read_text())
    assert scan["mesh"] == "scan_mesh.ply" and (result.outdir / "scan_mesh.ply").is_file()
    assert scan["triangles"] == facets["n_triangles"]
    assert facets["joints"] == "miter"
    # the scanned mesh is the reconstruction's tubes: its closed parts are those the
    # comparison with the mesh found, and it left out what lies inside them
    hidden = run["vs_mesh"]["reference"]["hidden_surface"]
    assert hidden["parts"] == hidden["closed_parts"] == run["reconstruction"]["n_tubes"]
    assert 0 < hidden["area_share"] < 0.1
    page = result.report_html.read_text()
    assert "level of detail: facets" in page and "level of detail: rays" in page


def test_trivially_exact_comparisons_say_so(sapling_run):
    result, _ = sapling_run
    mesh = json.loads((result.outdir / "vs_mesh" / "report.json").read_text())
    field = json.loads((result.outdir / "vs_field" / "report.json").read_text())
    # a scan without noise against its own mesh is exact by construction; against the
    # field cloud it is not
    assert len(mesh["notes"]) == 1 and "trivially exact" in mesh["notes"][0]
    assert "scan without noise models against the mesh it was scanned from" in mesh["notes"][0]
    assert field["notes"] == []
    assert 'id="exact-note"' in (result.outdir / "vs_mesh" / "report.html").read_text()
    assert 'id="exact-note"' not in (result.outdir / "vs_field" / "report.html").read_text()


def test_field_and_simulated_clouds_side_by_side(sapling_run, saplings):
    from treesim.io import read_cloud

    result, _ = sapling_run
    c = result.summary["clouds"]
    field = read_cloud(saplings["sapling0"])
    assert c["field"]["points"] == len(field)
    assert c["simulated"]["points"] == result.summary["scan"]["points"]
    assert c["simulated"]["point_spacing_m"] == result.vs_mesh["point_spacing_m"]
    area = result.vs_mesh["reference"]["area_m2"]
    assert c["mesh_area_m2"] == area
    assert c["field"]["points_per_m2"] == pytest.approx(len(field) / area)
    assert (result.outdir / "clouds.png").read_bytes().startswith(b"\x89PNG")
    page = result.report_html.read_text()
    assert "Field and simulated clouds" in page and 'src="clouds.png"' in page
    assert f"{len(field):,}" in page
    assert page.count("Trivially exact") == 1  # vs mesh only


def test_a_moved_output_folder_works_and_its_figures_can_be_recomputed(sapling_run, tmp_path):
    import re
    import shutil

    from treesim.compare import compare
    from treesim.io import read_cloud, read_reference
    from treesim.params import CompareParams
    from treesim.report import ReportParams, build_report

    result, _ = sapling_run
    moved = tmp_path / "elsewhere" / "run"
    shutil.copytree(result.outdir, moved)
    # every link and image of every page resolves inside the moved folder
    for page in (moved / "report.html", moved / "vs_mesh/report.html"):
        refs = re.findall(r'(?:href|src)="([^"#]+)', page.read_text())
        refs = [r for r in refs if not r.startswith("data:")]
        assert refs or page.parent != moved  # the run page links its files, a report inlines
        for ref in refs:
            target = (page.parent / ref).resolve()
            assert target.is_file() and moved.resolve() in target.parents, ref
    # inputs outside the folder are named relative to it, and identified by content
    run = json.loads((moved / "run.json").read_text())
    assert not Path(run["inputs"]["cloud"]).is_absolute()
    assert (result.outdir / run["inputs"]["cloud"]).is_file()
    field_in = json.loads((moved / "vs_field/comparison.json").read_text())["inputs"]
    assert (result.outdir / "vs_field" / field_in["reference"]).is_file()
    assert field_in["reference_sha256"] == run["inputs"]["sha256"]
    # the comparison again, from the moved float64 scan and mesh: the same figures
    comp = json.loads((moved / "vs_mesh/comparison.json").read_text())
    rep = json.loads((moved / "vs_mesh/report.json").read_text())
    par = comp["parameters"]
    keep = ("tolerance_m", "seed", "min_samples", "max_samples", "spacing_subsample")
    again = compare(
        read_cloud(moved / "vs_mesh" / comp["inputs"]["cloud"]),
        read_reference(moved / "vs_mesh" / comp["inputs"]["reference"])[0],
        params=CompareParams(**{k: par[k] for k in keep}),
    )
    assert again.accuracy.to_dict() == rep["figures"]["accuracy"]
    assert again.completeness.to_dict() == rep["figures"]["completeness"]
    assert again.coverage == rep["figures"]["coverage"]
    assert {str(k): v for k, v in again.by_station.items()} == rep["figures"]["by_station"]
    # the report drawn again from the moved files has the same occlusion profile
    drawn = ReportParams(**run["parameters"]["report"])
    files = build_report(moved / "vs_mesh", tmp_path / "again", params=drawn)
    assert (
        json.loads(files["report_json"].read_text())["occlusion_profile"]
        == (rep["occlusion_profile"])
    )


def test_a_run_without_plots_links_no_missing_image(saplings, quick, tmp_path):
    """report.plots = false: the run page says the views were not drawn instead of
    showing images that were never written."""
    import re

    result = run_tree(saplings["sapling1"], quick, tmp_path / "run")
    assert not list(result.outdir.rglob("*.png"))
    page = result.report_html.read_text()
    refs = [r for r in re.findall(r'(?:href|src)="([^"#]+)', page) if not r.startswith("data:")]
    assert refs
    for ref in refs:
        assert (result.outdir / ref).is_file(), ref


def test_the_run_page_has_a_3d_view_that_draws_in_chromium(sapling_run):
    from tests.report.browser import open_page

    result, _ = sapling_run
    html = result.report_html.read_text()
    data = json.loads(html.split('id="viewer-data">')[1].split("</script>")[0])
    assert [d["key"] for d in data["datasets"]] == ["sim_vs_field", "field_vs_sim", "mesh_vs_sim"]
    assert f"of {result.summary['scan']['points']:,} points" in data["datasets"][0]["caption"]
    page = open_page(result.report_html)
    assert page["errors"] == "0", page["console"]
    assert page["viewer"] == "ready" and page["drawn"] > 500
    assert page["images_ok"] and page["console"] == [] and page["outside"] == []


def test_lod_scan_keeps_the_models_leaf_layer():
    """Under lod auto the run scans the QSM tubes remeshed with fewer facets; a leaf layer
    beside them (a leaf-on reconstruction) must be scanned too, not dropped."""
    from types import SimpleNamespace

    import numpy as np

    from treesim.cloud import LABEL_CODES
    from treesim.models import generate_tree
    from treesim.params import run_preset
    from treesim.run import _lod_scene
    from treesim.scan import Station

    tree = generate_tree("sapling", seed=0, leaves=False)
    wood_v, wood_f, _ = tree.mesh(32)
    leaf_v = np.array([[0.0, 0.0, 3.0], [0.05, 0.0, 3.0], [0.05, 0.05, 3.0], [0.0, 0.05, 3.0]])
    leaf_f = np.array([[0, 1, 2], [0, 2, 3]]) + len(wood_v)
    model = SimpleNamespace(
        cylinders=tree.cylinders,
        vertices=np.concatenate([wood_v, leaf_v]),
        faces=np.concatenate([wood_f, leaf_f]),
        face_label=np.concatenate(
            [
                np.full(len(wood_f), LABEL_CODES["wood"], np.uint8),
                np.full(2, LABEL_CODES["leaf"], np.uint8),
            ]
        ),
    )
    far = [Station(position_m=(40.0, 0.0, 1.5))]  # far: the tubes get fewer facets
    scene, info = _lod_scene(model, far, run_preset("draft"))
    labels = {p.label: len(p.faces) for p in scene.parts}
    assert labels["leaf"] == 2
    assert labels["wood"] < len(wood_f)  # the wood was remeshed coarser
    assert "why" in info
    # the scanned mesh (written as scan_mesh.ply) holds no vertex of the full-detail wood:
    # every vertex its parts share is used by one of them
    used = np.unique(np.concatenate([p.faces.ravel() for p in scene.parts]))
    assert len(used) == len(scene.parts[0].vertices)
