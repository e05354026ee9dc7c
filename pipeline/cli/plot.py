"""``treesim plot``: forest plots.

* ``treesim plot generate --species aspen:0.6,balsam-fir:0.4 --stems-per-ha 600
  --radius-m 15 --seed 1 -o plot/``: a synthetic stand (``plot.toml``, ``trees.csv``,
  ``map.png``);
* ``treesim plot scan plot.toml -o out/ [scanner options]``: scan it station by station
  (only the trees each station can record are loaded) and measure every tree in the
  plot's context (``plot_scan.laz`` with ``tree_id``, ``plot_scan.json``,
  ``tree_figures.csv``);
* ``treesim plot from-cloud PLOT.laz|PLOT.e57 -o twin/``: a field plot's cloud becomes a
  digital twin (ground and DTM, stems, trees, a QSM per tree, ``plot.toml``, a report);
  ``treesim plot from-cloud A.laz B.laz field/ -o twins/``: many plots, each twin in
  ``twins/<plot>/``, ``plots.csv`` and ``plots.json``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InvalidParameterError
from ..params import CompareParams, RunParams, ScannerSpec, ScanParams
from ..plot.generate import StandParams
from ._options import (
    collect,
    execution,
    execution_options,
    floats_type,
    number_type,
    param_option,
    param_options,
    station_task_options,
    whole_number,
)
from ._outputs import output_folder
from .progress import print_warnings, progress_printer

if TYPE_CHECKING:  # named only: the twin's stages are imported when the command runs
    from ..twin import TwinParams, TwinResult


def _terrain(args: argparse.Namespace, sp: StandParams):
    from ..plot import Terrain

    kind = args.terrain or ("slope" if sp.slope_deg else "flat")
    path = None
    if args.terrain_path:
        path = str(Path(args.terrain_path).resolve())
    return Terrain(kind=kind, slope_deg=sp.slope_deg, aspect_deg=sp.aspect_deg, path=path)


def cmd_generate(args: argparse.Namespace) -> int:
    from ..params import merge
    from ..plot.generate import write_map
    from ..plot.io import PLOT_FILE, write_plot

    sp = merge(StandParams(), collect(args))
    radius = sp.radius_m
    out = output_folder(args.output, files=[PLOT_FILE, "trees.csv", "map.png"])
    plot, stand = sp.generate(_terrain(args, sp))
    out.mkdir(parents=True, exist_ok=True)
    path = write_plot(out / PLOT_FILE, plot, stand=stand)
    files = [path, out / "trees.csv"]
    if not args.no_map:
        files.append(write_map(out / "map.png", plot))
    per = ", ".join(f"{k} {v['trees']}" for k, v in stand["species"].items())
    dbh = [t.dbh_m for t in plot.trees]
    hts = [t.height_m for t in plot.trees]
    print(
        f"{len(plot.trees)} trees ({per}) in a {radius:g} m plot "
        f"({stand['count_rule']} count of {stand['expected_trees']:.1f} expected)"
    )
    if dbh:
        print(
            f"DBH {min(dbh) * 100:.1f}-{max(dbh) * 100:.1f} cm (mean "
            f"{sum(dbh) / len(dbh) * 100:.1f}), height {min(hts):.1f}-{max(hts):.1f} m; "
            f"min distance {stand['min_distance_rule']}"
            + (f", relaxed {stand['relaxations']}x" if stand["relaxations"] else "")
        )
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def cmd_scan(args: argparse.Namespace) -> int:
    from ..params import merge
    from ..plot.io import read_plot
    from ..plot.scan import PLOT_SCAN_FILES, plot_scan_files, plot_stations, read_stations
    from .scan import params_from_args

    plot = read_plot(args.plot)
    if args.facets:
        plot.facets = int(args.facets)
    cloud_name = f"plot_scan{args.format}"
    out = output_folder(
        args.output, files=[cloud_name, PLOT_SCAN_FILES["json"], PLOT_SCAN_FILES["trees"]]
    )
    # τ is the comparison's, not the scan's: taken out before the scan's flags are read
    tol = vars(args).pop("param:tolerance_m", None)
    compare = merge(CompareParams(), {} if tol is None else {"tolerance_m": tol})
    params, threads = params_from_args(args)
    if params.distance_m is not None and params.distance_m < 0:
        raise InvalidParameterError("--distance-m must be >= 0")
    if args.full_fov:
        raise InvalidParameterError("--full-fov is not offered for plots; drop it")
    given = [
        f for f, v in (("--station", args.station), ("--stations-from", args.stations_from)) if v
    ]
    if len(given) > 1:
        raise InvalidParameterError(f"give either {' or '.join(given)}, not both")
    if args.stations_from:
        stations = read_stations(args.stations_from, plot, height_m=params.height_m)
    else:
        stations = plot_stations(
            plot,
            positions=args.station or None,
            n=params.n_stations,
            distance_m=params.distance_m,
            height_m=params.height_m,
        )
    step = plot_scan_files(
        plot,
        out,
        params,
        stations=stations,
        compare=compare,
        cloud_name=cloud_name,
        figures=not args.no_figures,
        threads=threads,
        progress=progress_printer(label="plot scan"),
        executor=args.executor,
        workers=args.workers,
        scheduler=args.scheduler,
        cache_dir=args.cache_dir,
        sectors=args.sectors or 1,
    )
    res = step.result
    print(
        f"{'station':>7}  {'position (m)':>28}  {'trees':>5}  {'triangles loaded':>16}"
        f"  {'points':>10}  {'time (s)':>8}"
    )
    for s, ld in zip(res.station_stats, res.loading, strict=True):
        pos = ", ".join(f"{c:.2f}" for c in s.position_m)
        share = ld["triangles_loaded"] / max(1, ld["triangles_total"])
        print(
            f"{s.index:>7}  {pos:>28}  {len(ld['trees_loaded']):>5}  "
            f"{ld['triangles_loaded']:>9,} ({share:4.0%})  {s.points:>10,}  {s.time_s:>8.2f}"
        )
    rows = step.details["trees"]
    if rows:
        cov = [r["coverage"] for r in rows]
        low = sorted(rows, key=lambda r: r["coverage"])[:3]
        print(
            f"{len(rows)} trees: coverage {min(cov):.2f}-{max(cov):.2f} (mean "
            f"{sum(cov) / len(cov):.2f}); lowest: "
            + ", ".join(f"tree {r['tree_id']} {r['coverage']:.2f}" for r in low)
        )
    print(f"total: {res.n_points:,} points in {res.total_s:.1f} s")
    print_warnings(res.warnings)
    print("wrote " + ", ".join(str(p) for p in step.outputs.values()))
    return 0


def cmd_from_cloud(args: argparse.Namespace) -> int:
    from ..params import merge
    from ..twin import TwinParams

    tp = merge(TwinParams(), collect(args))
    clouds = list(args.cloud)
    if len(clouds) == 1 and not Path(clouds[0]).is_dir():
        return _from_one_cloud(args, clouds[0], tp)
    return _from_many_clouds(args, clouds, tp)


def _print_twin(res: TwinResult, output: str) -> None:
    from ..twin import TWIN_FILES

    print(f"{'tree':>5} {'x (m)':>11} {'y (m)':>11} {'slab DBH':>9} {'QSM DBH':>8} {'height':>7}")
    for r in res.trees:
        qsm = f"{r['qsm_dbh_m'] * 100:6.1f}cm" if r.get("qsm_dbh_m") else "     –  "
        print(
            f"{r['tree_id']:>5} {r['x_m']:>11.2f} {r['y_m']:>11.2f} "
            f"{r['slab_dbh_m'] * 100:7.1f}cm {qsm} "
            + ("     – " if r["height_m"] is None else f"{r['height_m']:6.1f}m")
        )
    for r in res.left_out:
        print(f"left out: stem {r['tree_id']} at ({r['x_m']:.2f}, {r['y_m']:.2f}): {r['reason']}")
    print_warnings(res.warnings)
    print(res.summary_line())
    print(f"twin: {res.plot_file}; report: {Path(output) / TWIN_FILES['report']}")


def _from_one_cloud(args: argparse.Namespace, cloud: str, tp: TwinParams) -> int:
    """One cloud file: its twin directly in -o (a finished one made from the same cloud
    and settings is reused)."""
    import sys

    from ..twin import PLOTS_FILES, TWIN_FILES, finished_twin, plot_from_cloud
    from .progress import BatchProgressBar

    out = output_folder(args.output, files=list(TWIN_FILES.values()))
    if (out / PLOTS_FILES["json"]).is_file():
        raise InvalidParameterError(
            f"{out} holds the twins of many plots ({PLOTS_FILES['json']}); give another -o, "
            f"or {out / Path(cloud).stem} to make this plot's twin again among them"
        )
    res = finished_twin(cloud, args.output, tp)
    if res is not None:
        print(
            f"the twin in {args.output} was made from this cloud with these settings: reused, "
            f"not made again (delete {Path(args.output) / TWIN_FILES['json']} to make it again)"
        )
        _print_twin(res, args.output)
        return 0
    bar = None if args.no_progress else BatchProgressBar(sys.stderr)
    try:
        res = plot_from_cloud(
            cloud,
            args.output,
            tp,
            **execution(args),
            progress=None if args.no_progress else progress_printer(label="from-cloud"),
            batch_progress=bar,
        )
    except KeyboardInterrupt:
        print(
            f"treesim: interrupted; trees reconstructed so far are kept in {args.output}; "
            "run the same command again to finish the rest",
            file=sys.stderr,
        )
        return 130
    finally:
        if bar is not None:
            bar.close()
    _print_twin(res, args.output)
    return 0


def _from_many_clouds(args: argparse.Namespace, clouds: list[str], tp: TwinParams) -> int:
    """Many clouds (or folders): each plot's twin in -o/<id>/, plots.csv and plots.json."""
    import sys

    from ..twin import PLOTS_FILES, plots_from_clouds

    output_folder(args.output, files=list(PLOTS_FILES.values()))
    try:
        res = plots_from_clouds(
            clouds,
            args.output,
            tp,
            **execution(args),
            progress=None if args.no_progress else progress_printer(label="from-cloud"),
        )
    except KeyboardInterrupt:
        print(
            f"treesim: interrupted; the plots finished so far are kept in {args.output} "
            f"(listed in {PLOTS_FILES['csv']}); run the same command again to finish the rest",
            file=sys.stderr,
        )
        return 130
    for path, why in res.skipped_files:
        print(f"skipped: {path} ({why})")
    print(f"{'plot':<24} {'status':<7} {'trees':>5} {'left out':>8} {'time (s)':>9}")
    for r in res.rows:
        trees = "–" if r["trees"] is None else r["trees"]
        left = "–" if r["left_out"] is None else r["left_out"]
        print(f"{r['id']:<24} {r['status']:<7} {trees:>5} {left:>8} {r['time_s']:>9.1f}")
    for pid, warnings in res.warnings.items():
        print_warnings([f"{pid}: {w}" for w in warnings])
    for r in res.failed:
        print(f"failed: {r['id']} ({r['input']}): {r['error_class']}: {r['error']}")
    print(res.summary_line())
    print(f"twins in {args.output}/<plot>/; summary: {res.summary_csv}, {res.summary_json}")
    if res.n_failed:
        print(
            f"treesim: error: {res.n_failed} of {len(res.rows)} plots failed (listed above "
            f"and in {res.summary_csv})",
            file=sys.stderr,
        )
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``plot`` and its subcommands to ``treesim``'s parser."""
    p = sub.add_parser(
        "plot", help="forest plots: generate a stand, make a twin of a field plot, scan a plot"
    )
    psub = p.add_subparsers(dest="plot_command", metavar="SUBCOMMAND", required=True)
    _register_generate(psub)
    _register_from_cloud(psub)
    _register_scan(psub)


