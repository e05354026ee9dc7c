"""A hectare plot's scan: time, peak memory (children included), triangles loaded, peak
bytes per loaded triangle, points; on one machine and on a Dask cluster.

A generated stand (``aspen:0.6,balsam-fir:0.4``, seed 1, flat ground) of ``--trees``
trees in a 1-ha disc (radius 56.42 m; ``--radius-m`` to change it), meshed at
``--facets``, scanned from ``--stations`` stations on a square grid over the plot's inner
half (1.5 m above the ground) at ``--step-deg``, ground included, the points counted and
hashed as they come (a sink: nothing is kept). Each case runs in a fresh process:

* the case asked for (``--executor inline|local|dask``, ``--workers``): with ``local``
  or ``dask`` each station is a task that builds only the trees it can record;
* with ``local`` or ``dask``, also the one-machine run (``inline``: this process, one
  station after another), and whether the merged points equal it (SHA-256 of every
  point's coordinates and of every field, in station order);
* with ``--sectors N`` (each station scanned in N azimuth sectors, each a task with an
  executor: ``treesim.plot.sectors``), the cases above with those sectors, and (unless
  ``--no-whole``) the one-machine run with one scene a station, against which the
  sectors' pulses, returns, labels and tree ids are compared (SHA-256) and their points'
  distances measured (the coordinates written to files and read back a chunk at a time).

Peak RSS sums the case's process and all its descendants (sampled every 0.2 s from
``/proc``). Bytes per triangle while casting: the first station alone in a fresh process
(inline, no tree kept), its peak over its resident memory before the scan, once with the
trees and once with the ground only (the rasters, ray buffers and ground a station holds
whatever its trees), the difference over the trees' triangles; at the default batch of
rays and at batches of ``SMALL_CHUNK_RAYS``, whose buffers for the trees' hits (which the
default batch holds more of with trees than with the ground alone, and which do not grow
with the triangles) hardly count: that one is what a loaded triangle costs. The task
runs' own peak over their start per loaded triangle is printed too (it holds the fixed
part).

Usage: ``python benchmarks/bench_hectare.py --trees 40 --stations 4 --step-deg 0.2
--executor dask --workers 2 [--facets 32] [--sectors 4 [--no-whole]] [--memory-repeats 3]
[--memory-only] [--no-memory] [--docs]``
(``--docs``: the printout becomes ``docs/validation.md``'s ``bench-hectare`` part;
``--memory-repeats``: the bytes-per-triangle measurement that many times, each pair of
fresh processes, the median used and the spread printed; ``--memory-only``: that
measurement alone). Prints measured figures, and an extrapolation to the issue's full
size labelled as such.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import docs_part  # noqa: E402

DOCS_PART = "bench-hectare"
HECTARE_RADIUS_M = math.sqrt(10_000.0 / math.pi)

_CHILD = r"""
import hashlib, json, os, sys, threading, time
from dataclasses import replace
sys.path.insert(0, {root!r})

def tree_rss():
    # resident bytes of this process and all its descendants
    kids, rss = {{}}, {{}}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{{d}}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{{d}}/statm") as fh:
                rss[int(d)] = int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
            kids.setdefault(ppid, []).append(int(d))
        except (OSError, ValueError, IndexError):
            continue
    todo, total = [os.getpid()], 0
    while todo:
        p = todo.pop()
        total += rss.get(p, 0)
        todo += kids.get(p, [])
    return total

peak = [0]
stop = threading.Event()
def sample():
    while not stop.is_set():
        peak[0] = max(peak[0], tree_rss())
        stop.wait(0.2)
threading.Thread(target=sample, daemon=True).start()

from treesim.params import ScanParams
from treesim.plot.io import read_plot
from treesim.plot.scan import plot_stations, scan_plot
from treesim.scan import ScannerSpec

