"""``treesim model ...`` subcommands (registered by ``pipeline.cli``)."""

from __future__ import annotations

import argparse
from pathlib import Path


def cmd_from_qsm(args: argparse.Namespace) -> int:
    from ..io.mesh import write_mesh
    from . import cylinders_to_mesh, mesh_volume, read_cylinders

    table = read_cylinders(args.table)
    v, f = cylinders_to_mesh(table, facets=args.facets)
    out = Path(args.output)
    write_mesh(out, v, f)
    s = table.summary()
    dbh = f"{s['dbh_m'] * 100:.2f} cm" if s["dbh_m"] is not None else "n/a (no stem)"
    print(
        f"{Path(args.table).name}: {s['n_cylinders']:,} cylinders, DBH {dbh}, "
        f"height {s['height_m']:.2f} m, volume {s['volume_total_m3'] * 1000:.2f} L "
        f"(stem {s['volume_stem_m3'] * 1000:.2f} L)"
    )
    print(
        f"wrote {out}: {len(f):,} triangles, {args.facets} facets per ring, "
        f"enclosed volume {mesh_volume(v, f) * 1000:.2f} L"
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``model`` command and its subcommands to ``treesim``'s parser."""
    md = sub.add_parser("model", help="tree models: QSM cylinder tables to meshes")
    msub = md.add_subparsers(dest="model_command", metavar="SUBCOMMAND", parser_class=type(md))
    fq = msub.add_parser(
        "from-qsm", help="mesh a QSM cylinder table (TreeQSM, SimpleForest, treesim CSV)"
    )
    fq.add_argument("table", metavar="TABLE")
    fq.add_argument("-o", "--output", required=True, metavar="tree.ply")
    fq.add_argument("--facets", type=int, default=32, help="facets per cylinder ring (default 32)")
    fq.set_defaults(func=cmd_from_qsm)
    md.set_defaults(func=lambda a: (md.print_help(), 2)[1])
