"""``treesim sweep``: a grid of settings on trees, timed and scored; the trade measured."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from ._options import execution, whole_number
from ._outputs import output_folder
from .run import report_option

if TYPE_CHECKING:
    from ..sweep import SweepConfig


def _list(cfg: SweepConfig) -> int:
    from ..sweep.engine import point_id

    print(
        f"{cfg.name}: {len(cfg.trees)} trees × {len(cfg.designs)} designs = "
        f"{len(cfg.trees) * len(cfg.designs)} points; preset {cfg.preset}; "
        f"repeat {cfg.repeat}; τ "
        + (
            f"{cfg.tolerance_m:g} m"
            if cfg.tolerance_m is not None
            else f"{cfg.tolerance_factor:g} × the coarsest reference's point spacing"
        )
    )
    for t in cfg.trees:
        print(f"tree {t.id}: {t.source}")
    for d in cfg.designs:
        vals = ", ".join(f"{k}={v}" for k, v in cfg.values_of(d).items())
        label = f" [{', '.join(d.labels)}]" if d.labels else ""
        ids = " ".join(point_id(t.id, d) for t in cfg.trees)
        print(f"design {d.index}{label}: {vals}  ({ids})")
    return 0


def _with_report_level(cfg: SweepConfig, args: argparse.Namespace) -> SweepConfig:
    """``cfg`` with every design drawing the ``--report`` level given (a level changes
    no figure, but a point run at another level is run again, into the same folder)."""
    level = getattr(args, "param:report.level", None)
    if level is None:
        return cfg
    designs = [
        replace(d, params=replace(d.params, report=replace(d.params.report, level=level)))
        for d in cfg.designs
    ]
    return replace(cfg, designs=type(cfg.designs)(designs))


def cmd_sweep(args: argparse.Namespace) -> int:
    from ..sweep import load_sweep, run_sweep
    from .progress import BatchProgressBar

    if not args.list and not args.output:
        args._parser.error("the following arguments are required: -o/--output")
    if args.output:
        output_folder(args.output)
    cfg = _with_report_level(load_sweep(args.config), args)
    if args.list:
        return _list(cfg if args.repeat is None else replace(cfg, repeat=args.repeat))
    bar = (
        None
        if args.no_progress
        else BatchProgressBar(sys.stderr, tty=False, name="sweep", noun="points")
    )

    def say(text: str) -> None:
        if not args.no_progress:
            print(f"sweep: {text}", file=sys.stderr, flush=True)

    try:
        result = run_sweep(
            cfg,
            args.output,
            repeat=args.repeat,
            **execution(args),
            fresh=args.fresh,
            progress=bar,
            say=say,
        )
    except KeyboardInterrupt:
        out = Path(args.output)
        print(
            f"treesim: interrupted; finished points are kept in {out}/points and listed in "
            f"{out}/sweep.csv; run the same command again to finish the rest",
            file=sys.stderr,
        )
        return 130
    for r in result.rows:
        if r["status"] == "failed":
            print(f"failed {r['id']}: {r.get('error_class')}: {r.get('error')}")
    print(
        f"{result.tally('points')}, in {result.elapsed_s:.1f} s on {result.plan.describe()}; "
        f"τ = {result.tolerance['tolerance_m'] * 1000:.3g} mm"
    )
    print(f"table: {result.csv.resolve()} (and sweep.json)")
    print(f"page: {result.html.resolve()}")
    return 1 if result.n_failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``sweep`` to ``treesim``'s parser."""
    sp = sub.add_parser(
        "sweep",
        help="run a grid of settings on trees: time, memory, accuracy, Pareto fronts",
        description="Run every design of the grid (or list) in CONFIG on every tree in it "
        "(procedural species with exact truth, field clouds, or both) and record per point "
        "the wall time per stage, peak memory, points, rays and the accuracy figures "
        "(AVOHD both ways against the truth mesh, the field cloud and the scanned mesh; "
        "coverage at one τ; DBH, height and volume errors against the truth). Writes "
        "OUTDIR/sweep.csv, sweep.json and sweep.html (accuracy against time with the "
        "Pareto fronts, each parameter alone, the table). Points already finished with "
        "the same tree, settings and version are not run again.",
        epilog="The CONFIG format: see 'pydoc treesim.sweep' or the manual (docs/commands/"
        "sweep.md); 'treesim sweep CONFIG --list' shows the points it expands to.",
    )
    sp.add_argument("config", metavar="CONFIG", help="the sweep file (TOML)")
    sp.add_argument("-o", "--output", metavar="OUTDIR", help="the sweep's folder")
    sp.add_argument(
        "--repeat",
        type=whole_number(1),
        metavar="N",
        help="timings per point, each in a fresh process (default: the file's repeat, or 1); "
        "finished points get only the missing timings",
    )
    sp.add_argument("--list", action="store_true", help="list the points and exit")
    report_option(sp)
    sp.add_argument(
        "--fresh",
        action="store_true",
        help="make the trees ready and run every point again (after changing the code)",
    )
    x = sp.add_argument_group("execution")
    x.add_argument(
        "--executor",
        choices=["inline", "local", "dask"],
        default="inline",
        help="inline: one point at a time (default; the cleanest timings); local: a process "
        "pool; dask: a Dask cluster. Every point runs in a fresh process of its own",
    )
    x.add_argument(
        "--workers",
        type=whole_number(1),
        help="points at once (local, dask; default one per core)",
    )
    x.add_argument(
        "--threads", type=whole_number(1), help="threads per point (default cores // workers)"
    )
    x.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a running Dask scheduler (default: a local cluster); with --executor dask",
    )
    x.add_argument("--no-progress", action="store_true", help="no progress output on stderr")
    sp.set_defaults(func=cmd_sweep, _parser=sp)
