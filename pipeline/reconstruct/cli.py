"""``treesim reconstruct`` (registered by ``pipeline.cli``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _fmt(v: float | None, scale: float, unit: str, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v * scale:.{digits}f} {unit}"


def cmd_reconstruct(args: argparse.Namespace) -> int:
    from ..errors import InvalidParameterError
    from ..io import read_cloud
    from . import PrepareParams, QSMParams, ReconstructParams, reconstruct

    columns = None
    if args.columns:
        columns = [c.strip() or None for c in args.columns.split(",")]
        if not {"x", "y", "z"} <= {c for c in columns if c}:
            raise InvalidParameterError("--columns must name x, y and z (e.g. x,y,z,intensity)")
    cloud = read_cloud(args.cloud, columns=columns) if columns else read_cloud(args.cloud)
    prep = PrepareParams(
        voxel_size_m=None if args.voxel_m == 0 else args.voxel_m,
        sor_std_ratio=None if args.no_outlier_removal else args.sor_std_ratio,
        remove_ground=args.remove_ground,
    )
    params = ReconstructParams(
        method=args.method,
        prepare=prep,
        qsm=QSMParams(slice_m=args.slice_m, twig_radius_m=args.twig_radius_m),
        facets=args.facets,
        poisson_depth=args.depth,
        bpa_radii_m=tuple(args.bpa_radius_m) if args.bpa_radius_m else None,
        timeout_s=args.timeout_s,
    )
    show = None
    if sys.stderr.isatty():

        def show(f: float, m: str) -> None:
            sys.stderr.write(f"\r  {m}: {100 * f:3.0f} %   ")
            if f >= 1:
                sys.stderr.write("\n")

    model = reconstruct(cloud, params, progress=show)
    paths = model.write(args.output)
    fig = model.figures
    print(
        f"{Path(args.cloud).name}: {fig['points_input']:,} points -> {fig['points_used']:,} "
        f"after preparation (spacing {fig['spacing_m'] * 1000:.1f} mm)"
    )
    for step in model.preparation.get("steps", []):
        print(f"  {step['step']}: removed {step['removed']:,}")
    if fig["leaves_present"]:
        print(
            f"  leaves present: about {fig['leaf_fraction'] * 100:.0f} % of points look leaf-like; "
            "wood volume figures include them as modelled twigs"
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
    return 0


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
    p.add_argument("--method", choices=["qsm", "poisson", "bpa"], default="qsm")
    p.add_argument("--columns", help="column names of a text cloud, e.g. x,y,z,intensity")
    g = p.add_argument_group("preparation")
    g.add_argument(
        "--voxel-m",
        type=float,
        default=0.005,
        help="voxel size for downsampling (default 0.005; 0 = off)",
    )
    g.add_argument(
        "--sor-std-ratio",
        type=float,
        default=2.5,
        help="statistical outlier removal threshold (default 2.5)",
    )
    g.add_argument("--no-outlier-removal", action="store_true")
    g.add_argument("--remove-ground", action="store_true", help="remove a ground plane first")
    q = p.add_argument_group("qsm")
    q.add_argument("--slice-m", type=float, help="geodesic slice thickness (default from spacing)")
    q.add_argument(
        "--twig-radius-m",
        type=float,
        default=0.003,
        help="radius prior of branch tips (default 0.003)",
    )
    q.add_argument("--facets", type=int, default=32, help="facets per cylinder ring (default 32)")
    s = p.add_argument_group("surface methods")
    s.add_argument("--depth", type=int, default=8, help="Poisson octree depth (default 8)")
    s.add_argument(
        "--bpa-radius-m",
        type=float,
        action="append",
        help="ball radius (repeatable; default from the point spacing)",
    )
    s.add_argument(
        "--timeout-s",
        type=float,
        default=600.0,
        help="stop a pymeshlab step after this long (default 600)",
    )
    p.set_defaults(func=cmd_reconstruct)
