"""Scanning a plot: time, peak memory, and the triangles each station loads.

A generated stand (``aspen:0.6,balsam-fir:0.4``, 300 stems/ha in 15 m, seed 1: 21
trees) meshed at high facets (200: ~1M triangles for an aspen) on a 5° slope, scanned
at 0.1° from three stations on a ring at 0.6 × the plot's radius, the points counted
and dropped (a sink, as a file writer takes them), each case in a fresh process (peak
RSS is the process's own ``ru_maxrss``; time includes building the trees):

1. ``scan_plot`` with the scanner's full range: every tree is within reach, so every
   station loads them all (the per-station culling cannot help here; the cache keeps the
   trees between stations);
2. ``scan_plot`` with a short range (``--short-range-m``, default 10 m): each station loads
   only the trees whose box it can reach;
3. the same short-range scan with ``cache_triangles=0`` (no tree kept between stations:
   memory follows one station's scene; trees needed again are rebuilt);
4. the whole plot as one scene scanned at once by :func:`treesim.scan.scan` (the
   baseline: every tree held and loaded), at the short range.

Usage: ``python benchmarks/bench_plot.py [--quick] [--docs]`` (``--quick``: 16 facets
and 0.2°, a smoke run; ``--docs``: write the table into ``docs/validation.md`` between
``<!-- bench-plot:begin -->`` and ``<!-- bench-plot:end -->``). Prints measured figures
only.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import docs_part  # noqa: E402

DOCS_PART = "bench-plot"

_CHILD = r"""
import json, resource, sys, time
from dataclasses import replace
sys.path.insert(0, {root!r})
from treesim.params import ScanParams
from treesim.plot.io import read_plot
from treesim.plot.scan import plot_stations, scan_plot
from treesim.scan import ScannerSpec, scan

case, plot_dir, res, rng, threads = {case!r}, {plot_dir!r}, {res!r}, {rng!r}, {threads!r}
plot = read_plot(plot_dir)
spec = ScannerSpec(horizontal_resolution_deg=res, vertical_resolution_deg=res,
                   **({{"max_range_m": rng}} if rng else {{}}))
params = replace(ScanParams(), scanner=spec, max_rays=10**10)
stations = plot_stations(plot, n=3, distance_m=0.6 * plot.radius_m)
count = [0]

def sink(p, f):
    count[0] += len(p)

t0 = time.perf_counter()
out = {{"case": case}}
if case == "whole":
    scene = plot.scene()
    t1 = time.perf_counter()
    r = scan(scene, stations, spec, nthreads=threads, frame=plot.frame(), max_rays=10**10,
             sink=sink)
    out.update(points=count[0], build_s=t1 - t0, triangles=scene.n_triangles,
               loaded=[scene.n_triangles] * len(stations),
               trees=[len(plot.trees)] * len(stations))
else:
    cache = 0 if case == "nocache" else 20_000_000
    r = scan_plot(plot, stations, params, threads=threads, cache_triangles=cache, sink=sink)
    out.update(points=count[0], triangles=r.loading[0]["triangles_total"],
               loaded=[ld["triangles_loaded"] for ld in r.loading],
               trees=[len(ld["trees_loaded"]) for ld in r.loading],
               built=[len(ld["trees_built"]) for ld in r.loading])