def _register_generate(psub: argparse._SubParsersAction) -> None:
    from ..plot import TERRAIN_KINDS

    g = psub.add_parser(
        "generate",
        help="a synthetic stand of procedural trees",
        description="Make a plausible stand: an exact (or Poisson) number of trees from the "
        "stems per hectare, Weibull DBHs, Näslund heights with lognormal noise, positions by "
        "sequential inhibition (see docs/commands/plot.md). Writes plot.toml, trees.csv "
        "and map.png into -o.",
    )
    param_option(g, StandParams, "species", metavar="NAME:SHARE,...", required=True)
    param_options(
        g,
        StandParams,
        ["stems_per_ha", "radius_m", "count", "mean_dbh_m", "weibull_shape", "seed", "facets",
         "leaves", "slope_deg", "aspect_deg"],
    )  # fmt: skip
    g.add_argument("--terrain", choices=TERRAIN_KINDS, help="terrain kind (default flat)")
    g.add_argument(
        "--terrain-path",
        metavar="FILE",
        help="the DTM (.asc) or ground cloud of a dtm/cloud terrain",
    )
    g.add_argument("--no-map", action="store_true", help="do not draw map.png")
    g.add_argument("-o", "--output", required=True, metavar="DIR")
    g.set_defaults(func=cmd_generate)


