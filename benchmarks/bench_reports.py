"""A run's time spent on science and on its reports (issue 25): ``treesim demo`` per stage.

    python benchmarks/bench_reports.py                     # this code: demo, --report levels
    python benchmarks/bench_reports.py --baseline 847b160  # and a revision's demo beside it
    python benchmarks/bench_reports.py --docs              # write docs/validation.md's table

Each run is a fresh ``treesim`` process on the bundled coffee tree (as ``treesim demo``:
the standard preset, the tree's TreeQSM model beside it), so that importing the drawing
libraries counts where a user pays for it. Printed per run: the stage times of its
``run.json`` (wall clock), the reports' share of the whole run, the CPU seconds of the
report stage's drawing on the run's own thread (``report CPU s``: what the load moves
least), the process's CPU seconds (its drawing processes included) and the machine's load
when it started; then, drawn again in this process from the demo's output, the CPU seconds
of each figure. Work that a run's report stage hands to threads of its own (each PNG's
encoding and writing, the occlusion profile's numbers) counts in ``CPU s``, not in
``report CPU s``; the per-figure table draws and encodes each figure in turn. A baseline
revision (``--baseline``) is unpacked with ``git archive`` and run the same way,
alternating with this code's runs. On a shared machine the load moves every time; compare
runs made together.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import docs_part  # noqa: E402

SAMPLE = ROOT / "pipeline" / "data" / "coffee_tree"
STAGES = ("read", "reconstruct", "scan", "compare_mesh", "compare_field", "report")


def _child_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


#: Runs the CLI with the report stage's drawing (``treesim.run._draw_reports``) timed on
#: the CPU clock of the run's own thread: on a shared machine its wall time moves with the
#: load, its CPU time much less (drawing processes, where there are any, are not counted).
_CLI = """
import json, os, sys, time
import treesim.run as run
from treesim.cli import main
draw = getattr(run, "_draw_reports", None)
if draw is not None:
    def timed(*a, **k):
        t0 = time.thread_time()
        try:
            return draw(*a, **k)
        finally:
            with open(os.environ["BENCH_REPORT_CPU"], "w") as fh:
                json.dump(time.thread_time() - t0, fh)
    run._draw_reports = timed
sys.argv = ["treesim", *sys.argv[1:]]
sys.exit(main())
"""


def _treesim(args: list[str], pythonpath: Path | None = None) -> tuple[dict, float, float, float]:
    """Run the ``treesim`` CLI with ``ARGS`` in a fresh process: its run.json, its CPU
    seconds (children included), the one-minute load when it started and the CPU seconds
    of its report stage's drawing (NaN where not measured)."""
    env = dict(os.environ)
    if pythonpath is not None:  # a baseline revision's package ahead of the installed one
        env["PYTHONPATH"] = f"{pythonpath}{os.pathsep}{env.get('PYTHONPATH', '')}"
    out = Path(args[args.index("-o") + 1])
    stage_cpu = out.parent / f"{out.name}.report_cpu.json"
    stage_cpu.unlink(missing_ok=True)
    env["BENCH_REPORT_CPU"] = str(stage_cpu)
    load = os.getloadavg()[0]
    cpu0 = _child_cpu_s()
    done = subprocess.run(
        [sys.executable, "-c", _CLI, *args],
        env=env,
        capture_output=True,
        text=True,
        cwd=tempfile.gettempdir(),
    )
    if done.returncode:
        raise SystemExit(f"treesim {' '.join(args)} failed:\n{done.stderr}")
    report_cpu = json.loads(stage_cpu.read_text()) if stage_cpu.is_file() else float("nan")
    run_json = json.loads((out / "run.json").read_text())
    return run_json, _child_cpu_s() - cpu0, load, report_cpu


def _baseline(rev: str, into: Path) -> Path:
    """A folder whose ``treesim`` package is revision ``rev``'s ``pipeline/``."""
    into.mkdir(parents=True, exist_ok=True)
    tar = into / "rev.tar"
    with open(tar, "wb") as fh:
        subprocess.run(["git", "archive", rev, "pipeline"], cwd=ROOT, check=True, stdout=fh)
    with tarfile.open(tar) as t:
        t.extractall(into, filter="data")
    (into / "pipeline").rename(into / "treesim")
    return into


def _row(name: str, run: dict, cpu_s: float, load: float, report_cpu: float) -> list[str]:
    t = run["timings_s"]
    share = 100.0 * t["report"] / t["total"]
    drawing = run.get("report_drawing") or {}
    n = drawing.get("processes", 2 if drawing.get("forked") else 0)  # "forked": before 2026-11
    how = f" ({n} drawing process{'es' if n > 1 else ''})" if n else ""
    return [
        f"{name}{how}",
        f"{t['total']:.1f}",
        *(f"{t.get(s, 0.0):.2f}" for s in STAGES),
        f"{share:.0f} %",
        f"{report_cpu:.2f}",
        f"{cpu_s:.1f}",
        f"{load:.1f}",
    ]


