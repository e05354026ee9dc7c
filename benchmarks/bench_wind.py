"""The price of wind (issue 26): a windy scan's time against the still scan's.

Scans a procedural preset (default ``aspen``, seed 0, 32-facet wood) from three stations
10 m away at ``--step-deg`` (default 0.1°) with the generic scanner, still and with a
turbulent wind of ``--wind`` m/s (default 5; :mod:`treesim.scan.wind`), and prints for
each: the scan's time (s), points, time slices, the shortest slice (ms), the time spent
building the slices' ray-casting scenes, and the windy / still time ratio; then the
points' ``wind_displacement_m`` (median, 95th percentile, largest) by label.

Usage: ``python benchmarks/bench_wind.py [--species aspen] [--step-deg 0.1] [--wind 5]
[--facets 32] [--stations 3]``; about a minute on 2 cores at the defaults. Prints
measured figures only.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import treesim as ts  # noqa: E402
from treesim.cloud import LABEL_CODES  # noqa: E402
from treesim.models import generate_tree  # noqa: E402
from treesim.scan.wind import Forcing, Wind  # noqa: E402
from treesim.scene import Scene  # noqa: E402


def _scan(scene, stations, spec, wind=None) -> tuple[float, object]:
    t = time.perf_counter()
    result = ts.scan(scene, stations, spec, wind=wind)
    return time.perf_counter() - t, result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--species", default="aspen")
    ap.add_argument("--step-deg", type=float, default=0.1)
    ap.add_argument("--wind", type=float, default=5.0)
    ap.add_argument("--facets", type=int, default=32)
    ap.add_argument("--stations", type=int, default=3)
    a = ap.parse_args(argv)
    tree = generate_tree(a.species, seed=0)
    v, f, lab = tree.mesh(facets=a.facets)
    scene = Scene.from_labelled_mesh(v, f, lab)
    stations = ts.ring_layout(a.stations, distance_m=10.0, height_m=1.5, centre_xy=(0.0, 0.0))
    spec = ts.ScannerSpec(horizontal_resolution_deg=a.step_deg, vertical_resolution_deg=a.step_deg)
    print(
        f"# bench_wind: {a.species} (seed 0, {len(f):,} triangles), {a.stations} stations at "
        f"10 m, {a.step_deg:g}°, wind {a.wind:g} m/s; {platform.processor() or platform.machine()}"
        f", {os.cpu_count()} cores"
    )
    ts.scan(scene, stations[:1], spec.with_(horizontal_resolution_deg=2.0))  # warm Open3D
    t_still, still = _scan(scene, stations, spec)
    wind = Wind(tree.cylinders, Forcing(a.wind, seed=0))
    t_wind, windy = _scan(scene, stations, spec, wind)
    w = windy.wind
    slices = sum(s["slices"] for s in w["stations"])
    shortest = min(s["slice_s"] for s in w["stations"])
    build = sum(s["bvh_build_s"] for s in w["stations"])
    print(
        f"{'scan':>6} {'time (s)':>9} {'points':>9} {'slices':>7} {'slice (ms)':>10} {'BVH (s)':>8}"
    )
    print(
        f"{'still':>6} {t_still:9.2f} {len(still.cloud):9,} {1:7} {'-':>10} "
        f"{still.bvh_build_s:8.2f}"
    )
    print(
        f"{'wind':>6} {t_wind:9.2f} {len(windy.cloud):9,} {slices:7,} {shortest * 1e3:10.2f} "
        f"{build:8.2f}"
    )
    print(f"ratio windy / still: {t_wind / t_still:.1f}")
    print(
        f"stem {w['stem_frequency_hz']:.2f} Hz, top {w['stem_tip_mean_m'] * 100:.1f} cm "
        f"downwind ± {w['stem_tip_swing_3sigma_m'] * 100:.1f} cm (3σ); branches "
        f"{w['branch_frequency_hz']['min']:.2f}-{w['branch_frequency_hz']['max']:.2f} Hz, "
        f"{w['branches_capped']} of {w['branches']} capped at 10 % of their length"
    )
    d, labels = windy.cloud.fields["wind_displacement_m"], windy.cloud.fields["label"]
    for name in ("wood", "leaf"):
        sel = labels == LABEL_CODES[name]
        if sel.any():
            q = np.percentile(d[sel], [50, 95, 100]) * 1000
            print(
                f"wind_displacement_m {name}: median {q[0]:.1f} mm, 95 % {q[1]:.1f} mm, "
                f"max {q[2]:.1f} mm"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
