"""``treesim compare``: AVOHD distances between a cloud and a reference mesh or cloud."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..params import CompareParams, merge
from ._options import collect, param_options
from ._outputs import output_folder
from .progress import progress_printer


def _fmt_mm(x: float | None) -> str:
    return "      –" if x is None else f"{x * 1e3:9.3f}"


def cmd_compare(args: argparse.Namespace) -> int:
    from ..params import ReportParams
    from ..report.text import length, percent
    from ..steps import compare_files

    output_folder(args.output)
    cloud_path = Path(args.cloud)
    params = merge(CompareParams(), collect(args))
    step = compare_files(
        cloud_path,
        args.reference,
        params,
        args.output,
        report=ReportParams() if args.report else None,
        progress=progress_printer(label="compare"),
    )
    result, kind = step.result, step.details["kind"]
    ref = result.reference_info
    what = (
        f"mesh, {ref['triangles']:,} triangles, {ref['area_m2']:.3g} m², "
        f"{ref['samples']:,} surface samples every {length(result.sample_spacing_m)}"
        if kind == "mesh"
        else f"cloud, {ref['points']:,} points"
    )
    print(
        f"compared {cloud_path.name} ({step.details['points']:,} points, spacing "
        f"{length(result.point_spacing_m)}) with {Path(args.reference).name} ({what})"
    )
    hidden = ref.get("hidden_surface")
    if hidden and hidden["samples_dropped"]:
        print(
            f"hidden surface left out: {hidden['area_m2']:.3g} m² ({percent(hidden['area_share'])}"
            f", {hidden['samples_dropped']:,} samples) inside other closed parts of the mesh "
            f"({hidden['closed_parts']:,} closed of {hidden['parts']:,})"
        )
    head = "".join(f"{h:>9}" for h in ("mean", "RMS", "median", "p95", "p99", "max"))
    print(f"{'(mm)':<14}{'n':>11}{head}")
    for name, st in (("accuracy", result.accuracy), ("completeness", result.completeness)):
        vals = (st.mean_m, st.rms_m, st.median_m, st.p95_m, st.p99_m, st.max_m)
        print(f"{name:<14}{st.n:>11,}" + "".join(_fmt_mm(v) for v in vals))
    print(
        f"Hausdorff {length(result.hausdorff_m)} · Chamfer {length(result.chamfer_m)} · "
        f"coverage {percent(result.coverage)} within τ = {length(result.tolerance_m)}"
    )
    for label, e in result.by_label.items():
        bits = []
        if "accuracy" in e and e["accuracy"]["n"]:
            bits.append(f"{e['accuracy']['n']:,} points, p95 {length(e['accuracy']['p95_m'])}")
        if e.get("coverage") is not None:
            bits.append(f"coverage {percent(e['coverage'])}")
        if bits:
            print(f"  {label}: " + ", ".join(bits))
    for k, e in result.by_station.items():
        print(
            f"  station {k}: {e['points']:,} points, p95 {length(e['accuracy']['p95_m'])}, "
            f"coverage alone {percent(e['coverage'])}"
        )
    written = step.outputs
    names = ", ".join(p.name for key, p in written.items() if key not in ("comparison", "report"))
    print(f"wrote {written['comparison']} and {names}")
    if "report" in written:
        print(f"wrote {written['report']} (open it in a browser; it works offline)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``compare`` to ``treesim``'s parser."""
    cp = sub.add_parser(
        "compare",
        help="AVOHD comparison of a cloud with a reference mesh or cloud",
        description="Measure absolute distances both ways between CLOUD and REFERENCE "
        "(a mesh: OBJ, PLY with faces, STL, OFF, GLB; or a point cloud) and write "
        "comparison.json and the distance clouds (PLY and LAZ with a scalar_distance field).",
    )
    cp.add_argument("cloud", metavar="CLOUD", help="the (simulated) point cloud")
    cp.add_argument("reference", metavar="REFERENCE", help="the reference mesh or cloud")
    cp.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder")
    g = cp.add_argument_group("comparison")
    param_options(g, CompareParams)
    cp.add_argument("--report", action="store_true", help="also write the report into OUTDIR")
    cp.set_defaults(func=cmd_compare)