plot = read_plot({plot_dir!r})
spec = ScannerSpec(horizontal_resolution_deg={step!r}, vertical_resolution_deg={step!r})
params = replace(ScanParams(), scanner=spec, max_rays=10**12)
stations = plot_stations(plot, positions={positions!r})
hashes, count = {{}}, [0]
PULSE = {pulse_fields!r}
xyz_file = open({xyz_path!r}, "wb") if {xyz_path!r} else None

def sink(p, f):
    count[0] += len(p)
    hashes.setdefault("xyz", hashlib.sha256()).update(p.tobytes())
    if xyz_file is not None:
        p.tofile(xyz_file)
    for k in sorted(f):
        hashes.setdefault(k, hashlib.sha256()).update(f[k].tobytes())

t0 = time.perf_counter()
# progress lines for whoever watches a long run (BENCH_HECTARE_LOG: a file to append to)
log = open(os.environ.get("BENCH_HECTARE_LOG", os.devnull), "a")
def progress(f, m):
    log.write(f"{{time.strftime('%H:%M:%S')}} {{{executor!r}}} sectors {{{sectors!r}}}: "
              f"{{f:.3f}} {{m}}\n")
    log.flush()
r = scan_plot(plot, stations, params, sink=sink, executor={executor!r}, workers={workers!r},
              threads={threads!r}, sectors={sectors!r}, progress=progress)
wall = time.perf_counter() - t0
if xyz_file is not None:
    xyz_file.close()
stop.set()
peak[0] = max(peak[0], tree_rss())
digest = hashlib.sha256("".join(k + h.hexdigest() for k, h in sorted(hashes.items())).encode())
pulse = hashlib.sha256("".join(k + hashes[k].hexdigest() for k in PULSE if k in hashes).encode())
print("RESULT " + json.dumps({{
    "executor": {executor!r}, "sectors": {sectors!r}, "pulse_digest": pulse.hexdigest(),
    "time_s": wall, "peak_rss_bytes": peak[0], "points": count[0],
    "digest": digest.hexdigest(), "loading": r.loading, "trees_build_s": r.trees_build_s,
    "stations": [s.to_dict() for s in r.station_stats],
}}))
"""


_MEMORY_CHILD = r"""
import json, sys
from dataclasses import replace
sys.path.insert(0, {root!r})
from treesim.params import ScanParams
from treesim.plot import Plot
from treesim.plot.io import read_plot
from treesim.plot.scan import plot_stations, scan_plot
from treesim.scan import ScannerSpec
import open3d  # noqa: F401  (imported before the measurement starts)

def status(key):
    with open("/proc/self/status") as fh:
        return next(int(x.split()[1]) * 1024 for x in fh if x.startswith(key))

plot = read_plot({plot_dir!r})
if not {trees!r}:
    plot = Plot([], terrain=plot.terrain, radius_m=plot.radius_m, centre_xy=plot.centre_xy,
                facets=plot.facets, terrain_cell_m=plot.terrain_cell_m)
spec = ScannerSpec(horizontal_resolution_deg={step!r}, vertical_resolution_deg={step!r})
params = replace(ScanParams(), scanner=spec, max_rays=10**12)
if {chunk!r}:
    params = replace(params, chunk_rays={chunk!r})
stations = plot_stations(plot, positions={positions!r})
before = status("VmRSS:")
r = scan_plot(plot, stations, params, sink=lambda p, f: None, cache_triangles=0, threads=1)
print("RESULT " + json.dumps({{"before": before, "peak": status("VmHWM:"),
      "triangles": r.loading[0]["triangles_loaded"], "time_s": r.total_s}}))