def _register_from_cloud(psub: argparse._SubParsersAction) -> None:
    fc = psub.add_parser(
        "from-cloud",
        help="field plots' clouds become digital twins",
        description="Classify the ground (cloth simulation filter) and build a DTM; find the "
        "stems and give every point above the ground to its tree; reconstruct each tree (a "
        "QSM) in parallel, resumably; write the twin (plot.toml with the DTM as terrain and "
        "each tree as its QSM with its field cloud), each tree's cloud, the labelled plot "
        "cloud and a report into -o. Trees that fail are listed and left out. Many clouds "
        "(or folders of them): one plot after another, each twin in -o/<plot>/, a row per "
        "plot in plots.csv and plots.json; a plot that fails is listed and the others go "
        "on; a plot made before from the same cloud and settings is reused.",
    )
    fc.add_argument(
        "cloud",
        metavar="CLOUD",
        nargs="+",
        help="a plot's cloud (.laz, .las, .e57, .ply, ...) or a folder of them",
    )
    fc.add_argument("-o", "--output", required=True, metavar="DIR")
    from ..twin import TwinParams

    param_options(fc, TwinParams, ["units", "dtm_cell_m", "min_tree_points", "preset", "facets"])
    execution_options(fc)
    fc.set_defaults(func=cmd_from_cloud)


