"""``treesim plan``: where to put the scanner, how often, to measure the trees well enough."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..errors import InvalidParameterError
from ..params import INSTRUMENTS, SETTINGS, ScannerSpec, merge
from ..params.models import ModelParams
from ..plan.params import DEFAULT_INSTRUMENT
from ._options import (
    collect,
    number_type,
    param_option,
    param_options,
    station_task_options,
)
from ._outputs import output_folder
from .progress import print_warnings, progress_printer


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``plan`` to ``treesim``'s parser."""
    from ..plan.params import PlanParams

    p = sub.add_parser(
        "plan",
        help="plan scan stations for a plot or a tree: fewest stations to a per-tree goal",
        description="Choose scanner stations from a grid of candidates over a plot (or "
        "around one tree) so that every tree meets a goal (coverage of its surface at a "
        "tolerance, the DBH band seen over an arc) within a budget (stations, field time); "
        "compare with the classic layouts (ring of 3, centre+3, 5-scan cross, grids) and "
        "verify with a full-resolution scan. Writes plan.json, stations.csv, map.png and "
        "curve.png into -o.",
    )
    p.add_argument("mesh", nargs="?", metavar="MESH", help="one tree as a mesh file")
    p.add_argument("-o", "--output", metavar="OUTDIR", required=True)
    g = p.add_argument_group("what to plan for (one of)")
    g.add_argument("--plot", metavar="PLOT.toml", help="a plot file (trees and terrain)")
    param_option(g, ModelParams, "species", path=("tree",), metavar="NAME")
    param_options(g, ModelParams, ["seed", "leaves", "facets"], path=("tree",))
    g.add_argument(
        "--radius-m",
        type=float,
        metavar="M",
        help="one tree: radius of the candidate area around it (m; default 1.5 × the "
        "station rule's distance)",
    )
    s = p.add_argument_group("scanner")
    s.add_argument(
        "--instrument",
        choices=list(INSTRUMENTS),
        default=DEFAULT_INSTRUMENT,
        help=f"the instrument: field of view, ranges, measurement rate and set-up time "
        f"(default {DEFAULT_INSTRUMENT})",
    )
    s.add_argument(
        "--resolution-deg",
        type=number_type(SETTINGS["resolution_deg"].info),
        metavar="DEG",
        help="angular step of the field scans, both axes (deg; default the instrument's): "
        "sets the visibility rule's point spacing, the field time and the verification scans",
    )
    goal = p.add_argument_group("goal")
    param_options(
        goal,
        PlanParams,
        ["goal_coverage", "tolerance_m", "dbh_arc_deg", "dbh_band_m", "arc_bin_deg"],
        path=("plan",),
    )
    b = p.add_argument_group("budget")
    param_options(b, PlanParams, ["max_stations", "max_field_time_min"], path=("plan",))
    w = p.add_argument_group("wind (the stations are still chosen for a still tree)")
    param_options(w, PlanParams, ["wind_speed_m_s"], path=("plan",))
    c = p.add_argument_group("candidates, samples, baselines")
    param_options(
        c,
        PlanParams,
        [
            "candidate_spacing_m",
            "height_m",
            "clearance_m",
            "samples_per_tree",
            "band_samples",
            "sample_seed",
            "local_search",
            "ring_distance_m",
            "grid_spacings_m",
            "verify",
            "threads",
        ],
        path=("plan",),
    )
    _verification_options(p)
    p.set_defaults(func=cmd_plan)


def _verification_options(p: argparse.ArgumentParser) -> None:
    """Where the verification scans' stations run (as ``treesim plot scan``'s)."""
    x = p.add_argument_group("verification's execution")
    station_task_options(
        x,
        "the verification scans' stations",
        "the same verified figures; the planning itself runs here",
    )


def load_plot(path: str | Path) -> Any:
    """A plot from a plot file (``plot.toml`` and its trees, :func:`treesim.plot.io.read_plot`)."""
    from ..plot.io import read_plot

    p = Path(path)
    if not p.exists():
        raise InvalidParameterError(f"--plot {p}: no such file")
    return read_plot(p)