"""


def run_memory(
    plot_dir: Path, position: tuple, step: float, trees: bool, chunk: int | None = None
) -> dict:
    """One station in a fresh process (inline, no tree kept): its peak over its resident
    memory before the scan, with the plot's trees or with the ground only; ``chunk``: rays
    per batch (None: the default)."""
    code = _MEMORY_CHILD.format(
        root=str(ROOT), plot_dir=str(plot_dir), trees=trees, step=step, positions=[position],
        chunk=chunk,
    )  # fmt: skip
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise SystemExit(f"the memory case failed:\n{p.stderr[-3000:]}")
    line = next(x for x in p.stdout.splitlines() if x.startswith("RESULT "))
    return json.loads(line[len("RESULT ") :])


#: Rays per batch of the second memory measurement: an eighth of the default, so that the
#: batch's own buffers (their hits' gathered corners, normals and ranges, which a scan
#: with trees fills more than one of the ground alone) hardly count.
SMALL_CHUNK_RAYS = 1 << 16


def measure_memory(
    plot_dir: Path, position: tuple, step: float, repeats: int
) -> tuple[float, float]:
    """Bytes per tree triangle while casting: one station (the first) in a fresh process,
    with the trees and with the ground only, the difference over the trees' triangles; at
    the default batch of rays and at :data:`SMALL_CHUNK_RAYS`, ``repeats`` times (the
    peaks move by a few MiB from run to run: the allocator's leftovers). At the default
    batch the difference holds the batch's extra buffers for the trees' hits, which do
    not grow with the triangles; the small batch's is what a triangle costs. Prints each
    and returns the small batch's median and the default batch's ground-only part plus
    those extra buffers (what does not grow with the trees)."""
    runs = []
    for _ in range(max(1, repeats)):
        row = {}
        for chunk in (None, SMALL_CHUNK_RAYS):
            with_trees = run_memory(plot_dir, position, step, True, chunk)
            ground = run_memory(plot_dir, position, step, False, chunk)
            cost = [m["peak"] - m["before"] for m in (with_trees, ground)]
            tree_tri = with_trees["triangles"] - ground["triangles"]
            row[chunk] = ((cost[0] - cost[1]) / tree_tri, float(cost[0]), float(cost[1]), tree_tri)
            print(
                f"one station, fresh process, no tree kept, "
                f"{'default batch' if chunk is None else f'batches of {chunk:,} rays'}: "
                f"{cost[0] / 2**30:.2f} GiB over its start with the trees "
                f"({with_trees['triangles'] / 1e6:.2f} M triangles), {cost[1] / 2**30:.2f} GiB "
                f"with the ground only ({ground['triangles'] / 1e3:.0f} k triangles): "
                f"{row[chunk][0]:.0f} B per tree triangle while casting"
            )
        small, full = row[SMALL_CHUNK_RAYS], row[None]
        # the default batch's extra buffers for the trees' hits: its peak with the trees
        # over what the small batch's per-triangle cost explains, above the ground's
        extra = max(0.0, full[1] - small[0] * small[3] - full[2])
        runs.append((small[0], full[2] + extra, full[0]))
    per = sorted(r[0] for r in runs)
    mid = statistics.median(per)
    print(
        f"B per tree triangle while casting, batches of {SMALL_CHUNK_RAYS:,} rays, over "
        f"{len(runs)} measurement(s): median {mid:.0f}, range {per[0]:.0f}-{per[-1]:.0f} "
        f"(the default batch: median {statistics.median(r[2] for r in runs):.0f}, its extra "
        "buffers for the trees' hits counted per triangle at this size)"
    )
    return mid, statistics.median(r[1] for r in runs)


#: The fields that say which pulse, which return, which surface and which tree: a
#: station's sectors give these bit for bit (the points may move microns where a ray meets
#: a shared edge: see ``treesim.plot.sectors``).
PULSE_FIELDS = (
    "station", "scan_line", "scan_column", "time_s", "return_number", "number_of_returns",
    "label", "tree_id",
)  # fmt: skip


def run_case(
    plot_dir: Path,
    positions: list,
    step: float,
    executor: str,
    workers: int | None,
    threads: int,
    sectors: int = 1,
    xyz_path: Path | None = None,
) -> dict:
    """One case in a fresh process (``xyz_path``: its points' coordinates written there,
    float64, in order)."""
    code = _CHILD.format(
        root=str(ROOT),
        plot_dir=str(plot_dir),
        positions=positions,
        step=step,
        executor=executor,
        workers=workers,
        threads=threads,
        sectors=sectors,
        pulse_fields=PULSE_FIELDS,
        xyz_path=str(xyz_path) if xyz_path else "",
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise SystemExit(f"the {executor} case failed:\n{p.stderr[-3000:]}")
    line = next(x for x in p.stdout.splitlines() if x.startswith("RESULT "))
    return json.loads(line[len("RESULT ") :])


def bytes_per_triangle(r: dict) -> float | None:
    """Peak bytes per loaded triangle (see the module notes)."""
    ld = [x for x in r["loading"] if x.get("rss_peak_bytes") and x["triangles_loaded"]]
    if not ld:
        return None
    if r["executor"] == "inline":
        top = max(x["triangles_loaded"] for x in ld)
        return (max(x["rss_peak_bytes"] for x in ld) - ld[0]["rss_before_bytes"]) / top
    return max((x["rss_peak_bytes"] - x["rss_before_bytes"]) / x["triangles_loaded"] for x in ld)


def grid_positions(n: int, radius_m: float) -> list[tuple[float, float]]:
    """``n`` stations on a square grid over the plot's inner half, row by row."""
    side = math.ceil(math.sqrt(n))
    if side == 1:
        return [(0.0, 0.0)]
    xs = [-0.5 * radius_m + radius_m * i / (side - 1) for i in range(side)]
    return [(x, y) for y in xs for x in xs][:n]


def report(r: dict, label: str) -> None:
    ld = r["loading"]
    tri = [x["triangles_loaded"] for x in ld]
    bpt = bytes_per_triangle(r)
    rays = sum(s["rays_cast"] for s in r["stations"])
    print(
        f"{label:44} {r['time_s']:8.1f} s  peak RSS {r['peak_rss_bytes'] / 2**30:6.2f} GiB "
        f"(children included)  points {r['points']:>12,}  rays {rays:>12,}"
    )
    print(
        f"{'':44} triangles loaded per station {min(tri) / 1e6:.2f}-{max(tri) / 1e6:.2f} M "
        f"of {ld[0]['triangles_total'] / 1e6:.2f} M; peak bytes per loaded triangle "
        + ("n/a" if bpt is None else f"{bpt:.0f} B")
    )


def extrapolate(r: dict, step: float, full: dict, per_tri: tuple[float, float]) -> None:
    """The issue's full size from this run's rates: an extrapolation, not a measurement."""
    ld, st = r["loading"], r["stations"]
    total_tri = ld[0]["triangles_total"]
    bpt = bytes_per_triangle(r) or float("nan")
    cast_s = sum(s["time_s"] for s in st)
    rays = max(1, sum(s["rays_cast"] for s in st))
    # with sectors a station loads each sector's triangles in turn (a tree two sectors
    # share twice): its set-up is over all of them
    loaded = max(1, sum(sum(x.get("sector_triangles_loaded", [x["triangles_loaded"]])) for x in ld))
    # a station's time besides its cast (reading its trees, its scene, its caster) per
    # loaded triangle; the trees' building (once each) per triangle
    setup_per_tri = max(0.0, sum(x["time_s"] for x in ld) - cast_s) / loaded
    build_per_tri = r["trees_build_s"] / total_tri if r["trees_build_s"] else 0.0
    full_tri = full["trees"] * full["triangles_per_tree"]
    rays_full = rays / len(st) * (step / full["step_deg"]) ** 2
    station_s = setup_per_tri * full_tri + cast_s / rays * rays_full
    per, fixed = per_tri
    pulses = (step / full["step_deg"]) ** 2
    print(
        f"extrapolation (not measured) to {full['trees']} trees x "
        f"{full['triangles_per_tree'] / 1e3:.0f} k triangles, {full['stations']} stations at "
        f"{full['step_deg']} deg, every station loading every tree: {full_tri / 1e6:.0f} M "
        f"triangles a station -> {per * full_tri / 2**30:.0f} GiB per station at {per:.0f} B "
        f"a triangle, plus what does not grow with the trees (the ground's part and the "
        f"default batch's buffers, {fixed / 2**30:.2f} GiB here) grown with the pulses "
        f"(x{pulses:.0f}): ~{(per * full_tri + fixed * pulses) / 2**30:.0f} GiB "
        f"(at 150 B a triangle: {(150 * full_tri + fixed * pulses) / 2**30:.0f} GiB). "
        f"The task runs' peak over their start: {bpt:.0f} B a loaded triangle (all in). "
        f"~{rays_full / 1e6:.0f} M rays a station; on this host's rates ~"
        f"{station_s / 3600:.1f} h a station (one thread) and "
        f"~{build_per_tri * full_tri / 3600:.1f} h of building the trees, spread over the "
        f"workers (building {build_per_tri * 1e6:.1f} s per M triangles, casting "
        f"{rays / max(cast_s, 1e-9) / 1e6:.2f} M rays/s, a station's set-up "
        f"{setup_per_tri * 1e6:.1f} s per M triangles)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trees", type=int, default=40)
    ap.add_argument("--stations", type=int, default=4)
    ap.add_argument("--step-deg", type=float, default=0.2)
    ap.add_argument("--executor", choices=["inline", "local", "dask"], default="dask")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1, help="threads per station task")
    ap.add_argument("--facets", type=int, default=32)
    ap.add_argument("--radius-m", type=float, default=HECTARE_RADIUS_M)
    ap.add_argument("--memory-repeats", type=int, default=1)
    ap.add_argument("--memory-only", action="store_true")
    ap.add_argument("--sectors", type=int, default=1, help="azimuth sectors a station")
    ap.add_argument(
        "--docs-part", default=DOCS_PART,
        help="the part of docs/validation.md --docs writes (bench-hectare-full: a full-size run)",
    )  # fmt: skip
    ap.add_argument(
        "--no-whole", action="store_true",
        help="with --sectors, skip the one-scene-a-station run they are compared with",
    )  # fmt: skip
    ap.add_argument(
        "--no-memory", action="store_true",
        help="skip the bytes-per-triangle measurement (a station alone, fresh processes)",
    )  # fmt: skip
    ap.add_argument("--docs", action="store_true")
    a = ap.parse_args()
    with docs_part.recording(a.docs_part if a.docs else None, "bench_hectare.py"):
        _run(a)


