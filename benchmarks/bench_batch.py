"""Batch throughput: trees per minute on 1 and 2 workers, and where the time goes.

Runs ``treesim.run_batch`` on the same trees (``../shared/data/trees/`` when present,
else the bundled coffee tree and four procedural saplings) with the ``local`` executor:

* 1 worker × all cores' threads, then one worker per core × 1 thread (and, with
  ``--dask``, a local Dask cluster of one worker per core): wall time, trees per minute,
  and the scaling ratio against 1 worker;
* the share of the trees' time spent in each stage (read, reconstruct, scan, the two
  comparisons, report), summed over the trees of the 1-worker run;
* the machine's own ceiling: how much faster one pure-Python loop per core runs than one
  loop alone (virtual CPUs that are SMT siblings or share a quota give far less than the
  core count, and no batch can scale beyond it).

Every run writes into a fresh folder (nothing is reused). Measured figures only.

Usage: ``python benchmarks/bench_batch.py [--preset draft] [--dask] [--inputs PATH ...]``.
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SHARED = ROOT.parent / "shared" / "data" / "trees"


def fallback_inputs(folder: Path) -> list[Path]:
    """The bundled coffee tree and four saplings scanned at 0.05° (no shared data)."""
    from treesim.io import write_cloud
    from treesim.models import generate_tree
    from treesim.scan import ScannerSpec, ring_layout, scan
    from treesim.scene import MeshPart, Scene

    paths = [ROOT / "pipeline" / "data" / "coffee_tree" / "cloud.txt"]
    for seed in range(4):
        v, f, _ = generate_tree("sapling", seed=seed, leaves=False).mesh(16)
        scene = Scene([MeshPart(vertices=v, faces=f, label="wood")])
        lo, hi = scene.bounds
        st = ring_layout(
            3,
            distance_m=4.0,
            height_m=1.5,
            centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
            base_z_m=float(lo[2]),
        )
        spec = ScannerSpec(horizontal_resolution_deg=0.05, vertical_resolution_deg=0.05)
        paths.append(write_cloud(folder / f"sapling{seed}.ply", scan(scene, st, spec).cloud))
    return paths


def _loop(n: int) -> float:
    """Pure-Python arithmetic (CPU-bound, cache-resident)."""
    t0 = time.perf_counter()
    x = 0
    for i in range(n):
        x += i
    return time.perf_counter() - t0


def _kdtree(n: int) -> float:
    """k-d tree build and 8-neighbour queries on random points (memory-bound, like most
    of the loop's numerical work)."""
    import numpy as np
    from scipy.spatial import cKDTree

    p = np.random.default_rng(0).random((n, 3))
    t0 = time.perf_counter()
    cKDTree(p).query(p, k=8, workers=1)
    return time.perf_counter() - t0


def hardware_ceiling(processes: int, work: Any, n: int) -> float:
    """Speed-up of ``processes`` copies of ``work(n)`` run at once over one copy alone:
    what the machine's cores give to independent processes (virtual CPUs that share a
    physical core or a host give less than their count)."""
    import multiprocessing as mp

    one = min(work(n) for _ in range(2))
    with mp.get_context("spawn").Pool(processes) as pool:
        pool.map(work, [n // 10] * processes)  # warm the workers up
        t0 = time.perf_counter()
        pool.map(work, [n] * processes)
        both = time.perf_counter() - t0
    return processes * one / both


def main() -> int:
    from treesim._system import cpu_count
    from treesim.batch import run_batch
    from treesim.executors import detect_available
    from treesim.params import run_preset as preset
    from treesim.run import STAGES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="draft", choices=["draft", "standard", "fine"])
    ap.add_argument("--dask", action="store_true", help="also a local Dask cluster")
    ap.add_argument("--inputs", nargs="*", help="clouds or folders (default: shared trees)")
    args = ap.parse_args()
    cores = cpu_count()
    params = preset(args.preset)
    with tempfile.TemporaryDirectory() as tmp:
        if args.inputs:
            inputs = [Path(p) for p in args.inputs]
        elif SHARED.is_dir():
            inputs = [SHARED]
        else:
            inputs = fallback_inputs(Path(tmp))
        configs = [("local", 1), ("local", cores)]
        if args.dask and any(e.value == "dask" for e in detect_available()):
            configs.append(("dask", cores))
        print(
            f"# {time.strftime('%Y-%m-%d')}, {platform.machine()} {cores} cores, "
            f"Python {platform.python_version()}, preset {args.preset}"
        )
        print(
            f"# hardware ceiling on {cores} processes (throughput vs one process): "
            f"pure-Python loop {hardware_ceiling(cores, _loop, 20_000_000):.2f}×, "
            f"k-d tree queries {hardware_ceiling(cores, _kdtree, 400_000):.2f}×"
        )
        results = {}
        for kind, workers in configs:
            out = Path(tmp) / f"{kind}-{workers}"
            t0 = time.perf_counter()
            res = run_batch(inputs, params, out, executor=kind, workers=workers)
            wall = time.perf_counter() - t0
            ok = res.n_ok
            results[(kind, workers)] = (wall, res)
            base = results[("local", 1)][0]
            print(
                f"{kind:6} {workers} worker(s) × {res.plan.threads} thread(s): {ok} trees "
                f"({res.n_failed} failed) in {wall:6.1f} s = {60 * ok / wall:5.2f} trees/min; "
                f"speed-up vs 1 worker {base / wall:4.2f}×",
                flush=True,
            )
        wall1, res1 = results[("local", 1)]
        rows = [r for r in res1.rows if r["status"] == "ok"]
        total = sum(r["time_total_s"] for r in rows)
        print(f"\ntime per stage (1 worker, {len(rows)} trees, {total:.1f} s of tree time):")
        for stage in STAGES:
            t = sum(r[f"time_{stage}_s"] for r in rows)
            print(f"  {stage:14} {t:7.1f} s  {100 * t / total:5.1f} %")
        print("\nper tree (1 worker):")
        for r in rows:
            parts = " ".join(f"{s}={r[f'time_{s}_s']:.1f}" for s in STAGES)
            print(f"  {r['id']:22} {r['time_total_s']:6.1f} s  ({parts})")
    return 0


if __name__ == "__main__":
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("bench-batch"), "bench_batch.py"):
        rc = main()
    sys.exit(rc)
