"""A plot station scanned in azimuth sectors (issue 25: a hectare's station holds more
triangles than two tasks can hold at once on one machine).

Oracles: the station scanned as one scene (the inline scan without sectors, itself held
against the whole plot scanned at once by test_plot_scan.py), the scanner's column of a
point computed from its azimuth by hand, and the sectors' own inline scan for the
executors (bit for bit)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from treesim.errors import InvalidParameterError
from treesim.params import ScanParams
from treesim.plot import Plot, PlotTree, Terrain
from treesim.plot.scan import scan_plot
from treesim.plot.sectors import check_sectors, sector_columns, tree_columns
from treesim.scan import ScannerSpec, Station

# the fields that say which pulse, which return, which surface and which tree
_PULSE = ("station", "scan_line", "scan_column", "time_s", "return_number", "label", "tree_id")


def _plot() -> Plot:
    pos = [(3.0, 0.5), (-3.0, 1.0), (0.5, 4.0), (-2.5, -3.5), (4.0, -4.0), (8.0, 5.0)]
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i, rotation_deg=23.0 * i)
        for i, (x, y) in enumerate(pos)
    ]
    return Plot(trees, facets=8, terrain=Terrain(kind="slope", slope_deg=6.0), radius_m=12)


def _params(**kw) -> ScanParams:
    spec = ScannerSpec(
        horizontal_resolution_deg=0.3,
        vertical_resolution_deg=0.3,
        max_range_m=14.0,
        range_noise_sd_m=0.003,
        angular_jitter_sd_deg=0.01,
        **kw,
    )
    return replace(ScanParams(), scanner=spec)


STATIONS = [Station(position_m=(0.0, 0.0, 1.5)), Station(position_m=(-5.0, 4.0, 1.3))]


@pytest.fixture(scope="module")
def whole():
    return scan_plot(_plot(), STATIONS, _params())


@pytest.fixture(scope="module")
def four():
    return scan_plot(_plot(), STATIONS, _params(), sectors=4)


def test_sector_columns_partition_the_turn_in_order():
    spec = _params().scanner
    for n in (1, 3, 4, 7):
        ranges = sector_columns(spec, n)
        assert len(ranges) == n
        cols = np.concatenate([np.arange(a, b) for a, b in ranges])
        np.testing.assert_array_equal(cols, np.arange(spec.n_azimuth))
        widths = [b - a for a, b in ranges]
        assert max(widths) - min(widths) <= 1


def test_tree_columns_hold_every_column_that_sees_the_box():
    # points inside a box, their column by hand (nearest column of their azimuth): the
    # columns a pulse could reach the box from are among tree_columns'
    spec = _params().scanner
    st = Station(position_m=(1.0, -2.0, 1.5))
    rng = np.random.default_rng(4)
    for lo, hi in (
        ([4.0, 3.0, 0.0], [6.0, 5.5, 7.0]),  # north-east
        ([-9.0, -1.0, 0.0], [-7.0, 1.0, 5.0]),  # across the -180/180 seam, west
        ([0.5, -2.5, 0.0], [1.5, -1.5, 4.0]),  # around the station: every column
    ):
        box = np.array([lo, hi])
        cols = tree_columns(box, st, spec)
        p = lo + rng.random((20_000, 3)) * (np.array(hi) - lo)
        az = np.degrees(np.arctan2(p[:, 1] - st.position[1], p[:, 0] - st.position[0]))
        h0 = spec.horizontal_fov_deg[0]
        by_hand = np.unique(np.round((az - h0) / spec.horizontal_resolution_deg) % spec.n_azimuth)
        assert np.isin(by_hand.astype(np.int64), cols).all()
        assert len(cols) < spec.n_azimuth or lo[0] < st.position[0] < hi[0]


def test_sectors_hold_less_and_give_the_stations_points(whole, four):
    a, b = whole.cloud, four.cloud
    assert len(a) == len(b) > 20_000
    for name in _PULSE:
        np.testing.assert_array_equal(a.fields[name], b.fields[name], err_msg=name)
    # the same surfaces, to the micron: only a ray through an edge two triangles share can
    # meet the other one (Open3D's hierarchy differs)
    moved = np.linalg.norm(a.points - b.points, axis=1)
    assert moved.max() < 1e-5
    assert np.count_nonzero(moved) <= 1e-3 * len(a)
    # each sector holds a part of its station's trees (the second station sees all its
    # trees within one quarter of the turn: one of its sectors holds them all)
    for ld, st_whole in zip(four.loading, whole.loading, strict=True):
        per = ld["sector_triangles_loaded"]
        assert len(per) == 4
        assert max(per) == ld["triangles_loaded"] <= st_whole["triangles_loaded"]
    assert four.loading[0]["triangles_loaded"] < 0.6 * whole.loading[0]["triangles_loaded"]
    # the station's figures are its sectors' summed
    for s4, s1 in zip(four.station_stats, whole.station_stats, strict=True):
        assert s4.points == s1.points
        assert s4.pulses_full_fov == s1.pulses_full_fov
        assert s4.index == s1.index
    assert [len(lod["sectors"]) for lod in four.lod] == [4, 4]


def test_the_same_sectors_give_the_same_points_on_workers(four):
    got = scan_plot(_plot(), STATIONS, _params(), sectors=4, executor="local", workers=2, threads=1)
    a, b = four.cloud, got.cloud
    assert len(a) == len(b)
    np.testing.assert_array_equal(a.points, b.points)
    for name in a.fields:
        np.testing.assert_array_equal(a.fields[name], b.fields[name], err_msg=name)
    assert [ld["sector_triangles_loaded"] for ld in got.loading] == [
        ld["sector_triangles_loaded"] for ld in four.loading
    ]
    assert [s.rays_cast for s in got.station_stats] == [s.rays_cast for s in four.station_stats]


def test_sectors_are_checked():
    with pytest.raises(InvalidParameterError, match="sectors must be an integer"):
        check_sectors(0, _params().scanner)
    with pytest.raises(InvalidParameterError, match="sectors must be an integer"):
        check_sectors(2.5, _params().scanner)
    beam = _params(beam_divergence_mrad=0.3, subrays=7).scanner
    assert beam.rays_per_pulse == 7
    assert check_sectors(1, beam) == 1
    with pytest.raises(InvalidParameterError, match="neighbouring pulses"):
        scan_plot(_plot(), STATIONS[:1], replace(ScanParams(), scanner=beam), sectors=2)
    assert check_sectors(3, _params().scanner) == 3


def test_cli_sectors_option(tmp_path, capsys):
    from treesim.cli import main
    from treesim.io import read_cloud
    from treesim.plot.io import write_plot

    (tmp_path / "plot").mkdir()
    write_plot(tmp_path / "plot" / "plot.toml", _plot())
    argv = ["plot", "scan", str(tmp_path / "plot"), "--resolution-deg", "0.6"]
    argv += ["--station", "0,0,1.5", "--no-figures"]
    assert main([*argv, "-o", str(tmp_path / "a")]) == 0, capsys.readouterr().err
    assert main([*argv, "-o", str(tmp_path / "b"), "--sectors", "3"]) == 0
    a, b = (read_cloud(tmp_path / d / "plot_scan.laz") for d in ("a", "b"))
    assert len(a) == len(b) > 1000
    np.testing.assert_array_equal(a.fields["scan_column"], b.fields["scan_column"])
    import json

    station = json.loads((tmp_path / "b" / "plot_scan.json").read_text())["stations"][0]
    assert len(station["sector_triangles_loaded"]) == 3  # the option reached the scan
    with pytest.raises(SystemExit) as exc:
        main([*argv, "-o", str(tmp_path / "c"), "--sectors", "0"])
    assert exc.value.code == 2
    assert "--sectors" in capsys.readouterr().err


def test_a_station_that_would_not_fit_says_how_many_sectors(monkeypatch):
    import treesim._system as system
    from treesim.plot.sectors import BYTES_PER_TRIANGLE, memory_advice

    # the advice's sectors bring the need under what is available (a sector holding its
    # share of the station's triangles)
    for tri, conc, avail in ((83e6, 2, 22 * 2**30), (40e6, 1, 4 * 2**30), (9e6, 4, 2**30)):
        text = memory_advice([int(tri)], conc, 1, avail)
        assert text is not None
        n = int(text.split("sectors=")[1].split()[0])
        assert tri / n * BYTES_PER_TRIANGLE * conc <= avail
    assert memory_advice([1000], 2, 1, None) is None  # not known: no warning
    # a scan whose stations would not fit is told so, and goes on
    monkeypatch.setattr(system, "available_memory_bytes", lambda: 2**20)
    said = []
    r = scan_plot(_plot(), STATIONS[:1], _params(), progress=lambda f, m: said.append(m))
    assert any("sectors=" in w for w in r.warnings)
    assert any(m.startswith("warning: a station holds") for m in said)
    assert len(r.cloud) > 1000
    monkeypatch.setattr(system, "available_memory_bytes", lambda: 2**40)
    r = scan_plot(_plot(), STATIONS[:1], _params())
    assert not any("sectors=" in w for w in r.warnings)


def test_a_plans_verification_in_sectors_records_the_same_points():
    from tests.plan.setups import verification_case

    _, _, _, verify = verification_case()

    def figures(**kw):
        v = verify(**kw)
        return v["points"], {t: f["points"] for t, f in v["trees"].items()}

    whole = figures()
    assert whole[0] > 1000
    assert figures(sectors=3) == whole  # the same pulses, so as many points per tree
