"""``treesim reconstruct``: a tree mesh from a field point cloud."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InvalidParameterError
from ..params import PrepareParams, QSMParams, ReconstructParams, merge
from ._options import collect, param_option, param_options
from ._outputs import output_folder
from .progress import print_warnings, progress_printer


def _fmt(v: float | None, scale: float, unit: str, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v * scale:.{digits}f} {unit}"


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``reconstruct`` to ``treesim``'s parser."""
    p = sub.add_parser(
        "reconstruct",
        help="reconstruct a tree mesh from a field point cloud (QSM, Poisson or BPA)",
        description="Turn a single-tree point cloud (LAS, LAZ, PLY, XYZ, TXT, CSV) into a "
        "tree mesh: a cylinder QSM (default), a screened Poisson surface or a ball-pivoting "
        "surface. Writes tree.ply, cylinders.csv (qsm) and tree.json into OUTDIR.",
    )
    p.add_argument("cloud", metavar="CLOUD")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR")
    param_option(p, ReconstructParams, "method")
    p.add_argument("--columns", help="column names of a text cloud, e.g. x,y,z,intensity")
    g = p.add_argument_group("preparation")
    prep = ("prepare",)
    param_options(g, PrepareParams, ["voxel_size_m", "sor_std_ratio"], path=prep)
    g.add_argument(
        "--no-outlier-removal",
        action="store_true",
        help="turn statistical outlier removal off (as --sor-std-ratio none)",
    )
    param_options(g, PrepareParams, ["remove_ground", "remove_understory"], path=prep)
    lv = p.add_argument_group("leaves")
    param_options(lv, ReconstructParams, ["separate_leaves", "leaf_layer", "leaf_side_m"])
    q = p.add_argument_group("qsm")
    param_options(
        q, QSMParams, ["slice_m", "twig_radius_m", "resolve_sigmas", "min_radius_m"], path=("qsm",)
    )
    param_option(q, ReconstructParams, "facets")
    s = p.add_argument_group("surface methods")
    param_options(s, ReconstructParams, ["poisson_depth", "bpa_radii_m", "timeout_s"])
    p.set_defaults(func=cmd_reconstruct)


def params_from_args(args: argparse.Namespace) -> ReconstructParams:
    """ReconstructParams from the model's defaults and the flags."""
    given = collect(args)
    if args.no_outlier_removal:
        given.setdefault("prepare", {})["sor_std_ratio"] = None
    return merge(ReconstructParams(), given)


def cmd_reconstruct(args: argparse.Namespace) -> int:
    from ..reconstruct import OUTPUT_FILES
    from ..steps import reconstruct_files

    output_folder(args.output, files=OUTPUT_FILES.values())
    columns = None
    if args.columns:
        columns = [c.strip() or None for c in args.columns.split(",")]
        if not {"x", "y", "z"} <= {c for c in columns if c}:
            raise InvalidParameterError("--columns must name x, y and z (e.g. x,y,z,intensity)")
    step = reconstruct_files(
        args.cloud,
        params_from_args(args),
        args.output,
        columns=columns,
        progress=progress_printer(label="reconstruct"),
    )
    model, paths = step.result, step.outputs
    fig = model.figures
    print(
        f"{Path(args.cloud).name}: {fig['points_input']:,} points -> {fig['points_used']:,} "
        f"after preparation (spacing {fig['spacing_m'] * 1000:.1f} mm)"
    )
    for step in model.preparation.get("steps", []):
        print(f"  {step['step']}: removed {step['removed']:,}")
    if "points_wood" in fig:
        print(
            f"  leaves separated ({fig['leaf_separation']}): {fig['points_wood']:,} wood, "
            f"{fig['points_leaf']:,} leaf points (labels.laz); "
            f"{fig.get('n_leaves', 0):,} leaves modelled"
        )
    elif fig["leaves_present"]:
        print(
            f"  leaves present: about {fig['leaf_fraction'] * 100:.0f} % of points look leaf-like; "
            "wood volume figures include them as modelled twigs"
        )
    second = model.diagnostics.get("second_opinion")
    if second:
        print(
            f"  second opinion on the leaves ({', '.join(second['why'])} at first): the frond "
            + ("model's separation kept" if second["kept"] else "model's did not help; first kept")
        )
    print(
        f"method {model.method}: DBH {_fmt(fig['dbh_m'], 100, 'cm')}, "
        f"height {_fmt(fig['height_m'], 1, 'm')}, "
        f"volume {_fmt(fig['volume_total_m3'], 1000, 'L')} "
        f"(stem {_fmt(fig['volume_stem_m3'], 1000, 'L')}, "
        f"branches {_fmt(fig['volume_branch_m3'], 1000, 'L')}), "
        f"{fig['n_cylinders']:,} cylinders, {fig['n_triangles']:,} triangles, "
        f"watertight {'yes' if fig['watertight'] else 'no'}; "
        f"{model.timings_s['total']:.1f} s"
    )
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    print_warnings([w["message"] for w in fig.get("warnings", [])])  # implausible figures
    return 0
