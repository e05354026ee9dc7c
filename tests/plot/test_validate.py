"""``treesim validate``: a simulated plot scan against a "field" scan of the same plot.

The field scan is itself simulated, so the truth is known: two scans of one plot from one
set of stations that differ only in their noise seed must agree (same rays: density ratio
1, same coverage, distances at the noise level); a scan at twice the angular step casts a
quarter of the rays per solid angle (density ratio 1/4); a station moved by 3 m stands
3 m off and sees the plot from elsewhere (its range profile differs, the other's not).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from treesim.cli import main
from treesim.cloud import Cloud
from treesim.errors import InputFormatError, InvalidParameterError
from treesim.io import read_cloud, write_cloud
from treesim.params import ScanParams
from treesim.plot import Plot, PlotTree
from treesim.plot.scan import scan_plot
from treesim.plot.validate import VALIDATION_FILES, VERDICT, ValidateParams, validate_scans
from treesim.plot.validate_report import write_validation
from treesim.scan import ScannerSpec

NOISE_M = 0.002
STATIONS = [(0.0, -2.0, 1.5), (0.0, 2.0, 1.5)]
RES_DEG = 0.25


def _plot() -> Plot:
    pos = [(3.0, 0.0), (-3.0, 1.5), (0.5, 4.0)]
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i, rotation_deg=17.0 * i)
        for i, (x, y) in enumerate(pos)
    ]
    return Plot(trees, facets=8, radius_m=6.0)


def _scan(plot: Plot, res_deg: float, seed: int, stations=STATIONS) -> Cloud:
    spec = ScannerSpec(
        horizontal_resolution_deg=res_deg,
        vertical_resolution_deg=res_deg,
        range_noise_sd_m=NOISE_M,
        seed=seed,
    )
    return scan_plot(plot, stations, replace(ScanParams(), scanner=spec)).cloud


@pytest.fixture(scope="module")
def plot() -> Plot:
    return _plot()


@pytest.fixture(scope="module")
def field(plot) -> Cloud:
    return _scan(plot, RES_DEG, seed=1)


@pytest.fixture(scope="module")
def same(plot, field):
    return validate_scans(field, _scan(plot, RES_DEG, seed=2), plot=plot)


def test_two_noise_seeds_of_one_scan_agree(same):
    for g in ("0", "1"):
        assert same.density["per_station"][g]["density_ratio"] == pytest.approx(1.0, abs=0.02)
        assert same.density["per_station"][g]["range_profile_difference"] < 0.01
    assert same.groups == ["0", "1"]
    assert len(same.trees) == 3
    for t in same.trees:
        assert t["points_real"] > 500
        assert abs(t["coverage_difference_points"]) < 3.0
        assert 0.2 < t["coverage_real"] < 1.0
        # the assignment rule gives the simulated points to the tree that returned them
        assert t["assignment_agreement"] > 0.95
    # both ways at the noise level: |n1 - n2| has sd σ√2; p95 within 3σ√2, not zero
    for key in ("real_to_simulated", "simulated_to_real"):
        p95 = same.distances[key]["p95_m"]
        assert 0.0 < p95 < 3 * math.sqrt(2) * NOISE_M
    assert same.stations["offset_m"] == [0.0, 0.0]
    assert same.warnings == []
    assert same.summary.startswith("simulated scan reproduces the field scan: density ratio 1.00")


def test_the_occlusion_profile_agrees_band_by_band(same):
    prof = same.occlusion_profile
    for cr, cs, n in zip(
        prof["coverage_real"], prof["coverage_simulated"], prof["samples"], strict=True
    ):
        if n > 1000:
            assert abs(cr - cs) < 0.03


def test_twice_the_angular_step_records_a_quarter_of_the_points(plot, field):
    res = validate_scans(field, _scan(plot, 2 * RES_DEG, seed=2), plot=plot)
    # the oracle: rays per solid angle go with 1 / step², the same surfaces are hit
    for g in ("0", "1"):
        assert res.density["per_station"][g]["density_ratio"] == pytest.approx(0.25, abs=0.02)
    h = res.density_by_height["per_station"]["0"]
    for r, s in zip(h["real"], h["simulated"], strict=True):
        if r > 2000:
            assert s / r == pytest.approx(0.25, abs=0.05)
    assert all(t["coverage_difference_points"] < -10 for t in res.trees)
    assert res.summary.startswith("simulated scan does not reproduce")
    assert any("0.25 × the field's points" in w for w in res.warnings)


def test_a_station_moved_by_3_m_shows_in_its_range_profile(plot, field):
    moved = [STATIONS[0], (STATIONS[1][0] + 3.0, STATIONS[1][1], STATIONS[1][2])]
    res = validate_scans(field, _scan(plot, RES_DEG, seed=2, stations=moved), plot=plot)
    assert res.stations["offset_m"] == pytest.approx([0.0, 3.0], abs=1e-12)
    per = res.density["per_station"]
    assert per["0"]["range_profile_difference"] < 0.01
    assert per["1"]["range_profile_difference"] > 0.1
    assert any("station 1 stands 3.00 m" in w for w in res.warnings)


def test_a_field_cloud_without_stations_is_one_group(plot, field, tmp_path):
    merged = Cloud(field.points, {}, {})
    res = validate_scans(merged, field, plot=plot)
    assert res.groups == ["all"]
    assert any("no station field" in n for n in res.notes)
    assert res.density["density_ratio"] == pytest.approx(1.0)
    assert res.distances["real_to_simulated"]["max_m"] == 0.0  # the same points


def test_without_a_twin_the_coverage_is_left_out(field):
    # settings as ValidateParams and as keywords over it (the keyword wins)
    params = ValidateParams(height_bin_m=0.5, range_bin_m=3.0)
    res = validate_scans(field, field, params, range_bin_m=4.0)
    assert res.trees is None and res.occlusion_profile is None
    assert any("no twin given" in n for n in res.notes)
    assert res.density["density_ratio"] == 1.0
    assert np.diff(res.density_by_height["edges_m"]) == pytest.approx(0.5)
    assert np.diff(res.density_by_range["edges_m"]) == pytest.approx(4.0)
    assert res.parameters["range_bin_m"] == 4.0 and res.parameters["height_bin_m"] == 0.5
    assert res.verdict["criteria"]["coverage_points"]["passed"] is None  # no trees


def test_settings_out_of_range_name_themselves(field):
    with pytest.raises(InvalidParameterError, match=r"tau_m must be a number in \(0, 1\]"):
        ValidateParams(tau_m=0.0)
    with pytest.raises(InvalidParameterError, match="max_samples_per_tree"):
        ValidateParams(max_samples_per_tree=10)
    with pytest.raises(InvalidParameterError, match="height_bin_m"):
        validate_scans(field, field, height_bin_m=-1.0)
    with pytest.raises(InvalidParameterError, match="tau_m must be a number"):
        validate_scans(field, field, tau_m="fine")
    with pytest.raises(InvalidParameterError, match="unknown setting 'bins'"):
        validate_scans(field, field, bins=3)


def test_bad_inputs_say_what_is_wrong(plot, field):
    far = Cloud(field.points + (5000.0, 0.0, 0.0), dict(field.fields), dict(field.metadata))
    with pytest.raises(InputFormatError, match="5.0 km apart: different coordinate frames"):
        validate_scans(field, far)
    one = field.fields["station"] == 0
    single = Cloud(
        field.points[one],
        {"station": field.fields["station"][one]},
        {"stations": [list(STATIONS[0])]},
    )
    with pytest.raises(InputFormatError, match="field scan has 1 station and the simulated scan 2"):
        validate_scans(single, field, plot=plot)


def test_the_e57_path_keeps_each_scans_pose(plot, field, tmp_path):
    from treesim.io.e57 import available

    if not available():
        pytest.skip("pye57 is not installed: the E57 path is not tested")
    stations = [list(s) for s in STATIONS]
    path = tmp_path / "field.e57"
    write_cloud(
        path, Cloud(field.points, {"station": field.fields["station"]}, {"stations": stations})
    )
    real = read_cloud(path)
    res = validate_scans(real, field, plot=plot)
    assert res.stations["real_m"] == stations
    assert res.groups == ["0", "1"]
    assert res.density["density_ratio"] == pytest.approx(1.0)
    assert res.distances["real_to_simulated"]["p95_m"] < 1e-6


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A tiny twin and two coarse scans of it on disk."""
    from treesim.plot.io import write_plot

    d = tmp_path_factory.mktemp("validate")
    plot = _plot()
    write_plot(d / "plot.toml", plot)
    write_cloud(d / "field.laz", _scan(plot, 0.5, seed=1))
    write_cloud(d / "plot_scan.laz", _scan(plot, 0.5, seed=2))
    (d / "notes.txt").write_text("these are not points\n")
    return d


