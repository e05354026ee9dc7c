"""Streaming point cloud writers: time and memory for a scanner-sized cloud.

Writes a 5M-point cloud with the scanner's fields (station, range_m, incidence_deg, label,
return_number, number_of_returns, intensity, scan_line, scan_column) through
:func:`treesim.io.open_cloud_writer` in 1M-point chunks, each made just before it is
written (as the scanner does), in a fresh process per case:

1. LAZ with lazrs on one core (``threads=1``, ``LazBackend.Lazrs``);
2. LAZ with lazrs on all cores (``threads=0``, ``LazBackend.LazrsParallel``);
3. PLY.

For each: wall and CPU seconds (all threads) in ``write`` and ``close`` (making the
chunks not counted), file size, and the growth of peak RSS (max RSS of the process) from
just before the writer is opened (one chunk already made) to after it is closed.

Usage: ``python benchmarks/bench_writers.py [--points N] [--chunk N]``. Prints measured
figures only, with the load average around them (other processes on the machine take
cores from the parallel compressor).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from treesim.io import open_cloud_writer  # noqa: E402
from treesim.scan import SCAN_FIELDS  # noqa: E402

#: The scanner's fields, as a scan writes them.
FIELDS = dict(SCAN_FIELDS)

CASES = {
    "LAZ, Lazrs (1 core)": ("scan.laz", 1),
    "LAZ, LazrsParallel (all cores)": ("scan.laz", 0),
    "PLY": ("scan.ply", 0),
}


def make_chunk(index: int, n: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Chunk ``index`` of a georeferenced scan: (n, 3) points and the scanner's fields."""
    rng = np.random.default_rng(index)
    origin = np.array([500_000.0, 5_500_000.0, 300.0])
    points = origin + rng.uniform(0.0, 40.0, (n, 3))
    returns = rng.integers(1, 4, n)
    fields = {
        "station": np.full(n, index % 3),
        "range_m": rng.uniform(0.5, 60.0, n),
        "incidence_deg": rng.uniform(0.0, 90.0, n),
        "label": rng.integers(0, 4, n),
        "return_number": rng.integers(1, returns + 1),
        "number_of_returns": returns,
        "intensity": rng.integers(0, 65536, n),
        "scan_line": np.full(n, index),
        "scan_column": np.arange(n),
    }
    return points, {k: v.astype(FIELDS[k]) for k, v in fields.items()}


def cpu_seconds() -> float:
    """User + system CPU time of this process so far, all its threads."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def max_rss_bytes() -> int:
    """Peak resident memory of this process so far (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def run_case(name: str, total: int, chunk: int, folder: Path) -> dict:
    """Write the cloud for one case in this process; return its figures."""
    filename, threads = CASES[name]
    path = folder / filename
    chunks = [(i, min(chunk, total - start)) for i, start in enumerate(range(0, total, chunk))]
    next_chunk = make_chunk(*chunks[0])
    base = max_rss_bytes()
    seconds = cpu = 0.0
    writer = open_cloud_writer(
        path,
        fields=FIELDS,
        origin_hint_m=[500_000.0, 5_500_000.0, 300.0],
        threads=threads,
    )
    with writer:
        for k in range(len(chunks)):
            points, fields = next_chunk
            next_chunk = None  # the writer's caller holds one chunk at a time
            t0, c0 = time.perf_counter(), cpu_seconds()
            writer.write(points, fields)
            seconds += time.perf_counter() - t0
            cpu += cpu_seconds() - c0
            del points, fields
            next_chunk = make_chunk(*chunks[k + 1]) if k + 1 < len(chunks) else None
        backend = getattr(writer, "laz_backend", None)
        t0, c0 = time.perf_counter(), cpu_seconds()
    seconds += time.perf_counter() - t0  # close: the last batch, header, rename
    cpu += cpu_seconds() - c0
    return {
        "seconds": seconds,
        "cpu_seconds": cpu,
        "points": writer.points_written,
        "bytes": path.stat().st_size,
        "rss_growth": max_rss_bytes() - base,
        "backend": None if backend is None else backend.name,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=5_000_000)
    parser.add_argument("--chunk", type=int, default=1_000_000)
    parser.add_argument("--case", choices=list(CASES), help=argparse.SUPPRESS)
    args = parser.parse_args()

    if args.case:  # child process: one case, JSON on stdout
        with tempfile.TemporaryDirectory() as folder:
            print(json.dumps(run_case(args.case, args.points, args.chunk, Path(folder))))
        return

    import laspy

    try:
        lazrs_version = importlib.metadata.version("lazrs")
    except importlib.metadata.PackageNotFoundError:
        lazrs_version = "not installed"
    print(f"date: {datetime.datetime.now().isoformat(timespec='seconds')}")
    print(f"os.cpu_count(): {os.cpu_count()}")
    print("load average (1, 5, 15 min) before: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    print(f"laspy {laspy.__version__}, lazrs {lazrs_version}")
    print(f"cloud: {args.points:,} points in chunks of {args.chunk:,}, fields: {', '.join(FIELDS)}")
    print()
    print(
        f"{'case':32s} {'wall s':>7s} {'CPU s':>7s} {'Mpts/s':>7s} {'MB':>7s} "
        f"{'peak RSS +MiB':>14s}  backend"
    )
    for name in CASES:
        out = subprocess.run(
            [sys.executable, __file__, "--case", name]
            + ["--points", str(args.points), "--chunk", str(args.chunk)],
            check=True,
            capture_output=True,
            text=True,
        )
        r = json.loads(out.stdout.strip().splitlines()[-1])
        assert r["points"] == args.points
        print(
            f"{name:32s} {r['seconds']:7.2f} {r['cpu_seconds']:7.2f} "
            f"{r['points'] / r['seconds'] / 1e6:7.2f} "
            f"{r['bytes'] / 1e6:7.1f} {r['rss_growth'] / 2**20:14.0f}  {r['backend'] or '-'}"
        )

    print("load average (1, 5, 15 min) after: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))


if __name__ == "__main__":
    main()