def _register_scan(psub: argparse._SubParsersAction) -> None:
    s = psub.add_parser(
        "scan",
        help="scan a plot and measure every tree in it",
        description="Scan a plot (plot.toml, or a folder holding one) from stations, one at "
        "a time, loading only the trees each station can record; label every point with "
        "its tree_id; measure each tree's points against its own mesh (coverage, AVOHD). "
        "Writes plot_scan.laz, plot_scan.json and tree_figures.csv into -o.",
    )
    s.add_argument("plot", metavar="PLOT", help="plot.toml or its folder")
    s.add_argument("-o", "--output", required=True, metavar="DIR")
    s.add_argument(
        "--format",
        choices=[".laz", ".las", ".ply"],
        default=".laz",
        help="the cloud's format (default .laz)",
    )
    st = s.add_argument_group("stations")
    st.add_argument(
        "--station",
        action="append",
        default=[],
        metavar="X,Y,Z",
        type=floats_type(3, "--station"),
        help="a station position in plot coordinates (repeatable)",
    )
    st.add_argument(
        "--stations-from",
        "--stations-csv",
        dest="stations_from",
        metavar="FILE",
        help="the field's stations: an E57 file's scan poses, or a CSV with x_m, y_m and "
        "z_m or height_m columns (as treesim plan writes stations.csv)",
    )
    # without --station: a ring around the plot centre at --distance-m (unset: half the
    # plot's radius), --height-m above the terrain
    param_options(st, ScanParams, ["n_stations", "distance_m", "height_m"])
    sc = s.add_argument_group("scanner")
    from ..params import INSTRUMENTS, SETTINGS

    sc.add_argument(
        "--instrument",
        choices=list(INSTRUMENTS),
        help="start from a real instrument's figures (see treesim scan)",
    )
    sc.add_argument("--beam", action="store_true", help="beam divergence model (see treesim scan)")
    sc.add_argument(
        "--noise", action="store_true", help="range noise and jitter (see treesim scan)"
    )
    sc.add_argument(
        "--resolution-deg",
        type=number_type(SETTINGS["resolution_deg"].info),
        metavar="DEG",
        help=f"{SETTINGS['resolution_deg'].help} (deg)",
    )
    param_options(sc, ScannerSpec, path=("scanner",), exclude=("reflectance",))
    param_option(sc, ScanParams, "lod")
    x = s.add_argument_group("execution and figures")
    x.add_argument("--full-fov", action="store_true", help=argparse.SUPPRESS)
    param_options(x, ScanParams, ["max_rays", "chunk_rays"])
    param_option(x, RunParams, "threads")
    x.add_argument(
        "--facets",
        type=whole_number(3),
        metavar="N",
        help="override the plot file's facets per ring",
    )
    param_option(x, CompareParams, "tolerance_m")
    x.add_argument("--no-figures", action="store_true", help="scan only: no per-tree comparison")
    station_task_options(x, "the stations", "the same cloud")
    s.set_defaults(func=cmd_scan)
