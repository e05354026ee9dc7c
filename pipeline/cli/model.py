"""``treesim model ...``: the tree model library's commands.

* ``treesim model generate --species NAME [--leaves/--no-leaves] [--seed N] [--facets N]
  -o tree.obj``: a procedural tree as a labelled mesh (OBJ with ``wood`` and ``leaf``
  groups, or PLY with a per-face label), plus ``tree.cylinders.csv`` (the exact cylinder
  table, treesim's CSV) and ``tree.truth.json`` (its reference figures);
* ``treesim model list``: the species presets with their key figures;
* ``treesim model from-qsm TABLE -o tree.ply``: a QSM cylinder table as a mesh.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..errors import InputFormatError, InvalidParameterError
from ..io.mesh import MESH_WRITE_SUFFIXES
from ..jsonio import write_json as _write_json
from ..params import merge
from ..params.models import ModelParams
from ._options import collect, param_option, param_options
from ._outputs import output_file


def _check_output(path: Path) -> None:
    if path.suffix.lower() not in MESH_WRITE_SUFFIXES:
        raise InputFormatError(
            f"{path.name}: cannot write a mesh as {path.suffix or 'no suffix'!r}; "
            f"use one of {', '.join(MESH_WRITE_SUFFIXES)}"
        )


def companion_paths(mesh_path: str | Path) -> tuple[Path, Path]:
    """``tree.cylinders.csv`` and ``tree.truth.json`` beside ``tree.obj``."""
    p = Path(mesh_path)
    return p.with_name(p.stem + ".cylinders.csv"), p.with_name(p.stem + ".truth.json")


def cmd_generate(args: argparse.Namespace) -> int:
    from .._version import __version__
    from ..io.mesh import write_mesh
    from ..models import generate_tree, species_preset, write_cylinders

    mp = merge(ModelParams(), collect(args))
    facets = mp.facets
    out = Path(args.output)
    _check_output(out)
    table_path, truth_path = companion_paths(out)
    for path in (out, table_path, truth_path):
        output_file(path)
    if mp.species is None:
        raise InvalidParameterError(
            "give the tree species: --species NAME (see 'treesim model list')"
        )
    params = species_preset(mp.species)
    tree = generate_tree(params, seed=mp.seed, leaves=mp.leaves)
    vertices, faces, label = tree.mesh(facets)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_mesh(out, vertices, faces, face_label=label)
    write_cylinders(table_path, tree.cylinders)
    truth = tree.truth(facets)
    truth["files"] = {"mesh": out.name, "cylinders": table_path.name}
    truth["generator"] = f"treesim {__version__} (Weber & Penn procedural model)"
    _write_json(truth_path, truth)
    dbh = truth["dbh_m"] * 100.0
    print(
        f"{params.name} (seed {mp.seed}): DBH {dbh:.1f} cm, height {truth['height_m']:.2f} m, "
        f"wood {truth['volume_total_m3'] * 1000:.1f} L (stem {truth['volume_stem_m3'] * 1000:.1f} "
        f"L), {truth['n_cylinders']:,} cylinders, {truth['n_leaves']:,} leaves"
    )
    print(
        f"wrote {out}: {truth['n_triangles_wood']:,} wood + {truth['n_triangles_leaf']:,} leaf "
        f"triangles, {facets} facets per ring, wood mesh volume "
        f"{truth['mesh_volume_wood_m3'] * 1000:.1f} L ({truth['mesh_volume_error'] * 100:+.2f} % "
        f"vs the table)"
    )
    print(f"wrote {table_path} and {truth_path}")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    from ..models import SPECIES, generate_tree

    mp = merge(ModelParams(), collect(args))
    facets = mp.facets
    header = (
        f"{'species':13} {'DBH cm':>7} {'height m':>9} {'wood L':>8} {'stem L':>7} "
        f"{'cylinders':>9} {'triangles':>9} {'leaves':>7}  description"
    )
    print(f"seed {mp.seed}, {facets} facets per ring (figures of the generated trees)")
    print(header)
    for name, params in SPECIES.items():
        t = generate_tree(params, seed=mp.seed).truth(facets)
        print(
            f"{name:13} {t['dbh_m'] * 100:7.1f} {t['height_m']:9.2f} "
            f"{t['volume_total_m3'] * 1000:8.1f} {t['volume_stem_m3'] * 1000:7.1f} "
            f"{t['n_cylinders']:9,} {t['n_triangles']:9,} {t['n_leaves']:7,}  "
            f"{params.description}"
        )
        if args.sources:
            print(f"{'':13} source: {params.source}")
    if not args.sources:
        print("(--sources shows where each preset's parameters come from)")
    return 0


def cmd_from_qsm(args: argparse.Namespace) -> int:
    from ..io.mesh import write_mesh
    from ..models import mesh_volume, qsm_mesh, read_cylinders

    mp = merge(ModelParams(), collect(args))
    out = Path(args.output)
    _check_output(out)
    output_file(out, inputs=[args.table])
    facets = mp.facets
    table = read_cylinders(args.table, format=args.format)
    v, f, sunk = qsm_mesh(table, facets=facets, joints=mp.joints)
    plugs = ""
    plug_volume = 0.0
    if sunk is not None:
        plug_volume = sunk.plug_volume_m3(facets)
        plugs = (
            f"; {sunk.n_plugs:,} of {sunk.branch_starts:,} branch starts sunk into their "
            f"parents ({plug_volume * 1000:.2f} L inside them)"
        )
    write_mesh(out, v, f)
    s = table.summary()
    dbh = f"{s['dbh_m'] * 100:.2f} cm" if s["dbh_m"] is not None else "n/a (no stem)"
    print(
        f"{Path(args.table).name}: {s['n_cylinders']:,} cylinders, DBH {dbh}, "
        f"height {s['height_m']:.2f} m, volume {s['volume_total_m3'] * 1000:.2f} L "
        f"(stem {s['volume_stem_m3'] * 1000:.2f} L)"
    )
    volume = mesh_volume(v, f) - plug_volume
    prism = facets * math.sin(2 * math.pi / facets) / (2 * math.pi) - 1.0
    print(
        f"wrote {out}: {len(f):,} triangles, {facets} facets per ring, {mp.joints} joints, "
        f"enclosed volume {volume * 1000:.2f} L{' less the plugs' if plug_volume else ''} "
        f"({(volume / s['volume_total_m3'] - 1) * 100:+.2f} % vs the table; the {facets}-gon "
        f"alone gives {prism * 100:+.2f} %){plugs}"
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``model`` command and its subcommands to ``treesim``'s parser."""
    from ..models import FORMATS

    md = sub.add_parser(
        "model",
        help="tree models: procedural trees, QSM cylinder tables to meshes",
        description="Tree models with known geometry: procedural trees with their exact "
        "cylinder tables, and meshes of QSM cylinder tables.",
    )
    msub = md.add_subparsers(dest="model_command", metavar="SUBCOMMAND", parser_class=type(md))

    gen = msub.add_parser(
        "generate",
        help="generate a procedural tree: mesh, cylinder table and truth figures",
        description="Generate a procedural tree (Weber & Penn model) and write its labelled "
        "mesh (wood and leaf parts), its exact cylinder table (OUT.cylinders.csv) and its "
        "reference figures (OUT.truth.json).",
    )
    param_option(gen, ModelParams, "species", metavar="NAME", required=True)
    param_options(gen, ModelParams, ["leaves", "seed", "facets"])
    gen.add_argument("-o", "--output", required=True, metavar="tree.obj", help=".obj or .ply")
    gen.set_defaults(func=cmd_generate)

    ls = msub.add_parser(
        "list",
        help="list the species presets with their key figures",
        description="Generate each species preset and list its figures.",
    )
    param_options(ls, ModelParams, ["seed", "facets"])
    ls.add_argument("--sources", action="store_true", help="show where parameters come from")
    ls.set_defaults(func=cmd_list)

    fq = msub.add_parser(
        "from-qsm",
        help="mesh a QSM cylinder table (TreeQSM CSV or text, SimpleForest, treesim CSV)",
        description="Mesh a QSM cylinder table, labelled wood.",
    )
    fq.add_argument("table", metavar="TABLE")
    fq.add_argument("-o", "--output", required=True, metavar="tree.ply", help=".ply or .obj")
    param_options(fq, ModelParams, ["facets", "joints"])
    fq.add_argument("--format", choices=FORMATS, help="table format (default: detected)")
    fq.set_defaults(func=cmd_from_qsm)
    md.set_defaults(func=lambda a: (md.print_help(), 2)[1])