def run_cases(a: argparse.Namespace, folder: Path, positions: list) -> dict:
    """The case asked for; with an executor, the one-process run with the same sectors
    (bit for bit); with sectors (unless ``--no-whole``), the one-process run with one scene a
    station, its pulses compared and its points' distances measured. Returns each case's
    result by (executor, sectors)."""
    n = a.sectors
    cases = [(a.executor, a.workers if a.executor != "inline" else None, n)]
    if a.executor != "inline":
        cases.append(("inline", None, n))
    whole = n > 1 and not a.no_whole
    if whole:
        cases.append(("inline", None, 1))
    out = {}
    for ex, w, sec in cases:
        xyz = folder / f"xyz-{ex}-{sec}.bin" if whole and ex == "inline" else None
        r = run_case(folder, positions, a.step_deg, ex, w, a.threads, sec, xyz)
        out[(ex, sec)] = r
        label = f"{ex} ({w} workers)" if w else f"{ex} (one process)"
        report(r, label + (f", {sec} sectors" if sec > 1 else ", one scene a station"))
    if a.executor != "inline":
        same = out[(a.executor, n)]["digest"] == out[("inline", n)]["digest"]
        print(
            f"merged points of {a.executor} equal the one-process run with the same sectors: "
            f"{'yes' if same else 'NO'} (SHA-256 of coordinates and every field, station "
            f"order; {out[('inline', n)]['points']:,} points)"
        )
    if whole:
        s, o = out[("inline", n)], out[("inline", 1)]
        pulses = s["pulse_digest"] == o["pulse_digest"] and s["points"] == o["points"]
        print(
            f"{n} sectors against one scene a station: the same pulses, returns, labels and "
            f"tree ids: {'yes' if pulses else 'NO'} (SHA-256 of {', '.join(PULSE_FIELDS)}); "
            + (xyz_differences(folder / f"xyz-inline-{n}.bin", folder / "xyz-inline-1.bin"))
        )
    return out