def _figures_cpu(folder: Path) -> list[tuple[str, float]]:
    """CPU seconds of each figure of the demo's reports, drawn again here (warm), into a
    temporary folder removed afterwards."""
    with tempfile.TemporaryDirectory(prefix="bench_reports_") as tmp:
        return _figures_cpu_in(folder, Path(tmp))


def _figures_cpu_in(folder: Path, out: Path) -> list[tuple[str, float]]:
    """:func:`_figures_cpu`, its PNGs drawn into ``out``."""
    import numpy as np

    from treesim.report import ReportParams, figures
    from treesim.report.data import ReportData
    from treesim.report.profile import occlusion_profile

    p = ReportParams()
    rows: list[tuple[str, float]] = []

    def clock(name: str, fn) -> None:  # noqa: ANN001
        t0 = time.process_time()
        fn()
        rows.append((name, time.process_time() - t0))

    import scipy.spatial  # noqa: F401 - imported by the comparisons before a run's reports

    warm = ReportData.from_file(folder / "vs_field")
    figures.coverage_bars(warm, out / "warm.png", dpi=p.dpi)  # first use: fonts, imports
    for key in ("vs_mesh", "vs_field"):
        t0 = time.process_time()
        d = ReportData.from_file(folder / key)
        rows.append((f"{key}: read the distance clouds", time.process_time() - t0))
        t0 = time.process_time()
        prof = occlusion_profile(d)
        rows.append((f"{key}: occlusion profile (numbers)", time.process_time() - t0))
        s = d.summary
        clock(f"{key}: histograms", lambda d=d: figures.histograms(d, out / "h.png", dpi=p.dpi))
        clock(f"{key}: cumulative", lambda d=d: figures.cumulative(d, out / "c.png", dpi=p.dpi))
        clock(
            f"{key}: views (accuracy)",
            lambda d=d, s=s: figures.views(
                d.cloud_points,
                d.cloud_distance_m,
                figures.accuracy_colour_limit(s),
                out / "va.png",
                title="accuracy",
                colour_label="distance",
                origin=d.origin,
                dpi=p.dpi,
            ),
        )
        clock(
            f"{key}: views (completeness)",
            lambda d=d, s=s: figures.views(
                d.reference_points,
                d.reference_distance_m,
                figures.completeness_colour_limit(s),
                out / "vc.png",
                title="completeness",
                colour_label="distance",
                origin=d.origin,
                tau_m=float(s["tolerance_m"]),
                dpi=p.dpi,
            ),
        )
        clock(f"{key}: coverage", lambda d=d: figures.coverage_bars(d, out / "cv.png", dpi=p.dpi))
        clock(
            f"{key}: occlusion",
            lambda pr=prof: figures.occlusion_profile(pr, out / "o.png", ref_word="x", dpi=p.dpi),
        )
    clock(
        "clouds side by side",
        lambda: figures.clouds_side_by_side(
            [
                ("field cloud", warm.reference_points, figures.FIELD_COLOUR),
                ("simulated cloud", warm.cloud_points, figures.SIMULATED_COLOUR),
            ],
            out / "clouds.png",
            origin=np.zeros(3),
            dpi=p.dpi,
        ),
    )
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="runs of each (default 1)")
    parser.add_argument("--baseline", metavar="REV", help="also run this git revision's demo")
    parser.add_argument("--no-levels", action="store_true", help="the demo only")
    parser.add_argument("--docs", action="store_true", help="write docs/validation.md's part")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_reports_") as tmp_s:
        tmp = Path(tmp_s)
        base = _baseline(args.baseline, tmp / "base") if args.baseline else None
        cloud, qsm = SAMPLE / "cloud.txt", SAMPLE / "QSM_treeqsm_v2.4.1_cylinders.csv"
        variants: list[tuple[str, list[str], Path | None]] = []
        for i in range(args.repeat):
            variants.append(("demo", ["demo", "-o", str(tmp / f"demo{i}")], None))
            if base is not None:
                name = f"demo at {args.baseline}"
                variants.append((name, ["demo", "-o", str(tmp / f"base{i}")], base))
            if not args.no_levels:
                for level in ("summary", "none"):
                    cmd = ["run", str(cloud), "--reference-qsm", str(qsm), "--report", level]
                    variants.append((f"run --report {level}", [*cmd, "-o", str(tmp / level)], None))
        rows = [_row(name, *_treesim(a, pp)) for name, a, pp in variants]
        figs = _figures_cpu(tmp / "demo0")
    head = ["run", "total s", *(f"{s.replace('_', ' ')} s" for s in STAGES)]
    head += ["reports' share", "report CPU s", "CPU s", "load"]
    with docs_part.recording("bench-reports" if args.docs else None, "bench_reports.py"):
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for r in rows:
            print("| " + " | ".join(r) + " |")
        print()
        print(
            "CPU seconds of each figure of the demo's reports, drawn again in one warm process "
            "from the saved files (as `treesim report`: a run takes the distance clouds and "
            "the stations' distances from memory):"
        )
        print()
        print("| figure | CPU s |")
        print("|---|---|")
        for name, s in figs:
            print(f"| {name} | {s:.2f} |")
        print(f"| all | {sum(s for _, s in figs):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
