"""One point of a sweep, in a fresh process: ``python -m treesim.sweep.point TASK.json``.

Every point (and every repeat of it) runs in a process of its own, started for it, so
that its peak memory is its own: Linux's peak resident set size (``VmHWM``) of a process
that ran only this point, not the most any earlier point of a long-lived worker needed.
The process

1. imports what a run uses and uses open3d and matplotlib once (:func:`warm_up`), so the
   timed stages hold the loop's own work, not imports and first-use costs, and records its
   resident memory then (``base_rss_mib``);
2. runs :func:`treesim.run.run_tree` on the tree's field cloud with the point's settings
   into the task's folder, then reads its peak resident memory (``peak_rss_mib``: the
   process's high-water mark, imports included, up to the end of the loop);
3. for a tree with a truth mesh (and ``truth`` set), compares the simulated cloud
   (``scan.laz``, as written: 0.1 mm) with the truth mesh at the sweep's τ, both ways, into
   ``vs_truth/comparison.json`` (timed apart: not part of the loop's cost);
4. writes ``point.json`` (timings, memory, the truth comparison's figures) or, on a
   failure, ``error.json`` (class, one-line message, traceback) and exits 1.

It exits by itself when the process that started it dies.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from .._process import exit_with_parent

__all__ = ["main", "peak_rss_mib", "rss_mib", "warm_up"]


def _status_kib(key: str) -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return float(line.split()[1])
    except OSError:
        pass
    return None


def _windows_memory_mib(counter: str) -> float | None:
    """A counter of ``GetProcessMemoryInfo`` for this process (MiB): ``PeakWorkingSetSize``
    or ``WorkingSetSize``, Windows' names for the peak and current resident memory; None
    if the call fails."""
    import ctypes
    from ctypes import wintypes

    class Counters(ctypes.Structure):  # PROCESS_MEMORY_COUNTERS
        _fields_ = [
            ("cb", wintypes.DWORD),
            ("PageFaultCount", wintypes.DWORD),
            ("PeakWorkingSetSize", ctypes.c_size_t),
            ("WorkingSetSize", ctypes.c_size_t),
            ("QuotaPeakPagedPoolUsage", ctypes.c_size_t),
            ("QuotaPagedPoolUsage", ctypes.c_size_t),
            ("QuotaPeakNonPagedPoolUsage", ctypes.c_size_t),
            ("QuotaNonPagedPoolUsage", ctypes.c_size_t),
            ("PagefileUsage", ctypes.c_size_t),
            ("PeakPagefileUsage", ctypes.c_size_t),
        ]

    try:
        kernel32 = ctypes.WinDLL("kernel32")  # type: ignore[attr-defined]
        psapi = ctypes.WinDLL("psapi")  # type: ignore[attr-defined]
        kernel32.GetCurrentProcess.restype = wintypes.HANDLE
        psapi.GetProcessMemoryInfo.argtypes = [
            wintypes.HANDLE,
            ctypes.POINTER(Counters),
            wintypes.DWORD,
        ]
        counters = Counters()
        counters.cb = ctypes.sizeof(Counters)
        if not psapi.GetProcessMemoryInfo(
            kernel32.GetCurrentProcess(), ctypes.byref(counters), counters.cb
        ):
            return None
    except (AttributeError, OSError):
        return None
    return getattr(counters, counter) / (1024 * 1024)


def peak_rss_mib() -> float:
    """This process's peak resident memory (MiB): ``VmHWM`` where Linux has it, else
    ``getrusage``'s ``ru_maxrss`` (which Linux carries from a parent across exec, hence
    not the first choice); on Windows, which has no :mod:`resource`, the peak working
    set. NaN where none of them answers."""
    kib = _status_kib("VmHWM")
    if kib is not None:
        return kib / 1024
    if sys.platform != "win32":
        import resource  # POSIX only

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / (1024 * 1024) if sys.platform == "darwin" else peak / 1024
    peak_mib = _windows_memory_mib("PeakWorkingSetSize")
    return float("nan") if peak_mib is None else peak_mib


def rss_mib() -> float | None:
    """This process's resident memory now (MiB), where the system says (Linux's
    ``VmRSS``, Windows' working set)."""
    kib = _status_kib("VmRSS")
    if kib is None and sys.platform == "win32":
        return _windows_memory_mib("WorkingSetSize")
    return None if kib is None else kib / 1024