def xyz_differences(a: Path, b: Path) -> str:
    """How many points of two runs' coordinate files (float64, in order) differ, and by
    how much at most (m), read a chunk at a time."""
    import numpy as np

    ma = np.memmap(a, dtype=np.float64, mode="r").reshape(-1, 3)
    mb = np.memmap(b, dtype=np.float64, mode="r").reshape(-1, 3)
    if ma.shape != mb.shape:
        return f"the points differ in number ({len(ma):,} against {len(mb):,})"
    moved, most = 0, 0.0
    for i in range(0, len(ma), 1 << 22):
        d = np.linalg.norm(np.asarray(ma[i : i + (1 << 22)]) - mb[i : i + (1 << 22)], axis=1)
        moved += int(np.count_nonzero(d))
        most = max(most, float(d.max()) if len(d) else 0.0)
    return (
        f"points at other coordinates: {moved:,} of {len(ma):,} "
        f"({moved / max(1, len(ma)):.2e}), at most {most * 1e6:.2f} µm away"
    )


def _run(a: argparse.Namespace) -> None:
    from treesim.plot.generate import generate_stand
    from treesim.plot.io import write_plot

    stems = a.trees / (math.pi * a.radius_m**2 / 10_000.0)

    def stand(folder: str, facets: int):
        plot, stand = generate_stand("aspen:0.6,balsam-fir:0.4", stems, a.radius_m, seed=1,
                                     facets=facets)  # fmt: skip
        write_plot(Path(folder) / "plot.toml", plot, stand=stand)
        return plot

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        plot = stand(tmp, a.facets)
        positions = grid_positions(a.stations, a.radius_m)
        print(
            f"stand: {len(plot.trees)} trees (aspen:0.6,balsam-fir:0.4, seed 1) in "
            f"{a.radius_m:.2f} m ({math.pi * a.radius_m**2 / 1e4:.2f} ha), {a.facets} facets, "
            f"flat ground; {len(positions)} stations on a grid at 1.5 m; {a.step_deg} deg; "
            f"{os.cpu_count()} cores; {a.threads} thread(s) per station task"
        )
        if a.memory_only:
            measure_memory(Path(tmp), positions[0], a.step_deg, a.memory_repeats)
            return
        out = run_cases(a, Path(tmp), positions)
        per_tri = None
        if not a.no_memory:
            per_tri = measure_memory(Path(tmp), positions[0], a.step_deg, a.memory_repeats)
        print(f"(the stand and every case: {time.perf_counter() - t0:.1f} s of wall time)")
        full = {"trees": 300, "triangles_per_tree": 500_000, "stations": 9, "step_deg": 0.04}
        main_case = out[(a.executor, a.sectors)]
        tri = main_case["loading"][0]["triangles_total"]
        ran = (
            len(plot.trees) >= full["trees"]
            and a.step_deg <= full["step_deg"]
            and len(positions) >= full["stations"]
        )
        print(
            f"size run: {len(plot.trees)} trees, {tri / 1e6:.2f} M triangles with the ground, "
            f"{len(positions)} stations at {a.step_deg} deg. The issue's full size "
            f"({full['trees']} trees of several hundred k triangles, "
            f"{full['stations']} stations at {full['step_deg']} deg, within 24 GiB) was "
            + (
                "run: the figures above are measured."
                if ran
                else "NOT run here: the lines below are an extrapolation from this run's "
                "rates, not a measurement."
            )
        )
        if not ran and per_tri is not None:
            extrapolate(main_case, a.step_deg, full, per_tri)


if __name__ == "__main__":
    main()
