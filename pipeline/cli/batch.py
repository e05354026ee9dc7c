"""``treesim batch``: the loop on many trees, resumable, on local processes or Dask."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..params import SETTINGS
from ._options import execution, execution_options
from ._outputs import output_folder
from ._settings import CONFIG_HELP, add_settings, params_from_args
from .progress import print_warnings
from .run import report_option, with_report_level


def cmd_batch(args: argparse.Namespace) -> int:
    from ..batch import run_batch
    from .progress import BatchProgressBar

    output_folder(args.output)
    params = with_report_level(params_from_args(args, with_threads=False), args)
    bar = None if args.no_progress else BatchProgressBar(sys.stderr)
    try:
        result = run_batch(
            args.inputs,
            params,
            args.output,
            **execution(args),
            progress=bar,
        )
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        out = Path(args.output)
        print(
            f"treesim: interrupted; finished trees are kept in {out}/trees and listed in "
            f"{out}/summary.csv; run the same command again to finish the rest",
            file=sys.stderr,
        )
        return 130
    if bar is not None:
        bar.close()
    for p, why in result.skipped_files:
        print(f"skipped {p}: {why}")
    print_warnings(
        [
            f"tree {r['id']}: implausible reconstruction ({r['warnings']}); see its run.json"
            for r in result.rows
            if r.get("warnings")
        ]
    )
    for r in result.rows:
        if r["status"] == "failed":
            print(f"failed {r['id']} ({r['input']}): {r.get('error_class')}: {r.get('error')}")
    print(f"{result.tally('trees')}, in {result.elapsed_s:.1f} s on {result.plan.describe()}")
    print(f"summary: {result.summary_csv.resolve()} (and summary.json)")
    print(f"index: {result.index_html.resolve()}")
    return 1 if result.n_failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``batch`` to ``treesim``'s parser."""
    bp = sub.add_parser(
        "batch",
        help="run the loop on many trees (resumable; local processes or Dask)",
        description="Run the whole loop on every tree in INPUTS (cloud files, folders of "
        "clouds, or CSV manifests with a 'path' column and per-tree settings in columns "
        f"named like the flags: {', '.join(SETTINGS)}). Each tree goes to "
        "OUTDIR/trees/<id>/; summary.csv, summary.json and index.html list them all. "
        "Trees already finished with the same file and settings are not run again, so an "
        "interrupted batch resumes.",
        epilog=CONFIG_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    bp.add_argument("inputs", nargs="+", metavar="INPUT", help="files, folders or manifests")
    bp.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="batch folder")
    add_settings(bp)
    report_option(bp)
    execution_options(bp)
    bp.set_defaults(func=cmd_batch)