def _target(args: argparse.Namespace, tree: dict[str, Any]) -> tuple[Any, bool, dict[str, Any]]:
    from ..plan.sources import mesh_tree_plot, model_tree_plot

    given = [
        n
        for n, v in (("--plot", args.plot), ("--species", tree.get("species")), ("MESH", args.mesh))
        if v
    ]
    if len(given) != 1:
        raise InvalidParameterError(
            "give one of --plot PLOT.toml, --species NAME or MESH"
            + (f" (got {', '.join(given)})" if given else "")
        )
    if args.radius_m is not None and not args.radius_m > 0:
        raise InvalidParameterError(f"--radius-m must be > 0, got {args.radius_m}")
    if args.plot:
        if args.radius_m is not None:
            raise InvalidParameterError("--radius-m is for one tree; a plot has its own radius")
        return load_plot(args.plot), False, {"plot": str(args.plot)}
    if args.mesh:
        return mesh_tree_plot(args.mesh, radius_m=args.radius_m), True, {"mesh": str(args.mesh)}
    plot, what = model_tree_plot(merge(ModelParams(), tree), radius_m=args.radius_m)
    return plot, True, what


def cmd_plan(args: argparse.Namespace) -> int:
    from ..params import instrument
    from ..plan import plan_scans
    from ..plan.outputs import PLAN_FILES, write_plan
    from ..plan.params import PlanParams

    out = output_folder(args.output, files=PLAN_FILES)
    given = collect(args)
    params = merge(PlanParams(), given.get("plan", {}))
    inst = instrument(args.instrument)
    spec: ScannerSpec = inst.spec()
    if args.resolution_deg is not None:
        spec = spec.with_(
            horizontal_resolution_deg=args.resolution_deg,
            vertical_resolution_deg=args.resolution_deg,
        )
    plot, single, what = _target(args, given.get("tree", {}))
    result = plan_scans(
        plot,
        spec=spec,
        instrument=inst,
        params=params,
        progress=progress_printer(label="plan"),
        single_tree=single,
        executor=args.executor,
        workers=args.workers,
        scheduler=args.scheduler,
        cache_dir=args.cache_dir,
        sectors=args.sectors or 1,
    )
    inputs = {**what, "instrument": inst.name, "resolution_deg": spec.horizontal_resolution_deg}
    paths = write_plan(result, out, inputs=inputs)
    d = result.to_dict()
    pl = d["plan"]
    print(
        f"{pl['n_stations']} stations, {pl['field_time_min']:.1f} min in the field "
        f"({d['instrument']['station_time_min']:.1f} min each), {pl['trees_meeting_goal']}/"
        f"{pl['trees']} trees meet the goal (predicted); {pl['stop_reason']}"
    )
    print(f"{'#':>3}  {'x (m)':>9}  {'y (m)':>9}  {'z (m)':>8}  {'gain':>8}  {'time (min)':>10}")
    for r in pl["stations"]:
        print(
            f"{r['order']:>3}  {r['x_m']:9.2f}  {r['y_m']:9.2f}  {r['z_m']:8.2f}  "
            f"{r['predicted_gain']:8.3f}  {r['cumulative_field_time_min']:10.1f}"
        )
    cmp_ = d["comparison"]
    print(f"predicted: {cmp_['predicted']['verdict']}: {cmp_['predicted']['statement']}")
    ver = cmp_.get("verified")
    if ver:
        sec = ver["seconds"]
        print(
            f"verified at {spec.horizontal_resolution_deg:g}° (full scans, "
            f"{sec['plan']:.0f} s for the plan"
            + (
                f", {sec['baseline']:.0f} s for {ver['baseline']}"
                if sec["baseline"] is not None
                else ""
            )
            + f"): {ver['plan_trees_meeting_goal']}/{ver['trees']} trees meet the goal with "
            "the plan"
            + (
                f", {ver['baseline_trees_meeting_goal']}/{ver['trees']} with {ver['baseline']}"
                if ver["baseline_trees_meeting_goal"] is not None
                else ""
            )
        )
        print(f"verdict: {cmp_['verdict']}: {cmp_['statement']}")
    wind = d.get("wind")
    for line in wind["summary"] if wind else []:
        print(f"wind: {line}")
    warnings = [
        f"wind: {line}"
        for line in (wind["summary"] if wind else [])
        if "at risk on" in line or "unknown" in line
    ]
    if d["unreachable_trees"]:
        ids = d["unreachable_trees"]
        warnings.append(
            f"{len(ids)} tree(s) cannot reach the goal from any candidate: "
            f"{', '.join(map(str, ids[:20]))}{' ...' if len(ids) > 20 else ''}"
        )
    print_warnings(warnings)
    print(f"wrote {', '.join(str(p) for p in paths.values())}", file=sys.stdout)
    return 0