def warm_up() -> None:
    """Import everything a run imports and use the lazily loaded libraries once (the
    font cache and text layout of matplotlib, Open3D's raycasting), so that the timed
    region holds the loop's own work. pymeshlab is not loaded: only the surface methods
    use it, and it would add its memory to runs that never do."""
    import matplotlib
    import numpy as np
    import open3d as o3d

    from .. import compare, io, reconstruct, report, run, scan  # noqa: F401
    from ..report.background import draw_once

    matplotlib.rcParams  # noqa: B018 - loads the rc file
    draw_once()
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.geometry.TriangleMesh.create_box())
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    scene.cast_rays(o3d.core.Tensor(np.array([[0.5, 0.5, -1, 0, 0, 1]], dtype=np.float32)))


def run_point(task: dict[str, Any]) -> dict[str, Any]:
    """Run one point as ``task`` says (see :mod:`treesim.sweep.engine`); return what
    ``point.json`` holds."""
    t0 = time.perf_counter()
    warm_up()
    warm_s = time.perf_counter() - t0
    base = rss_mib()

    from dataclasses import replace

    from ..params import params_from_dict, params_hash
    from ..run import run_tree

    params = params_from_dict(task["params"])
    if params_hash(params) != task["params_hash"]:
        raise RuntimeError("the point's settings changed on their way to its process")
    params = params.with_threads(int(task["threads"]))
    out = Path(task["outdir"])
    # report.level auto: the point's pages without plots (its figures are run.json's)
    res = run_tree(task["cloud"], params, out, name=task["name"], report_auto="summary")
    peak = peak_rss_mib()
    result: dict[str, Any] = {
        "kind": "treesim.sweep_point",
        "timings_s": res.summary["timings_s"],
        "peak_rss_mib": peak,
        "base_rss_mib": base,
        "warm_up_s": warm_s,
        "threads": int(task["threads"]),
        "pid": os.getpid(),
    }
    truth_mesh = task.get("truth_mesh")
    if truth_mesh and task.get("truth", True):
        from ..compare import COMPARISON_FIGURES, compare, write_comparison
        from ..io import load_scene, read_cloud

        t1 = time.perf_counter()
        sim = read_cloud(out / "scan.laz")
        scene = load_scene([truth_mesh])
        cp = replace(params.compare, nthreads=int(task["threads"]))
        cmp = compare(sim, scene, params=cp)
        write_comparison(
            cmp,
            out / "vs_truth",
            inputs={"cloud": "../scan.laz", "reference": str(truth_mesh)},
            formats=(),
        )
        result["vs_truth"] = {k: v for k, v in cmp.to_dict().items() if k in COMPARISON_FIGURES}
        result["time_truth_compare_s"] = time.perf_counter() - t1
    return result


def _empty_scan_reason(out: Path) -> str | None:
    """Why the point's scan recorded nothing (its ``scan.json``'s level-of-detail
    account), when it recorded nothing; else None."""
    try:
        scan = json.loads((out / "scan.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if scan.get("points") != 0:
        return None
    from ..report.text import lod_reasons

    why = "; ".join(f"{what}: {reason}" for what, reason in lod_reasons(scan.get("lod")))
    return "the scan recorded no points" + (f" ({why})" if why else "")


def main(argv: list[str] | None = None) -> int:
    """Run the task in ``argv[0]`` (a JSON file); write ``point.json`` or ``error.json``
    into the task's ``outdir``; exit status 0 or 1."""
    args = sys.argv[1:] if argv is None else argv
    task = json.loads(Path(args[0]).read_text(encoding="utf-8"))
    exit_with_parent(int(task["parent_pid"]), interval_s=1.0)  # status 70: the sweep died
    out = Path(task["outdir"])
    out.mkdir(parents=True, exist_ok=True)
    from ..jsonio import write_json

    try:
        result = run_point(task)
    except Exception as exc:  # recorded for the sweep, which goes on
        from ..errors import TreesimError

        text = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, MemoryError):
            text = "out of memory; use coarser settings or fewer workers"
        empty = _empty_scan_reason(out)
        if empty:
            text = f"{empty}; {text}"
        write_json(
            out / "error.json",
            {
                "error_class": type(exc).__name__,
                "error": text,
                "treesim_error": isinstance(exc, TreesimError),
                "traceback": traceback.format_exc(),
                "peak_rss_mib": peak_rss_mib(),
            },
        )
        return 1
    write_json(out / "point.json", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
