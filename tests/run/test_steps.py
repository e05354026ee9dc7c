"""The single stages on files (``treesim.steps``), with known answers: a tube's QSM has the
tube's diameter; a box scanned from one station gives points on the box's faces and a JSON
beside the cloud; a cloud taken from a mesh compared with that mesh is at distance zero;
progress rises to 1.0; the same results as the stage functions called directly."""

from __future__ import annotations

import json

import numpy as np
import pytest

from treesim.cloud import Cloud
from treesim.errors import InputFormatError, InvalidParameterError
from treesim.io import read_cloud, write_cloud, write_mesh
from treesim.params import CompareParams, ReconstructParams, ReportParams, ScanParams, merge
from treesim.steps import compare_files, reconstruct_files, scan_files

from ..reconstruct.shapes import GEO, tube


def _recorder():
    seen: list[tuple[float, str]] = []
    return seen, lambda f, m: seen.append((f, m))


def _rises_to_one(seen) -> None:
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and seen[-1][1] == "done"


def test_reconstruct_files_writes_the_tree_and_matches_the_library(tmp_path):
    from treesim.reconstruct import reconstruct

    pts, _ = tube(radius=0.15, height=2.0, n=20000, seed=1)
    src = write_cloud(tmp_path / "tube.ply", Cloud(pts + GEO))
    seen, progress = _recorder()
    step = reconstruct_files(src, ReconstructParams(), tmp_path / "out", progress=progress)
    assert {p.name for p in step.outputs.values()} == {"tree.ply", "cylinders.csv", "tree.json"}
    assert all(p.is_file() for p in step.outputs.values())
    assert step.summary["dbh_m"] == pytest.approx(0.30, abs=0.01)
    on_disk = json.loads((tmp_path / "out" / "tree.json").read_text())
    assert on_disk["dbh_m"] == step.summary["dbh_m"]
    direct = reconstruct(read_cloud(src), ReconstructParams())
    assert direct.figures["dbh_m"] == step.summary["dbh_m"]
    assert direct.figures["n_cylinders"] == step.summary["n_cylinders"]
    _rises_to_one(seen)
    with pytest.raises(InputFormatError, match="not found"):
        reconstruct_files(tmp_path / "missing.laz", None, tmp_path / "x")


@pytest.fixture
def box(tmp_path):
    import trimesh

    m = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    v = np.asarray(m.vertices, dtype=np.float64) + GEO + [0, 0, 1.0]
    return write_mesh(tmp_path / "box.ply", v, np.asarray(m.faces)), v


def test_scan_files_puts_points_on_the_box(tmp_path, box):
    path, v = box
    params = merge(
        ScanParams(),
        {"scanner": {"horizontal_resolution_deg": 0.5, "vertical_resolution_deg": 0.5}},
    )
    station = GEO + [6.0, 0.0, 1.5]
    seen, progress = _recorder()
    step = scan_files([path], params, tmp_path / "scan.laz", stations=[station], progress=progress)
    pts = read_cloud(step.outputs["cloud"]).points
    assert len(pts) == step.summary["points"] > 100
    # every point on the face x = +1 that faces the station (LAS keeps 0.1 mm)
    assert np.abs(pts[:, 0] - (GEO[0] + 1.0)).max() < 1e-4
    assert np.all(np.abs(pts[:, 1:] - (GEO[1:] + [0, 1.0])) <= 1.0 + 1e-4)
    side = json.loads((tmp_path / "scan.json").read_text())
    assert side["points"] == len(pts) and len(side["stations"]) == 1
    np.testing.assert_allclose(side["stations"][0]["position_m"], station)
    _rises_to_one(seen)
    with pytest.raises(InvalidParameterError, match="by suffix"):
        scan_files([path], params, tmp_path / "scan.e57", stations=[station])


def test_scan_files_places_a_ring_without_stations(tmp_path, box):
    path, _ = box
    params = merge(
        ScanParams(),
        {"n_stations": 3, "scanner": {"horizontal_resolution_deg": 1.0,
                                      "vertical_resolution_deg": 1.0}},
    )  # fmt: skip
    step = scan_files([path], params, tmp_path / "ring.ply")
    assert len(step.summary["stations"]) == 3 and "station_rule" in step.summary


@pytest.mark.parametrize("suffix", [".laz", ".ply", ".xyz"])
def test_scan_files_streams_what_the_scanner_makes(tmp_path, box, suffix):
    # the cloud is written chunk by chunk while it is cast: what is read back is the
    # in-memory scan of the same scene, whatever the chunk size
    from treesim.scan import Station, load_scene, scan

    path, _ = box
    params = merge(
        ScanParams(),
        {"chunk_rays": 777, "scanner": {"horizontal_resolution_deg": 0.4,
                                        "vertical_resolution_deg": 0.4}},
    )  # fmt: skip
    stations = [GEO + [6.0, 0.0, 1.5], GEO + [-5.0, 3.0, 0.5]]
    step = scan_files([path], params, tmp_path / f"scan{suffix}", stations=stations)
    back = read_cloud(step.outputs["cloud"])
    ref = scan(
        load_scene([path]), [Station(position_m=tuple(s)) for s in stations], params.scanner
    ).cloud
    assert len(back) == len(ref) == step.summary["points"] > 1000
    tol = {".laz": 0.5e-4 + 1e-9, ".ply": 0.0, ".xyz": 1e-6}[suffix]
    np.testing.assert_allclose(back.points, ref.points, atol=tol, rtol=0)
    for name in ("station", "scan_line", "scan_column", "return_number", "label"):
        np.testing.assert_array_equal(back.fields[name], ref.fields[name], err_msg=name)


def test_scan_files_of_nothing_in_range_writes_an_empty_cloud(tmp_path, box):
    path, _ = box
    params = merge(
        ScanParams(),
        {
            "scanner": {
                "max_range_m": 3.0,
                "horizontal_resolution_deg": 1.0,
                "vertical_resolution_deg": 1.0,
            }
        },
    )
    step = scan_files([path], params, tmp_path / "none.laz", stations=[GEO + [50.0, 0, 1]])
    assert step.summary["points"] == 0 and step.summary["lod"]["geometry"]["loaded"] == 0
    assert len(read_cloud(step.outputs["cloud"])) == 0


def test_compare_files_of_a_cloud_on_the_mesh(tmp_path, box):
    path, v = box
    rng = np.random.default_rng(4)
    # points on the top face (z = max), exactly
    top = v[:, 2].max()
    xy = rng.uniform(v[:, :2].min(0), v[:, :2].max(0), (3000, 2))
    cloud = write_cloud(tmp_path / "top.ply", Cloud(np.c_[xy, np.full(len(xy), top)]))
    seen, progress = _recorder()
    step = compare_files(cloud, path, CompareParams(), tmp_path / "cmp", progress=progress)
    assert step.summary["accuracy"]["max_m"] < 1e-9
    assert step.summary["reference_kind"] == "mesh"
    assert (tmp_path / "cmp" / "comparison.json").is_file()
    assert not (tmp_path / "cmp" / "report.html").exists()
    # one face of six is covered: coverage about a sixth
    assert step.summary["coverage"] == pytest.approx(1 / 6, abs=0.03)
    _rises_to_one(seen)
    with_report = compare_files(
        cloud, path, CompareParams(), tmp_path / "rep", report=ReportParams()
    )
    assert with_report.outputs["report"].name == "report.html"
    assert with_report.outputs["report"].is_file()
