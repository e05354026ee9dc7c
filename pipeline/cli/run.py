"""``treesim run``: the whole loop on one tree."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..errors import InvalidParameterError
from ..params import ReportParams, RunParams, ScannerSpec, preset_measurements, to_toml
from ._options import param_option
from ._outputs import output_folder
from ._settings import CONFIG_HELP, STATION_RULE, add_settings, params_from_args
from .progress import print_warnings, progress_printer


def _fmt(v: Any, scale: float = 1.0, unit: str = "", digits: int = 3) -> str:
    if v is None:
        return "n/a"
    return f"{v * scale:.{digits}g} {unit}".rstrip()


def print_run_summary(result: Any) -> None:
    """Key figures of a run, a few lines, then the report's path."""
    from ..report.text import length, percent

    s = result.summary
    rec, sc = s["reconstruction"], s["scan"]
    rule = sc["station_rule"]
    spec = s["parameters"]["scan"]["scanner"]
    print(
        f"{s['name']}: {rec.get('points_input', 0):,} field points -> "
        f"{s['parameters']['reconstruct']['method']}: DBH {_fmt(rec.get('dbh_m'), 100, 'cm')}, "
        f"height {_fmt(rec.get('height_m'), 1, 'm')}, "
        f"wood volume {_fmt(rec.get('volume_total_m3'), 1000, 'L')}, "
        f"{rec.get('n_cylinders') or 0:,} cylinders, {rec.get('n_triangles') or 0:,} triangles"
    )
    ref = s.get("reference_qsm")
    if ref:
        f = ref["figures"]
        print(
            f"reference QSM {Path(ref['path']).name}: DBH {_fmt(f.get('dbh_m'), 100, 'cm')}, "
            f"height {_fmt(f.get('height_m'), 1, 'm')}, "
            f"wood volume {_fmt(f.get('volume_total_m3'), 1000, 'L')}, "
            f"{f.get('n_cylinders') or 0:,} cylinders"
        )
    print(
        f"scan: {rule['n_stations']} stations {rule['distance_m']:.1f} m out, "
        f"{spec['horizontal_resolution_deg']:g}° steps: {sc['points']:,} points"
    )
    for key, what in (("vs_mesh", "vs mesh: "), ("vs_field", "vs field:")):
        c = s[key]
        print(
            f"{what} accuracy p95 {length(c['accuracy']['p95_m'])}, "
            f"completeness p95 {length(c['completeness']['p95_m'])}, "
            f"coverage {percent(c['coverage'])} within {length(c['tolerance_m'])}, "
            f"Chamfer {length(c['chamfer_m'])}"
        )
    t = s["timings_s"]
    parts = ", ".join(
        f"{k.replace('_', ' ')} {t[k]:.1f}"
        for k in ("reconstruct", "scan", "compare_mesh", "compare_field", "report")
    )
    print(f"time: {t['total']:.1f} s ({parts})")
    print_warnings([w["message"] for w in rec.get("warnings", [])])  # implausible tree
    print_warnings(sc.get("warnings", []))
    print(f"report: {result.report_html.resolve()}")


def report_option(parser: argparse.ArgumentParser) -> None:
    """``--report auto|none|summary|full``: which reports to draw
    (:attr:`treesim.params.ReportParams.level`)."""
    param_option(parser, ReportParams, "level", path=("report",), flag="--report")


def with_report_level(params: RunParams, args: argparse.Namespace) -> RunParams:
    """``params`` with the ``--report`` level and ``--wind-speed-m-s`` given (unchanged
    without them)."""
    level = getattr(args, "param:report.level", None)
    if level is not None:
        params = replace(params, report=replace(params.report, level=level))
    wind = getattr(args, "param:scan.scanner.wind_speed_m_s", None)
    if wind is not None:  # sways the reconstruction by its own table (treesim.run.run_wind)
        spec = params.scan.scanner.with_(wind_speed_m_s=wind)
        params = replace(params, scan=replace(params.scan, scanner=spec))
    return params


def cmd_run(args: argparse.Namespace) -> int:
    from ..run import run_tree

    params = with_report_level(params_from_args(args), args)
    if args.print_params:
        sys.stdout.write(to_toml(params))
        return 0
    if not args.cloud:
        raise InvalidParameterError("give the field cloud: treesim run CLOUD -o OUTDIR")
    if not args.output:
        raise InvalidParameterError("give the output folder with -o OUTDIR")
    output_folder(args.output)
    cloud = Path(args.cloud)
    result = run_tree(
        cloud,
        params,
        args.output,
        reference_qsm=args.reference_qsm,
        progress=progress_printer(label="run"),
    )
    print_run_summary(result)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``run`` to ``treesim``'s parser."""

    rp = sub.add_parser(
        "run",
        help="the whole loop on one tree: reconstruct, scan, compare, report",
        description="Reconstruct a tree mesh from a field cloud, scan it with the virtual "
        "scanner, compare the simulated cloud with the mesh and with the field cloud, and "
        "write every artefact, run.json and report.html into OUTDIR.",
        epilog=preset_measurements() + "\n" + STATION_RULE + "\n" + CONFIG_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rp.add_argument("cloud", nargs="?", metavar="CLOUD", help="the field point cloud of one tree")
    rp.add_argument("-o", "--output", metavar="OUTDIR", help="output folder")
    rp.add_argument(
        "--reference-qsm",
        metavar="CSV",
        help="a QSM of the same tree made elsewhere (TreeQSM or SimpleForest cylinder "
        "table): its DBH, height and volumes are shown beside the reconstruction's",
    )
    add_settings(rp)
    param_option(rp, RunParams, "threads", metavar="N")
    report_option(rp)
    param_option(rp, ScannerSpec, "wind_speed_m_s", path=("scan", "scanner"), metavar="U")
    rp.add_argument(
        "--print-params", action="store_true", help="print the settings as TOML and exit"
    )
    rp.set_defaults(func=cmd_run)
