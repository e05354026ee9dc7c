"""A plot scan's stations as tasks (issue 25): on local worker processes and on a local
Dask cluster of two workers, each station builds only the trees it can record, and the
merged scan is the inline scan's, bit for bit (every field, every point, the figures).

The oracle is the inline scan: one process, one station after another, which the
station-by-station tests (test_plot_scan.py) hold against the whole plot scanned at once."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from treesim.params import ScanParams
from treesim.plot import Plot, PlotTree, Terrain
from treesim.plot.scan import scan_plot
from treesim.scan import ScannerSpec, Station

_FIGURES = ("points", "rays_cast", "models_active", "warnings", "lod")
_STATION = ("index", "position_m", "pulses_full_fov", "pulses_window", "pulses_cast", "points")


def _plot() -> Plot:
    pos = [(3.0, 0.0), (-3.0, 1.0), (0.0, 4.0), (12.0, 0.0), (-2.0, -10.0)]
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i, rotation_deg=17.0 * i)
        for i, (x, y) in enumerate(pos)
    ]
    ter = Terrain(kind="slope", slope_deg=8.0, aspect_deg=30.0)
    return Plot(trees, facets=8, terrain=ter, radius_m=12)


def _params() -> ScanParams:
    spec = ScannerSpec(
        horizontal_resolution_deg=0.4,
        vertical_resolution_deg=0.4,
        max_range_m=9.0,
        horizontal_fov_deg=(0.0, 200.0),
    )
    return replace(ScanParams(), scanner=spec)


STATIONS = [
    Station(position_m=(0.0, 0.0, 1.5)),
    Station(position_m=(6.0, -5.0, 1.5)),
    Station(position_m=(-6.0, 6.0, 1.2)),
]


@pytest.fixture(scope="module")
def inline():
    return scan_plot(_plot(), STATIONS, _params())


def _same(a, b) -> None:
    """Every field and point equal, bit for bit; the same figures (times aside)."""
    ca, cb = a.cloud, b.cloud
    assert len(ca) == len(cb) > 5_000
    assert ca.points.dtype == cb.points.dtype
    np.testing.assert_array_equal(ca.points, cb.points)
    assert sorted(ca.fields) == sorted(cb.fields)
    for name in ca.fields:
        assert ca.fields[name].dtype == cb.fields[name].dtype, name
        np.testing.assert_array_equal(ca.fields[name], cb.fields[name], err_msg=name)
    sa, sb = a.summary(), b.summary()
    for key in _FIGURES:
        assert sa[key] == sb[key], key
    for x, y in zip(sa["stations"], sb["stations"], strict=True):
        for key in (*_STATION, "trees_loaded", "trees_beyond_range", "trees_outside_fov"):
            assert x[key] == y[key], key
        assert x["triangles_loaded"] == y["triangles_loaded"]
        assert x["triangles_total"] == y["triangles_total"]


def test_the_stations_left_trees_out(inline):
    # the case means something: each station loads only some of the trees
    assert any(ld["trees_beyond_range"] for ld in inline.loading)
    assert any(ld["trees_outside_fov"] for ld in inline.loading)
    assert all(ld["triangles_loaded"] < ld["triangles_total"] for ld in inline.loading)


def test_local_processes_give_the_inline_scan(inline):
    plot = _plot()
    got = scan_plot(plot, STATIONS, _params(), executor="local", workers=2, threads=1)
    _same(got, inline)
    assert plot.loaded == []  # the parent built no tree
    for ld in got.loading:
        assert ld["trees_built"] == []  # built once each, before, and read by the stations
        assert ld["rss_peak_bytes"] is None or ld["rss_peak_bytes"] >= ld["rss_before_bytes"]


def test_a_dask_cluster_of_two_gives_the_inline_scan(inline):
    pytest.importorskip("distributed", reason="the dask executor needs dask[distributed]")
    plot = _plot()
    chunks = []
    got = scan_plot(
        plot,
        STATIONS,
        _params(),
        executor="dask",
        workers=2,
        threads=1,
        sink=lambda p, f: chunks.append((p, f)),
    )
    assert len(got.cloud) == 0 and got.points_written == len(inline.cloud)
    # one chunk per station, in station order
    assert [int(f["station"][0]) for _, f in chunks] == [0, 1, 2]
    merged = replace(
        got,
        cloud=replace(
            inline.cloud,
            points=np.concatenate([p for p, _ in chunks]),
            fields={k: np.concatenate([f[k] for _, f in chunks]) for k in chunks[0][1]},
        ),
    )
    _same(merged, inline)
    # the truth needs no tree built here: the tasks handed the tables over
    assert plot.truth(1) == _plot().truth(1)


def test_cli_plot_scan_on_local_workers_writes_the_inline_files(tmp_path, capsys):
    import json

    from treesim.cli import main
    from treesim.io import read_cloud
    from treesim.plot.io import write_plot

    (tmp_path / "plot").mkdir()
    write_plot(tmp_path / "plot" / "plot.toml", _plot())
    common = ["--resolution-deg", "0.5", "--stations", "2", "--distance-m", "2.0"]
    argv = ["plot", "scan", str(tmp_path / "plot"), *common]
    assert main([*argv, "-o", str(tmp_path / "a")]) == 0, capsys.readouterr().err
    local = ["--executor", "local", "--workers", "2", "--threads", "1"]
    assert main([*argv, "-o", str(tmp_path / "b"), *local]) == 0, capsys.readouterr().err
    a, b = (
        read_cloud(tmp_path / "a" / "plot_scan.laz"),
        read_cloud(tmp_path / "b" / "plot_scan.laz"),
    )
    assert len(a) == len(b) > 1000
    np.testing.assert_array_equal(a.points, b.points)
    for name in a.fields:
        np.testing.assert_array_equal(a.fields[name], b.fields[name], err_msg=name)
    ja = json.loads((tmp_path / "a" / "plot_scan.json").read_text())
    jb = json.loads((tmp_path / "b" / "plot_scan.json").read_text())
    assert [r["points"] for r in ja["trees"]] == [r["points"] for r in jb["trees"]]
    assert [r["coverage"] for r in ja["trees"]] == [r["coverage"] for r in jb["trees"]]
    assert ja["truth"] == jb["truth"]


def test_a_plans_verification_on_local_workers_gives_the_inline_figures():
    from tests.plan.setups import verification_case

    _, _, r, figures = verification_case()
    assert len(r.stations) >= 2  # more than one task
    inline = figures()
    assert inline["points"] > 1000
    assert figures(executor="local", workers=2, nthreads=1) == inline


def test_a_remote_scheduler_needs_a_shared_tree_folder():
    from treesim.errors import InvalidParameterError

    pytest.importorskip("distributed", reason="the dask executor needs dask[distributed]")
    with pytest.raises(InvalidParameterError, match="cache_dir"):
        scan_plot(_plot(), STATIONS, _params(), executor="dask", scheduler="tcp://x:8786")
