"""``treesim plot from-cloud`` on a small generated plot: the twin's files, reuse, and
bad input (no ground, feet, a projected offset, a single tree), each a clear message or
a correct result. (The 30-tree acceptance plot is ``test_twin.py``; the two files run on
separate test workers.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import treesim as ts
from treesim.errors import InputFormatError
from treesim.models import read_cylinders
from treesim.plot.scan import read_stations
from treesim.twin import TwinParams, plot_from_cloud

from .field_plot import small_field_plot

#: Acceptance (issue 23): DBH within 1 cm.
DBH_M = 0.01


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The small field plot (``field_plot.SMALL_PLOT``), made once per test run."""
    return small_field_plot(tmp_path_factory)


@pytest.fixture(scope="module")
def twin(small, tmp_path_factory):
    out = tmp_path_factory.mktemp("twin")
    params = TwinParams(preset="draft")
    return plot_from_cloud(small.e57 or small.laz, out, params, executor="inline")


@pytest.mark.slow
def test_from_cloud_writes_a_twin_that_reads_and_scans(small, twin) -> None:
    out = twin.outdir
    for name in ("plot.toml", "trees.csv", "dtm.asc", "plot_labelled.laz", "from_cloud.json",
                 "report.html", "map.png", "dbh_height.png"):  # fmt: skip
        assert (out / name).is_file(), name
    plot = ts.read_plot(twin.plot_file)
    assert plot.terrain.kind == "dtm"
    assert len(plot.trees) == len(twin.trees) >= 3
    true_xy = np.array([[t["x_m"], t["y_m"]] for t in small.truth])
    for tree in plot.trees:
        assert tree.source == "qsm" and (out / tree.field_cloud).is_file()
        # the twin's tree stands where a true tree stands
        assert np.linalg.norm(true_xy - [tree.x_m, tree.y_m], axis=1).min() < 0.15
        assert plot.tree_bounds(tree.tree_id)[1, 2] > plot.tree_bounds(tree.tree_id)[0, 2] + 2
        # ... exactly where its table stands (on the field cloud's terrain): the plot
        # places it as it is, not re-seated on the slope (that lifted crowns off the
        # field scan's points by up to 21 cm)
        written = read_cylinders(out / tree.path)
        np.testing.assert_allclose(plot.tree_table(tree.tree_id).start, written.start, atol=1e-9)
    if small.e57 is not None:
        stations = read_stations(small.e57, plot)
        assert np.allclose([s.position_m for s in stations], small.stations)
        assert (out / "stations.csv").is_file()


@pytest.mark.slow
def test_from_cloud_again_reuses_the_reconstructions(small, twin) -> None:
    params = TwinParams(preset="draft")
    again = plot_from_cloud(twin.figures["input"], twin.outdir, params, executor="inline")
    assert [r["tree_id"] for r in again.trees] == [r["tree_id"] for r in twin.trees]
    import json

    rows = json.loads((twin.outdir / "reconstruct" / "summary.json").read_text())["trees"]
    assert rows and all(r["reused"] for r in rows)


# ---------------------------------------------------------------------- bad input
@pytest.mark.slow
def test_a_cloud_without_ground_is_refused(small, tmp_path: Path) -> None:
    cloud = ts.read_cloud(small.laz)
    keep = cloud.fields["tree_id"] > 0
    path = ts.write_cloud(tmp_path / "noground.laz", cloud.subset(keep))
    with pytest.raises(InputFormatError, match="no ground"):
        plot_from_cloud(path, tmp_path / "twin", executor="inline")


def _in_us_feet(cloud, path: Path) -> Path:
    """The cloud written in US survey feet, its LAS coordinate system saying so (WKT)."""
    import laspy
    from laspy.vlrs.known import WktCoordinateSystemVlr

    ft = 1200.0 / 3937.0
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = [0.001] * 3
    header.offsets = [0.0, 0.0, 0.0]
    header.vlrs.append(
        WktCoordinateSystemVlr(
            'PROJCS["NAD83 / Vermont (ftUS)",GEOGCS["NAD83",DATUM["North_American_Datum_1983",'
            'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],'
            'UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
            'UNIT["US survey foot",0.304800609601219]]'
        )
    )
    header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = (cloud.points / ft).T
    las.write(path)
    return path


