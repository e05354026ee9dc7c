"""A sweep over the wind (issue 26): a windy design measures the tree scanned in its wind.

Oracles: the wind model's definition of ``wind_displacement_m`` (a magnitude, never
negative; a 5 m/s wind moves a 4 m sapling, so not all zero; absent from a still scan),
the still tree's field cloud (a windy design gets another one; the still design the same
as a sweep with no wind), and the swept value itself in the sweep's table.
"""

from __future__ import annotations

import csv
import json

import numpy as np

import treesim as ts
from treesim.sweep import load_sweep, run_sweep

CONFIG = """
preset = "draft"
tolerance_m = 0.02
[reference]
n_stations = 2
resolution_deg = 0.4
[[tree]]
species = "sapling"
facets = 8
[base]
resolution_deg = 0.4
stations = 2
"report.level" = "none"
[grid]
"scan.scanner.wind_speed_m_s" = [0.0, 5.0]
"""


def test_wind_axis_sways_the_field_scan_and_the_design_scan(tmp_path):
    cfg = tmp_path / "wind.toml"
    cfg.write_text(CONFIG)
    result = run_sweep(load_sweep(cfg), tmp_path / "out")
    rows = {float(r["scan.scanner.wind_speed_m_s"]): r for r in result.rows}
    assert sorted(rows) == [0.0, 5.0] and all(r["status"] == "ok" for r in rows.values())
    # the still design's tree is the sweep's own; the windy one's was scanned in the wind
    still_field = ts.read_cloud(tmp_path / "out" / "trees" / "sapling" / "field.ply")
    assert "wind_displacement_m" not in still_field.fields
    (windy_dir,) = (tmp_path / "out" / "trees").glob("wind-5-*/sapling")
    info = json.loads((windy_dir / "tree.json").read_text())
    assert info["reference_scan"]["wind"]["wind_speed_m_s"] == 5.0
    d = np.asarray(ts.read_cloud(windy_dir / "field.ply").fields["wind_displacement_m"])
    assert np.all(d >= 0.0) and np.any(d > 0.0)
    # the windy design's own scan of the reconstruction sways by the reconstruction's table
    pts = tmp_path / "out" / "points"
    scan_json = json.loads((pts / rows[5.0]["id"] / "scan.json").read_text())
    assert scan_json["wind_cylinders"] == "cylinders.csv"
    windy_scan = ts.read_cloud(pts / rows[5.0]["id"] / "scan.ply")
    assert np.any(np.asarray(windy_scan.fields["wind_displacement_m"]) > 0.0)
    still_scan = ts.read_cloud(pts / rows[0.0]["id"] / "scan.ply")
    assert "wind_displacement_m" not in still_scan.fields
    # the table and the page carry the swept wind
    with open(tmp_path / "out" / "sweep.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert "scan.scanner.wind_speed_m_s" in header
    assert "wind_speed_m_s" in (tmp_path / "out" / "sweep.html").read_text()
    doc = json.loads((tmp_path / "out" / "sweep.json").read_text())
    assert [(t["id"], t["wind_speed_m_s"]) for t in doc["trees_in_wind"]] == [("sapling", 5.0)]