out["time_s"] = time.perf_counter() - t0
out["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print("RESULT " + json.dumps(out))
"""


def run_case(case: str, plot_dir: Path, res: float, rng: float | None, threads: int) -> dict:
    code = _CHILD.format(
        root=str(ROOT), case=case, plot_dir=str(plot_dir), res=res, rng=rng, threads=threads
    )
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise SystemExit(f"case {case} failed:\n{p.stderr[-3000:]}")
    line = next(x for x in p.stdout.splitlines() if x.startswith("RESULT "))
    out = json.loads(line[len("RESULT ") :])
    out["wall_s"] = time.perf_counter() - t0
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--docs", "--readme", dest="docs", action="store_true")
    ap.add_argument("--facets", type=int, default=None)
    ap.add_argument("--resolution-deg", type=float, default=None)
    ap.add_argument("--short-range-m", type=float, default=10.0)
    ap.add_argument("--threads", type=int, default=0)
    a = ap.parse_args()
    facets = a.facets or (16 if a.quick else 200)
    res = a.resolution_deg or (0.2 if a.quick else 0.1)
    from treesim.plot import Terrain
    from treesim.plot.generate import generate_stand
    from treesim.plot.io import write_plot

    radius = 15.0  # 300 stems/ha: 21 trees
    with tempfile.TemporaryDirectory() as tmp:
        plot, stand = generate_stand(
            "aspen:0.6,balsam-fir:0.4",
            300,
            radius,
            seed=1,
            facets=facets,
            terrain=Terrain(kind="slope", slope_deg=5.0, aspect_deg=45.0),
        )
        write_plot(Path(tmp) / "plot.toml", plot, stand=stand)
        print(
            f"plot: {len(plot.trees)} trees in {radius} m, {facets} facets; "
            f"{res}° resolution; 3 stations at {0.6 * radius} m from the centre; "
            f"short range {a.short_range_m} m",
            flush=True,
        )
        cases = [
            ("full range", "cached", None),
            ("short range", "cached", a.short_range_m),
            ("short range, no cache", "nocache", a.short_range_m),
            ("whole scene at once, short range", "whole", a.short_range_m),
        ]
        rows = []
        for label, case, rng in cases:
            r = run_case(case, Path(tmp), res, rng, a.threads)
            r["label"] = label
            rows.append(r)
            print(
                f"{label:34} {r['time_s']:7.1f} s  peak RSS {r['peak_rss_gib']:5.2f} GiB  "
                f"{r['points']:>11,} points  trees per station {r['trees']}  triangles "
                f"loaded per station {[f'{x / 1e6:.2f}M' for x in r['loaded']]} of "
                f"{r['triangles'] / 1e6:.2f}M"
                + (f"  trees built {r['built']}" if "built" in r else ""),
                flush=True,
            )
    machine = (
        f"{date.today()} on {platform.machine()} with {os.cpu_count()} cores, "
        f"python {sys.version.split()[0]}"
    )
    print(machine)
    by = {r["label"]: r for r in rows}
    short, nocache = by["short range"], by["short range, no cache"]
    whole = by["whole scene at once, short range"]
    ratios = (
        f"Short range against the whole scene at once: peak RSS "
        f"{short['peak_rss_gib'] / whole['peak_rss_gib']:.2f}x "
        f"({nocache['peak_rss_gib'] / whole['peak_rss_gib']:.2f}x without the cache), time "
        f"{short['time_s'] / whole['time_s']:.2f}x ({nocache['time_s'] / whole['time_s']:.2f}x "
        f"without the cache: rebuilding the trees a later station needs again cost "
        f"{nocache['time_s'] - short['time_s']:+.1f} s)."
    )
    print(ratios)
    if a.docs:
        command = " ".join(["python benchmarks/bench_plot.py", *sys.argv[1:]])
        lines = [
            f"`{command}` measured these in one run: {machine} "
            f"(a shared host: expect ±15 %). {len(plot.trees)} generated trees "
            f"(aspen:0.6,balsam-fir:0.4, 300 stems/ha, {radius} m, seed 1, {facets} facets, "
            f"{rows[0]['triangles'] / 1e6:.1f} M triangles with the terrain), 3 stations, "
            f"{res}°; each case a fresh process.",
            "",
            "| case | time | peak RSS | points | trees per station | triangles loaded per "
            "station |",
            "|---|---|---|---|---|---|",
        ]
        for r in rows:
            loaded = " / ".join(f"{x / 1e6:.1f} M" for x in r["loaded"])
            lines.append(
                f"| {r['label']} | {r['time_s']:.1f} s | {r['peak_rss_gib']:.2f} GiB | "
                f"{r['points'] / 1e6:.2f} M | {' / '.join(map(str, r['trees']))} | "
                f"{loaded} of {r['triangles'] / 1e6:.1f} M |"
            )
        lines += ["", ratios]
        docs_part.write_part(DOCS_PART, "\n".join(lines))
        print(f"wrote the table into {docs_part.VALIDATION.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
