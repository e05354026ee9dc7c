"""A plot scan reports the scanner's time as a single-tree scan does: ``timing`` in
``plot_scan.json`` and every station's ``scan_duration_s`` (the field scan takes its
time whether or not the station records anything), and points' ``time_s`` within the
station's scan.

The oracle is the scanner's mechanics (:func:`treesim.scan.timing.station_duration_s`,
held against the data sheets in tests/scan), not the plot scan's own figures."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from treesim.io import read_cloud
from treesim.params import ScanParams
from treesim.plot import Plot, PlotTree
from treesim.plot.scan import plot_scan_files, scan_plot
from treesim.scan import ScannerSpec
from treesim.scan.timing import station_duration_s

#: the first station stands among the trees; the second 60 m away, beyond max_range_m of
#: every tree and of the terrain (which reaches the plot's square plus 2 m): it records
#: nothing
STATIONS = [(0.0, 0.0, 1.5), (60.0, 0.0, 1.5)]


def _plot() -> Plot:
    trees = [
        PlotTree(tree_id=1, x_m=2.5, y_m=0.0, species="sapling", seed=0),
        PlotTree(tree_id=2, x_m=-2.0, y_m=1.5, species="sapling", seed=1, rotation_deg=40.0),
    ]
    return Plot(trees, facets=8, radius_m=5)


def _params() -> ScanParams:
    spec = ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5, max_range_m=9.0)
    return replace(ScanParams(), scanner=spec)


def test_plot_scan_json_carries_timing_and_every_stations_duration(tmp_path):
    params = _params()
    duration_s = station_duration_s(params.scanner)
    assert duration_s > 0
    step = plot_scan_files(_plot(), tmp_path, params, stations=STATIONS, figures=False, threads=1)
    j = json.loads((tmp_path / "plot_scan.json").read_text())
    assert j["timing"]["duration_s"] == pytest.approx(duration_s, rel=1e-12)
    assert j["timing"]["pulse_rate_hz"] == params.scanner.pulse_rate_hz
    assert "time_s" in j["timing"]["convention"]
    st = j["stations"]
    assert [s["points"] > 0 for s in st] == [True, False]  # the far one records nothing
    assert [s["scan_duration_s"] for s in st] == [pytest.approx(duration_s)] * 2
    assert step.result.summary()["timing"] == j["timing"]

    cloud = read_cloud(tmp_path / "plot_scan.laz")
    t = cloud.fields["time_s"]
    assert len(t) == st[0]["points"] > 1000
    assert (t >= 0).all() and (t < duration_s).all()
    # the scan is a sweep: the pulses' times spread over most of the turn it took
    assert t.max() - t.min() > 0.5 * duration_s


def test_an_empty_station_on_local_workers_has_its_duration_too():
    params = _params()
    r = scan_plot(_plot(), STATIONS, params, terrain=False, executor="local", workers=2, threads=1)
    duration_s = station_duration_s(params.scanner)
    assert [s.points > 0 for s in r.station_stats] == [True, False]
    assert [s.scan_duration_s for s in r.station_stats] == [pytest.approx(duration_s)] * 2
    t = r.cloud.fields["time_s"]
    assert len(t) > 500 and (t >= 0).all() and (t < duration_s).all()
    assert r.summary()["timing"]["duration_s"] == pytest.approx(duration_s)
