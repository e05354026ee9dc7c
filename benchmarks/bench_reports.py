"""A run's time spent on science and on its reports (issue 25): ``treesim demo`` per stage.

    python benchmarks/bench_reports.py                     # this code: demo, --report levels
    python benchmarks/bench_reports.py --baseline 847b160  # and a revision's demo beside it
    python benchmarks/bench_reports.py --docs              # write docs/validation.md's table
    python benchmarks/bench_reports.py --processes 0,1,2   # and the demo with that many
                                                           # drawing processes (0: inline)

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
alternating with this code's runs. With ``--repeat`` above 1, a second table gives each
kind of run's medians and how much longer than ``run --report none`` it took. On a shared
machine the load moves every time; compare runs made together.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
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


def _treesim(
    args: list[str], pythonpath: Path | None = None, processes: int | None = None
) -> tuple[dict, float, float, float]:
    """Run the ``treesim`` CLI with ``ARGS`` in a fresh process (``processes``: drawing
    processes chosen, ``TREESIM_DRAWING_PROCESSES``): its run.json, its CPU seconds
    (children included), the one-minute load when it started and the CPU seconds of its
    report stage's drawing (NaN where not measured)."""
    env = dict(os.environ)
    if processes is not None:
        env["TREESIM_DRAWING_PROCESSES"] = str(processes)
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


def _print_medians(runs: list[tuple[str, tuple[dict, float, float, float]]]) -> None:
    """Per kind of run: the median total, report stage, reports' share and CPU seconds
    (the medians of each column, not of one run), and the median total's excess over
    ``run --report none``'s where that was run."""
    by: dict[str, list[tuple[float, float, float, float]]] = {}
    for name, (run, cpu_s, _load, _report_cpu) in runs:
        name = name.split(" (")[0]
        t = run["timings_s"]
        by.setdefault(name, []).append(
            (t["total"], t["report"], 100.0 * t["report"] / t["total"], cpu_s)
        )
    med = {k: [statistics.median(col) for col in zip(*v, strict=True)] for k, v in by.items()}
    none = med.get("run --report none")
    print(
        "| run | runs | median total s | median report s | median reports' share | "
        "median CPU s | total over `--report none` s |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, (total, report, share, cpu) in med.items():
        over = f"{total - none[0]:+.2f}" if none is not None else "-"
        print(
            f"| {name} | {len(by[name])} | {total:.2f} | {report:.2f} | {share:.1f} % | "
            f"{cpu:.2f} | {over} |"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="runs of each (default 1)")
    parser.add_argument("--baseline", metavar="REV", help="also run this git revision's demo")
    parser.add_argument("--no-levels", action="store_true", help="the demo only")
    parser.add_argument("--docs", action="store_true", help="write docs/validation.md's part")
    parser.add_argument(
        "--processes",
        metavar="N,...",
        help="also run the demo with each of these numbers of drawing processes (0: inline)",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_reports_") as tmp_s:
        tmp = Path(tmp_s)
        base = _baseline(args.baseline, tmp / "base") if args.baseline else None
        cloud, qsm = SAMPLE / "cloud.txt", SAMPLE / "QSM_treeqsm_v2.4.1_cylinders.csv"
        chosen = [int(n) for n in args.processes.split(",")] if args.processes else []
        variants: list[tuple[str, list[str], Path | None, int | None]] = []
        for i in range(args.repeat):
            variants.append(("demo", ["demo", "-o", str(tmp / f"demo{i}")], None, None))
            for n in chosen:
                name = f"demo, TREESIM_DRAWING_PROCESSES={n}"
                variants.append((name, ["demo", "-o", str(tmp / f"p{n}_{i}")], None, n))
            if base is not None:
                name = f"demo at {args.baseline}"
                variants.append((name, ["demo", "-o", str(tmp / f"base{i}")], base, None))
            if not args.no_levels:
                for level in ("summary", "none"):
                    cmd = ["run", str(cloud), "--reference-qsm", str(qsm), "--report", level]
                    out = ["-o", str(tmp / level)]
                    variants.append((f"run --report {level}", [*cmd, *out], None, None))
        runs = [(name, _treesim(a, pp, n)) for name, a, pp, n in variants]
        rows = [_row(name, *got) for name, got in runs]
        figs = _figures_cpu(tmp / "demo0")
    head = ["run", "total s", *(f"{s.replace('_', ' ')} s" for s in STAGES)]
    head += ["reports' share", "report CPU s", "CPU s", "load"]
    with docs_part.recording("bench-reports" if args.docs else None, "bench_reports.py"):
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for r in rows:
            print("| " + " | ".join(r) + " |")
        if args.repeat > 1:
            print()
            _print_medians(runs)
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