def test_the_command_writes_the_report(files, tmp_path, capsys):
    out = tmp_path / "v"
    argv = ["validate", str(files / "field.laz"), str(files / "plot_scan.laz")]
    assert main([*argv, "--plot", str(files / "plot.toml"), "--tau-mm", "20", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    text = captured.out
    assert "simulated scan reproduces the field scan" in text
    # the deprecated --tau-mm still works, and says what to give instead
    assert "--tau-mm is deprecated; give --tau-m 0.02" in captured.err
    for name in VALIDATION_FILES.values():
        assert (out / name).stat().st_size > 0, name
    data = json.loads((out / "validation.json").read_text())
    assert data["parameters"]["tau_m"] == 0.02
    assert data["verdict"]["reproduces"] is True and data["verdict"]["failed"] == []
    assert data["verdict_bounds"]["stem_coverage_points"] == VERDICT["stem_coverage_points"]
    assert all(t["stem"]["samples"] > 0 for t in data["trees"])
    assert data["stations"]["simulated_m"] == [list(s) for s in STATIONS]
    html = (out / "validation.html").read_text()
    assert html.count("data:image/png;base64,") == 5
    # --tau-m gives the same setting the deprecated --tau-mm gave
    from treesim.cli import build_parser
    from treesim.cli._options import collect

    args = build_parser().parse_args([*argv, "--tau-m", "0.02", "--seed", "3", "-o", "x"])
    assert collect(args) == {"tau_m": 0.02, "seed": 3} and args.tau_from_mm is None
    # without the twin: no coverage figures, and why
    out2 = tmp_path / "v2"
    assert main([*argv, "-o", str(out2)]) == 0
    assert "no twin given" in capsys.readouterr().out
    assert not (out2 / VALIDATION_FILES["coverage_by_tree"]).exists()
    assert (out2 / VALIDATION_FILES["html"]).exists()


def test_the_command_refuses_bad_input_in_one_line(files, tmp_path, capsys):
    out = str(tmp_path / "v")
    assert main(["validate", str(files / "notes.txt"), str(files / "field.laz"), "-o", out]) == 1
    err = capsys.readouterr().err
    assert err.startswith("treesim: error: ") and "Traceback" not in err
    assert "field scan" in err
    assert main(["validate", str(files / "field.laz"), "missing.laz", "-o", out]) == 1
    assert "does not exist" in capsys.readouterr().err
    csv = files / "stations.csv"
    csv.write_text("x_m,y_m\n0,-2\n")
    argv = ["validate", str(files / "field.laz"), str(files / "plot_scan.laz")]
    assert main([*argv, "--stations-from", str(csv), "-o", out]) == 1
    assert "needs a z_m column" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # a usage error
        main([*argv, "--tau-mm", "0", "-o", out])
    assert exc.value.code == 2
    assert "--tau-mm: expected a number in (0, 1000] (mm), got '0'" in capsys.readouterr().err
    for bad in ("0", "2", "nan"):  # the range ValidateParams declares: (0, 1] m
        with pytest.raises(SystemExit) as exc:
            main([*argv, "--tau-m", bad, "-o", out])
        assert exc.value.code == 2
        assert "--tau-m: expected a number in (0, 1]" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # one τ, not two
        main([*argv, "--tau-m", "0.02", "--tau-mm", "20", "-o", out])
    assert "not allowed with argument" in capsys.readouterr().err


def test_the_writers_draw_without_a_range_profile(field, tmp_path):
    res = validate_scans(Cloud(field.points, {}, {}), field)
    assert res.density_by_range is not None  # the simulated cloud's stations stand in
    res.density_by_range = None
    names = {p.name for p in write_validation(res, tmp_path)}
    assert VALIDATION_FILES["density_by_range"] not in names
    assert VALIDATION_FILES["html"] in names


# -- stem and crown ----------------------------------------------------------------------
def test_a_scan_against_itself_agrees_on_stem_and_crown(plot, field):
    """The same points on both sides: every part's coverage is the same, exactly; the
    stem's area is its cylinders' side area (the generator's table, 8-sided tubes)."""
    from treesim.models import generate_tree, species_preset

    res = validate_scans(field, field, plot=plot)
    facets = 8 * math.sin(math.pi / 8) / math.pi  # an octagon's perimeter over the circle's
    for t, i in zip(res.trees, range(3), strict=True):
        for part in ("stem", "crown"):
            assert t[part]["coverage_difference_points"] == 0.0
            assert t[part]["coverage_real"] == t[part]["coverage_simulated"]
        assert t["stem"]["samples"] + t["crown"]["samples"] == t["samples"]
        assert 0.0 < t["stem"]["coverage_real"] < 1.0
        table = generate_tree(species_preset("sapling"), seed=i).cylinders
        stem = table.branch_order == 0
        side = np.sum(math.pi * (table.radius_m + table.end_radius_m)[stem] * table.length_m[stem])
        assert t["stem"]["area_m2"] == pytest.approx(facets * side, rel=0.06)
    prof = res.occlusion_profile
    assert sum(prof["stem"]["samples"]) == sum(t["stem"]["samples"] for t in res.trees)
    assert res.verdict["failed"] == [] and res.verdict["parts"].startswith("stems reproduce")


@pytest.fixture(scope="module")
def moved_crowns(tmp_path_factory):
    """The test plot's trees as cylinder tables (a twin's QSMs), and the same tables with
    every non-stem cylinder moved 1 m east: the 'field' the twin got the crowns wrong of."""
    from treesim.models import generate_tree, species_preset, write_cylinders

    d = tmp_path_factory.mktemp("crowns")
    twin, field = [], []
    for t in _plot().trees:
        table = generate_tree(species_preset("sapling"), seed=t.seed).cylinders
        crown = (table.branch_order > 0)[:, None]
        moved = replace(table, start=table.start + np.where(crown, (1.0, 0.0, 0.0), 0.0))
        paths = (
            write_cylinders(d / f"t{t.tree_id}.csv", table),
            write_cylinders(d / f"m{t.tree_id}.csv", moved),
        )
        for out, path in zip((twin, field), paths, strict=True):
            out.append(replace(t, source="qsm", species=None, path=str(path)))
    return Plot(twin, facets=8, radius_m=6.0), Plot(field, facets=8, radius_m=6.0)


def test_a_twin_with_its_crowns_1_m_off_reproduces_its_stems_only(moved_crowns):
    twin, truth = moved_crowns
    # coarse scans and τ 2 cm (the 8-sided tubes' stems are 3 cm thick): a few seconds
    field, sim = _scan(truth, 2 * RES_DEG, seed=1), _scan(twin, 2 * RES_DEG, seed=2)
    res = validate_scans(field, sim, plot=twin, tau_m=0.02)
    for t in res.trees:
        assert abs(t["stem"]["coverage_difference_points"]) < 5.0, t
        assert t["stem"]["coverage_real"] > 0.2
        # the field's crowns are 1 m away from the twin's: hardly a twin crown sample is
        # within τ of a field point, while the twin's own scan covers them
        assert t["crown"]["coverage_real"] < 0.1
        assert t["crown"]["coverage_difference_points"] > 20.0
    v = res.verdict
    assert "coverage_points" in v["failed"] and "stem_coverage_points" not in v["failed"]
    assert v["criteria"]["stem_coverage_points"]["passed"] is True
    assert v["parts"].startswith("stems reproduce") and "crowns do not" in v["parts"]
    assert "(failed: coverage_points)" in res.summary
    for band_r, band_s, n in zip(
        res.occlusion_profile["stem"]["coverage_real"],
        res.occlusion_profile["stem"]["coverage_simulated"],
        res.occlusion_profile["stem"]["samples"],
        strict=True,
    ):
        if n > 500:
            assert abs(band_r - band_s) < 0.1


def test_a_mesh_tree_has_no_parts(plot, tmp_path):
    from treesim.io import write_mesh
    from treesim.models import generate_tree, species_preset

    made = generate_tree(species_preset("sapling"), seed=0)
    v, f, lab = made.mesh(8)
    path = write_mesh(tmp_path / "tree.ply", v, f, face_label=lab)
    mesh_plot = Plot([PlotTree(tree_id=1, x_m=3.0, y_m=0.0, source="mesh", path=str(path))])
    scan = _scan(mesh_plot, 0.5, seed=1, stations=STATIONS[:1])
    res = validate_scans(scan, scan, plot=mesh_plot)
    (t,) = res.trees
    assert t["stem"] is None and t["crown"] is None
    assert t["coverage_difference_points"] == 0.0
    assert res.occlusion_profile["stem"] is None
    assert res.verdict["criteria"]["stem_coverage_points"]["passed"] is None
    assert res.verdict["parts"] is None
    assert any("no twin tree has a cylinder table" in n for n in res.notes)
    names = {p.name for p in write_validation(res, tmp_path / "v")}
    assert VALIDATION_FILES["coverage_by_tree"] in names
