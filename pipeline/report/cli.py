"""``treesim compare`` and ``treesim report`` (registered by ``pipeline.cli``)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ..errors import InputFormatError, InvalidParameterError


def scan_sidecar(cloud_path: Path) -> dict[str, Any] | None:
    """The scan settings ``treesim scan`` wrote beside a cloud (``OUT.json``), if any."""
    side = cloud_path.with_suffix(".json")
    if not side.is_file():
        return None
    try:
        info = json.loads(side.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or "stations" not in info:
        return None
    return {
        "source": side.name,
        "scanner": info.get("scanner"),
        "models_active": info.get("models_active"),
        "stations": [
            {k: st.get(k) for k in ("index", "position_m", "points")}
            for st in info.get("stations", [])
            if isinstance(st, dict)
        ],
    }


def _fmt_mm(x: float | None) -> str:
    return "      –" if x is None else f"{x * 1e3:9.3f}"


def cmd_compare(args: argparse.Namespace) -> int:
    from ..compare import CompareParams, compare, write_comparison
    from ..io import read_cloud, read_reference
    from .text import length, percent

    cloud_path = Path(args.cloud)
    params = CompareParams(
        tolerance_m=args.tolerance_m,
        sample_spacing_m=args.sample_spacing_m,
        seed=args.seed,
        max_samples=int(args.max_samples),
        nthreads=args.threads,
    )
    if not cloud_path.exists():
        raise InputFormatError(f"{cloud_path} not found; check the path")
    cloud = read_cloud(cloud_path)
    reference, kind = read_reference(args.reference)
    result = compare(cloud, reference, params=params)
    inputs: dict[str, Any] = {"cloud": str(cloud_path), "reference": str(args.reference)}
    sidecar = scan_sidecar(cloud_path)
    if sidecar:
        inputs["scan"] = sidecar
    written = write_comparison(result, args.output, inputs=inputs)

    ref = result.reference_info
    what = (
        f"mesh, {ref['triangles']:,} triangles, {ref['area_m2']:.3g} m², "
        f"{ref['samples']:,} surface samples every {length(result.sample_spacing_m)}"
        if kind == "mesh"
        else f"cloud, {ref['points']:,} points"
    )
    print(
        f"compared {cloud_path.name} ({len(cloud):,} points, spacing "
        f"{length(result.point_spacing_m)}) with {Path(args.reference).name} ({what})"
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
    out = Path(args.output)
    names = ", ".join(p.name for key, p in written.items() if key != "comparison")
    print(f"wrote {written['comparison']} and {names}")
    if args.report:
        from . import build_report

        files = build_report(out)
        print(f"wrote {files['report_html']} (open it in a browser; it works offline)")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from . import ReportParams, build_report

    if args.comparison and args.outdir_in:
        raise InvalidParameterError("give either OUTDIR or --comparison FILE, not both")
    source = args.comparison or args.outdir_in
    if not source:
        raise InvalidParameterError(
            "give the folder 'treesim compare' wrote (OUTDIR) or --comparison comparison.json"
        )
    params = ReportParams(max_view_points=args.max_view_points, seed=args.seed)
    files = build_report(source, args.output, params=params)
    print(
        f"wrote {files['report_html']}, {files['report_json'].name} and "
        f"{len(files) - 2} plots in {files['report_html'].parent}"
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``compare`` and ``report`` commands to ``treesim``'s parser."""
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
    cp.add_argument(
        "--tolerance-m",
        type=float,
        help="coverage tolerance τ in metres (default 3 × the cloud's median point spacing)",
    )
    cp.add_argument(
        "--sample-spacing-m",
        type=float,
        help="spacing of the mesh surface samples in metres (default the point spacing)",
    )
    cp.add_argument("--seed", type=int, default=0, help="seed of the surface sampling (default 0)")
    cp.add_argument(
        "--max-samples",
        type=float,
        default=2e6,
        help="most mesh surface samples (default 2e6; the spacing grows to fit)",
    )
    cp.add_argument("--threads", type=int, default=0, help="threads (default: all cores)")
    cp.add_argument("--report", action="store_true", help="also write the report into OUTDIR")
    cp.set_defaults(func=cmd_compare)

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
    rp.add_argument(
        "--max-view-points",
        type=int,
        default=40_000,
        help="points per data set in the 3D view (default 40000)",
    )
    rp.add_argument("--seed", type=int, default=0, help="seed of the subsamples (default 0)")
    rp.set_defaults(func=cmd_report)
