"""The committed sweep: ``benchmarks/sweeps/presets.toml`` run into ``benchmarks/sweeps/presets/``.

Runs ``treesim sweep`` on the committed config (two procedural species with exact truth and
the bundled coffee tree; angular step × facets × voxel at the presets' values, and the
presets themselves: 60 points), one point at a time, each in a fresh process. Finished
points are reused (``--fresh`` runs them all again: do that after changing the code, whose
version string does not change). Prints the sweep's wall time, point count and where the
page is; ``sweep.csv``, ``sweep.json`` and ``sweep.html`` are committed, the per-point
artefacts (``points/``, ``trees/``) are not.

Then ``python benchmarks/preset_table.py`` writes the manual's preset table (docs/validation.md) and
``pipeline/data/preset_measurements.txt`` (``treesim run --help``) from ``sweep.json``.

Usage: ``python benchmarks/bench_sweep.py [--fresh] [--repeat N] [--config F] [--out D]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CONFIG = ROOT / "benchmarks" / "sweeps" / "presets.toml"
OUT = ROOT / "benchmarks" / "sweeps" / "presets"


def main() -> int:
    from treesim.cli.progress import BatchProgressBar
    from treesim.sweep import run_sweep

    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--config", default=str(CONFIG))
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--repeat", type=int, help="timings per point (default the config's)")
    ap.add_argument("--fresh", action="store_true", help="run every point again")
    ap.add_argument("--executor", default="inline", choices=["inline", "local", "dask"])
    ap.add_argument("--workers", type=int)
    args = ap.parse_args()
    t0 = time.perf_counter()
    res = run_sweep(
        args.config,
        args.out,
        repeat=args.repeat,
        executor=args.executor,
        workers=args.workers,
        fresh=args.fresh,
        progress=BatchProgressBar(sys.stderr, tty=False, name="sweep", noun="points"),
        say=lambda s: print(f"sweep: {s}", file=sys.stderr, flush=True),
    )
    wall = time.perf_counter() - t0
    ran = res.n_ok - res.n_reused
    print(
        f"{len(res.rows)} points ({len(res.config.trees)} trees × {len(res.config.designs)} "
        f"designs, {len(res.config.parameters)} parameters): {ran} run, {res.n_reused} reused, "
        f"{res.n_failed} failed; wall time {wall:.0f} s on {res.plan.describe()}"
    )
    run_time = sum(r["time_total_s"] or 0 for r in res.rows if not r["reused"])
    if ran:
        print(f"loop time of the points run: {run_time:.0f} s (the rest: process start, truth)")
    print(f"page: {res.html}")
    return 1 if res.n_failed else 0


if __name__ == "__main__":
    sys.exit(main())
