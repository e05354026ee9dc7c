"""``treesim run`` and ``treesim batch`` (registered by ``pipeline.cli``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .errors import InvalidParameterError

#: Flags that set :data:`pipeline.run.SETTINGS` (dest -> setting name).
_FLAG_SETTINGS = {
    "method": "method",
    "stations": "stations",
    "resolution_deg": "resolution_deg",
    "distance_m": "distance_m",
    "height_m": "height_m",
    "facets": "facets",
    "voxel_m": "voxel_m",
    "depth": "depth",
}

_STATION_RULE = """\
Stations: --stations N (default 3) stand evenly on a ring around the tree's centre, the
first on +x, at max(5 m, 1.5 x crown diameter, 0.5 x height) from it (crown diameter and
height from the reconstructed mesh's extent) unless --distance-m is given, 1.5 m above the
tree's lowest point (--height-m).
"""

_CONFIG_HELP = """\
Settings come from the preset (default standard), then the --config TOML file, then the
flags. 'treesim run --print-params [--preset P] [--config F]' prints a complete TOML file
to start from; its tables are [reconstruct] ([reconstruct.prepare], [reconstruct.qsm]),
[scan] ([scan.scanner]: any ScannerSpec field), [compare] and [report].
"""


def _add_settings(p: argparse.ArgumentParser) -> None:
    from .reconstruct import METHODS
    from .run import PRESETS

    g = p.add_argument_group("settings (override the preset and --config)")
    g.add_argument("--preset", choices=list(PRESETS), help="base settings (default standard)")
    g.add_argument("--config", metavar="FILE", help="a TOML file of settings")
    g.add_argument("--method", choices=list(METHODS), help="reconstruction method (default qsm)")
    g.add_argument("--stations", type=int, metavar="N", help="stations on the ring (default 3)")
    g.add_argument(
        "--resolution-deg", type=float, metavar="R", help="scanner angular step (preset)"
    )
    g.add_argument(
        "--distance-m", type=float, help="station distance from the tree (default: the rule)"
    )
    g.add_argument("--height-m", type=float, help="instrument height (default 1.5)")
    g.add_argument("--facets", type=int, help="facets per cylinder ring of the QSM mesh")
    g.add_argument("--voxel-m", type=float, help="voxel size for the field cloud (0: off)")
    g.add_argument("--depth", type=int, help="Poisson octree depth (method poisson)")


def params_from_args(args: argparse.Namespace, *, with_threads: bool = True) -> Any:
    """RunParams from the preset, then ``--config``, then the flags."""
    from .run import apply_settings, load_config, preset

    base = preset(args.preset) if args.preset else None
    params = load_config(args.config, base=base) if args.config else (base or preset("standard"))
    flags = {name: getattr(args, dest) for dest, name in _FLAG_SETTINGS.items()}
    params = apply_settings(params, {k: v for k, v in flags.items() if v is not None})
    if with_threads and getattr(args, "threads", None) is not None:
        params = params.with_threads(args.threads)
    return params


def _fmt(v: Any, scale: float = 1.0, unit: str = "", digits: int = 3) -> str:
    if v is None:
        return "n/a"
    return f"{v * scale:.{digits}g} {unit}".rstrip()


def print_run_summary(result: Any) -> None:
    """Key figures of a run, a few lines, then the report's path."""
    from .report.text import length, percent

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
    print(f"report: {result.report_html.resolve()}")


def cmd_run(args: argparse.Namespace) -> int:
    from .cli import _progress_printer
    from .run import run_tree, to_toml

    params = params_from_args(args)
    if args.print_params:
        sys.stdout.write(to_toml(params))
        return 0
    if not args.cloud:
        raise InvalidParameterError("give the field cloud: treesim run CLOUD -o OUTDIR")
    if not args.output:
        raise InvalidParameterError("give the output folder with -o OUTDIR")
    cloud = Path(args.cloud)
    result = run_tree(cloud, params, args.output, progress=_progress_printer(sys.stderr.isatty()))
    print_run_summary(result)
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from .batch import ProgressBar, run_batch

    params = params_from_args(args, with_threads=False)
    bar = None if args.no_progress else ProgressBar(sys.stderr)
    try:
        result = run_batch(
            args.inputs,
            params,
            args.output,
            executor=args.executor,
            workers=args.workers,
            threads=args.threads,
            scheduler=args.scheduler,
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
    for r in result.rows:
        if r["status"] == "failed":
            print(f"failed {r['id']} ({r['input']}): {r.get('error_class')}: {r.get('error')}")
    n_run = result.n_ok - result.n_reused
    print(
        f"{len(result.rows)} trees: {n_run} run, {result.n_reused} unchanged (not run again), "
        f"{result.n_failed} failed, in {result.elapsed_s:.1f} s on {result.plan.describe()}"
    )
    print(f"summary: {result.summary_csv.resolve()} (and summary.json)")
    print(f"index: {result.index_html.resolve()}")
    return 1 if result.n_failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``batch`` to ``treesim``'s parser."""
    from .run import PRESET_MEASUREMENTS

    rp = sub.add_parser(
        "run",
        help="the whole loop on one tree: reconstruct, scan, compare, report",
        description="Reconstruct a tree mesh from a field cloud, scan it with the virtual "
        "scanner, compare the simulated cloud with the mesh and with the field cloud, and "
        "write every artefact, run.json and report.html into OUTDIR.",
        epilog=PRESET_MEASUREMENTS + "\n" + _STATION_RULE + "\n" + _CONFIG_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rp.add_argument("cloud", nargs="?", metavar="CLOUD", help="the field point cloud of one tree")
    rp.add_argument("-o", "--output", metavar="OUTDIR", help="output folder")
    _add_settings(rp)
    rp.add_argument(
        "--threads", type=int, metavar="N", help="threads for every stage (default: all cores)"
    )
    rp.add_argument(
        "--print-params", action="store_true", help="print the settings as TOML and exit"
    )
    rp.set_defaults(func=cmd_run)

    bp = sub.add_parser(
        "batch",
        help="run the loop on many trees (resumable; local processes or Dask)",
        description="Run the whole loop on every tree in INPUTS (cloud files, folders of "
        "clouds, or CSV manifests with a 'path' column and per-tree settings in columns "
        "named like the flags: method, resolution_deg, stations, distance_m, height_m, "
        "facets, voxel_m, depth). Each tree goes to OUTDIR/trees/<id>/; summary.csv, "
        "summary.json and index.html list them all. Trees already finished with the same "
        "file and settings are not run again, so an interrupted batch resumes.",
        epilog=_CONFIG_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    bp.add_argument("inputs", nargs="+", metavar="INPUT", help="files, folders or manifests")
    bp.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="batch folder")
    _add_settings(bp)
    x = bp.add_argument_group("execution")
    x.add_argument(
        "--executor",
        choices=["inline", "local", "dask"],
        default="local",
        help="inline: this process; local: a process pool (default); dask: a Dask cluster",
    )
    x.add_argument("--workers", type=int, help="worker processes (default one per core)")
    x.add_argument("--threads", type=int, help="threads per tree (default cores // workers)")
    x.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a running Dask scheduler (default: a local cluster); with --executor dask",
    )
    x.add_argument("--no-progress", action="store_true", help="no progress output on stderr")
    bp.set_defaults(func=cmd_batch)