@pytest.mark.slow
def test_a_plot_in_feet_is_converted_by_its_crs_or_when_told(small, twin, tmp_path: Path) -> None:
    """A LAS whose coordinate system declares US survey feet is converted (and said so);
    the same coordinates without a CRS are converted when told (--units us-ft)."""
    from treesim.twin import declared_units

    cloud = ts.read_cloud(small.laz)
    path = _in_us_feet(cloud, tmp_path / "feet.las")
    assert declared_units(path) == "us-ft"
    res = plot_from_cloud(path, tmp_path / "a", TwinParams(preset="draft"), executor="inline")
    assert any("converted to metres" in w for w in res.warnings)
    assert len(res.trees) == len(twin.trees)
    for a, b in zip(res.trees, twin.trees, strict=True):
        assert a["slab_dbh_m"] == pytest.approx(b["slab_dbh_m"], abs=2e-3)
        assert a["x_m"] == pytest.approx(b["x_m"], abs=0.01)
    # without a CRS, the same feet are converted when told: the cloud the twin is made of
    # is then the metre cloud to the LAS's 1 mm (feet) quantum, so the twin is the one above
    from treesim.twin.core import _read, _units

    bare = ts.write_cloud(tmp_path / "bare.laz", ts.read_cloud(path))  # no CRS any more
    assert declared_units(bare) is None and _units(bare, "auto") == ("m", [])
    told = _read(bare, _units(bare, "us-ft")[0])
    assert np.abs(told.points - cloud.points).max() < 1e-3


def test_trees_too_large_for_metres_are_refused() -> None:
    """Stems of a median DBH over 1.2 m (feet read as metres) stop with a message."""
    from treesim.plot.stems import Stem
    from treesim.twin.core import _check_units

    big = [
        Stem(x_m=0.0, y_m=float(i), base_xyz_m=(0.0, float(i), 0.0), dbh_m=1.5, circle_rms_m=0.01,
             arc_deg=200.0, n_points=500, lean_deg=0.0)
        for i in range(3)
    ]  # fmt: skip
    with pytest.raises(InputFormatError, match="in feet"):
        _check_units(big, np.array([60.0, 70.0, 80.0]), "m")
    _check_units([], np.array([]), "m")  # no stems: nothing to say


@pytest.mark.slow
def test_a_projected_offset_changes_nothing_but_the_coordinates(small, twin, tmp_path) -> None:
    cloud = ts.read_cloud(small.laz)
    offset = np.array([5e6, 5e6, 300.0])
    path = ts.write_cloud(tmp_path / "utm.laz", ts.Cloud(cloud.points + offset))
    params = TwinParams(preset="draft")
    res = plot_from_cloud(path, tmp_path / "t", params, executor="inline")
    assert len(res.trees) == len(twin.trees)
    for a, b in zip(res.trees, twin.trees, strict=True):
        assert a["x_m"] - offset[0] == pytest.approx(b["x_m"], abs=0.005)
        assert a["slab_dbh_m"] == pytest.approx(b["slab_dbh_m"], abs=2e-3)


@pytest.mark.slow
def test_a_single_tree_is_a_plot_of_one(small, tmp_path: Path) -> None:
    cloud = ts.read_cloud(small.laz)
    t = small.truth[0]
    near = np.hypot(cloud.points[:, 0] - t["x_m"], cloud.points[:, 1] - t["y_m"]) < 2.5
    one = cloud.subset(near & np.isin(cloud.fields["tree_id"], [0, t["tree_id"]]))
    path = ts.write_cloud(tmp_path / "one.laz", one)
    params = TwinParams(preset="draft")
    res = plot_from_cloud(path, tmp_path / "t", params, executor="inline")
    assert len(res.trees) == 1
    assert res.trees[0]["slab_dbh_m"] == pytest.approx(t["dbh_m"], abs=DBH_M)
