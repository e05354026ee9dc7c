"""``treesim report``: plots, report.json and an offline HTML page from a comparison."""

from __future__ import annotations

import argparse

from ..errors import InvalidParameterError
from ..params import ReportParams, merge
from ._options import collect, param_options
from ._outputs import output_folder


def cmd_report(args: argparse.Namespace) -> int:
    from ..report import build_report

    if args.comparison and args.outdir_in:
        raise InvalidParameterError("give either OUTDIR or --comparison FILE, not both")
    source = args.comparison or args.outdir_in
    if not source:
        raise InvalidParameterError(
            "give the folder 'treesim compare' wrote (OUTDIR) or --comparison comparison.json"
        )
    if args.output:
        output_folder(args.output)
    params = merge(ReportParams(), collect(args))
    files = build_report(source, args.output, params=params)
    print(
        f"wrote {files['report_html']}, {files['report_json'].name} and "
        f"{len(files) - 2} plots in {files['report_html'].parent}"
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``report`` to ``treesim``'s parser."""
    rp = sub.add_parser(
        "report",
        help="plots, report.json and an offline HTML page from a comparison",
        description="Draw the report of a comparison: report.json, PNG plots and one "
        "self-contained HTML page with an interactive 3D view.",
    )
    rp.add_argument(
        "outdir_in", nargs="?", metavar="OUTDIR", help="the folder 'treesim compare' wrote"
    )
    rp.add_argument("--comparison", metavar="FILE", help="a comparison.json (instead of OUTDIR)")
    rp.add_argument(
        "-o", "--output", metavar="DIR", help="where to write (default: beside comparison.json)"
    )
    g = rp.add_argument_group("report")
    param_options(g, ReportParams, exclude=("level",))  # which reports a run draws
    rp.set_defaults(func=cmd_report)
