"""The ``treesim`` command line.

Every command ends with a one-line error and a non-zero exit on bad input (exit 1 for
treesim's own errors, 2 for bad usage, 130 when interrupted); set ``TREESIM_DEBUG=1``
to see a traceback for unexpected errors.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .errors import InvalidParameterError, TreesimError
from .jsonio import write_json as _write_json

SAMPLE_DIR = Path(__file__).resolve().parent / "data" / "coffee_tree"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        self.exit(2, f"treesim: error: {message} (see '{self.prog} --help')\n")


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise InvalidParameterError(
            f"{what} must be {n} numbers separated by commas, got {text!r}"
        ) from None
    if len(vals) != n:
        raise InvalidParameterError(f"{what} must be {n} numbers separated by commas, got {text!r}")
    return vals


def _progress_printer(enabled: bool):
    if not enabled:
        return None
    last = [0.0]

    def show(fraction: float, message: str) -> None:
        now = time.monotonic()
        if now - last[0] < 0.2 and fraction < 1.0:
            return
        last[0] = now
        sys.stderr.write(f"\r  {message}: {100 * fraction:5.1f} %")
        if fraction >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


# -- scan ------------------------------------------------------------------------------
def _add_scan_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("stations")
    g.add_argument(
        "--layout",
        choices=["ring", "list"],
        default=None,
        help="ring: N stations around the scene centre (default); list: --station",
    )
    g.add_argument("--stations", type=int, default=3, help="stations in the ring (default 3)")
    g.add_argument(
        "--distance-m",
        type=float,
        default=10.0,
        help="ring radius, horizontal distance to the scene centre (default 10)",
    )
    g.add_argument(
        "--height-m",
        type=float,
        default=1.5,
        help="instrument height above the scene's lowest point (default 1.5)",
    )
    g.add_argument(
        "--start-angle-deg",
        type=float,
        default=0.0,
        help="polar angle of the first ring station (default 0: +x)",
    )
    g.add_argument(
        "--station",
        action="append",
        default=[],
        metavar="X,Y,Z",
        help="an explicit station position in scene coordinates (repeatable)",
    )
    s = p.add_argument_group("scanner")
    s.add_argument("--preset", help="instrument preset (see 'treesim scan --list-presets')")
    s.add_argument("--beam", action="store_true", help="turn on the preset's beam divergence model")
    s.add_argument(
        "--noise", action="store_true", help="turn on the preset's range noise and angular jitter"
    )
    s.add_argument(
        "--resolution-deg", type=float, help="horizontal and vertical angular step (default 0.04)"
    )
    s.add_argument("--h-resolution-deg", type=float, help="horizontal step only")
    s.add_argument("--v-resolution-deg", type=float, help="vertical step only")
    s.add_argument("--hfov-deg", metavar="START,END", help="horizontal field of view")
    s.add_argument("--vfov-deg", metavar="LOW,HIGH", help="vertical field of view (default -40,90)")
    s.add_argument("--min-range-m", type=float)
    s.add_argument("--max-range-m", type=float)
    s.add_argument(
        "--beam-divergence-mrad",
        type=float,
        help="full-angle divergence; > 0 turns the beam model on",
    )
    s.add_argument("--subrays", type=int, help="rays per pulse with the beam model (default 7)")
    s.add_argument(
        "--range-resolution-m",
        type=float,
        help="echo separation for multiple returns (default 0.3)",
    )
    s.add_argument("--range-noise-sd-m", type=float, help="Gaussian range noise σ (default off)")
    s.add_argument("--angular-jitter-sd-deg", type=float, help="pointing noise σ (default off)")
    s.add_argument("--return-mode", choices=["first", "last", "strongest", "all"])
    s.add_argument("--seed", type=int, help="seed of the noise models (default 0)")
    x = p.add_argument_group("execution")
    x.add_argument(
        "--full-fov",
        action="store_true",
        help="cast the whole field of view instead of the scene's window",
    )
    x.add_argument(
        "--max-rays",
        type=float,
        default=1e9,
        help="refuse scans needing more rays than this (default 1e9)",
    )
    x.add_argument(
        "--chunk-rays",
        type=int,
        default=1 << 19,
        help="rays per batch; bounds memory at ~200 B per ray (default 524288)",
    )
    x.add_argument("--threads", type=int, default=0, help="Open3D threads (default: all cores)")


def _spec_from_args(args: argparse.Namespace):
    from .scan import ScannerSpec, preset

    kw: dict[str, Any] = {}
    if args.resolution_deg is not None:
        kw["horizontal_resolution_deg"] = kw["vertical_resolution_deg"] = args.resolution_deg
    if args.h_resolution_deg is not None:
        kw["horizontal_resolution_deg"] = args.h_resolution_deg
    if args.v_resolution_deg is not None:
        kw["vertical_resolution_deg"] = args.v_resolution_deg
    if args.hfov_deg:
        kw["horizontal_fov_deg"] = _floats(args.hfov_deg, 2, "--hfov-deg")
    if args.vfov_deg:
        kw["vertical_fov_deg"] = _floats(args.vfov_deg, 2, "--vfov-deg")
    for name in (
        "min_range_m",
        "max_range_m",
        "beam_divergence_mrad",
        "subrays",
        "range_resolution_m",
        "range_noise_sd_m",
        "angular_jitter_sd_deg",
        "return_mode",
        "seed",
    ):
        v = getattr(args, name)
        if v is not None:
            kw[name] = v
    if args.preset:
        return preset(args.preset).spec(beam=args.beam, noise=args.noise, **kw)
    if args.beam or args.noise:
        raise InvalidParameterError(
            "--beam and --noise take their figures from --preset; "
            "give --preset or set --beam-divergence-mrad / "
            "--range-noise-sd-m directly"
        )
    return ScannerSpec(**kw)


def _stations_from_args(args: argparse.Namespace, scene) -> list:
    from .scan import Station, ring_around

    if args.station and args.layout == "ring":
        raise InvalidParameterError("give either --layout ring or --station positions, not both")
    if args.station:
        return [Station(position_m=_floats(s, 3, "--station")) for s in args.station]
    if args.layout == "list":
        raise InvalidParameterError("--layout list needs at least one --station X,Y,Z")
    return ring_around(
        scene.bounds,
        args.stations,
        distance_m=args.distance_m,
        height_m=args.height_m,
        start_angle_deg=args.start_angle_deg,
    )


def run_scan(
    args: argparse.Namespace, meshes: Sequence[Path], out: Path, label: str | None = None
) -> dict[str, Any]:
    """Load, scan, write the cloud and ``<out>.json``; print a per-station table."""
    from .io import write_cloud
    from .scan import load_scene, scan

    out_suffix = out.suffix.lower()
    if out_suffix not in (".laz", ".las", ".ply", ".xyz", ".txt", ".csv"):
        raise InvalidParameterError(f"-o {out}: write .laz, .las, .ply, .xyz, .txt or .csv")
    spec = _spec_from_args(args)
    t0 = time.perf_counter()
    scene = load_scene(meshes, labels=[label] * len(meshes) if label else None)
    t_load = time.perf_counter() - t0
    stations = _stations_from_args(args, scene)
    result = scan(
        scene,
        stations,
        spec,
        window=not args.full_fov,
        chunk_rays=args.chunk_rays,
        max_rays=int(args.max_rays),
        nthreads=args.threads,
        progress=_progress_printer(sys.stderr.isatty()),
    )
    t1 = time.perf_counter()
    write_cloud(out, result.cloud)
    t_write = time.perf_counter() - t1
    summary = {
        "meshes": [str(m) for m in meshes],
        "triangles": scene.n_triangles,
        "degenerate_triangles_dropped": scene.dropped_degenerate,
        "labels_in_scene": scene.labels_present(),
        "output": str(out),
        **result.summary(),
        "timings_s": {"load": t_load, "scan": result.total_s, "write": t_write},
    }
    summary_path = out.with_name(out.stem + ".json")
    _write_json(summary_path, summary)
    print(
        f"scanned {', '.join(Path(m).name for m in meshes)}: {scene.n_triangles:,} triangles "
        f"({', '.join(scene.labels_present())})"
    )
    print(
        f"{'station':>7}  {'position (m)':>34}  {'rays cast':>11}  {'points':>9}  {'time (s)':>8}"
    )
    for s in result.station_stats:
        pos = ", ".join(f"{c:.2f}" for c in s.position_m)
        print(f"{s.index:>7}  {pos:>34}  {s.rays_cast:>11,}  {s.points:>9,}  {s.time_s:>8.2f}")
    models = ", ".join(result.models) or "none (geometry only)"
    print(
        f"total: {len(result.cloud):,} points from {result.rays_cast:,} rays "
        f"(full field of view would be {result.rays_full_fov:,}) in {result.total_s:.2f} s; "
        f"models: {models}"
    )
    print(f"wrote {out} and {summary_path}")
    return summary


def cmd_scan(args: argparse.Namespace) -> int:
    if args.list_presets:
        from .scan import PRESETS

        for p in PRESETS.values():
            print(
                f"{p.name:20} {p.description}; "
                f"FOV {p.vertical_fov_deg[0]:g}..{p.vertical_fov_deg[1]:g}°, "
                f"{p.min_range_m:g}-{p.max_range_m:g} m, divergence {p.beam_divergence_mrad} mrad, "
                f"range noise {p.range_noise_sd_m * 1000:g} mm ({p.source})"
            )
        return 0
    if not args.meshes:
        raise InvalidParameterError("give at least one MESH file")
    if args.output is None:
        raise InvalidParameterError("give the output cloud with -o OUT.laz")
    run_scan(args, [Path(m) for m in args.meshes], Path(args.output), label=args.label)
    return 0


# -- demo ------------------------------------------------------------------------------
def cmd_demo(args: argparse.Namespace) -> int:
    """Run the whole loop (``run_tree``) on the bundled coffee tree's field cloud."""
    from .run import preset, run_tree
    from .run_cli import print_run_summary

    cloud = SAMPLE_DIR / "cloud.txt"
    print(
        "bundled sample: Kentucky coffee tree (rTwig), leaf-off TLS cloud; reconstruct, "
        "scan from three stations, compare with the mesh and the field cloud, report"
    )
    result = run_tree(
        cloud,
        preset("standard"),
        Path(args.output),
        name="coffee_tree",
        progress=_progress_printer(sys.stderr.isatty()),
    )
    print_run_summary(result)
    print(f"\ndemo output is in {result.outdir.resolve()}/; open the report in a browser:")
    print(f"{result.report_html.resolve()}")
    return 0


# -- parser ----------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    from ._version import __version__

    p = _Parser(prog="treesim", description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--version", action="version", version=f"treesim {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    sc = sub.add_parser(
        "scan",
        help="scan meshes with a virtual TLS scanner",
        description="Scan one or more meshes (OBJ, PLY, STL, OFF, GLB) from one "
        "or more stations and write the simulated cloud (LAZ, LAS, PLY, XYZ).",
    )
    sc.add_argument("meshes", nargs="*", metavar="MESH")
    sc.add_argument("-o", "--output", metavar="OUT.laz")
    sc.add_argument(
        "--label",
        choices=["wood", "leaf", "ground", "other"],
        help="label every part of the meshes (default: from group/material names)",
    )
    sc.add_argument("--list-presets", action="store_true", help="list instrument presets and exit")
    _add_scan_options(sc)
    sc.set_defaults(func=cmd_scan)

    from .models.cli import register as register_model
    from .reconstruct.cli import register as register_reconstruct
    from .report.cli import register as register_report
    from .run_cli import register as register_run

    register_model(sub)
    register_reconstruct(sub)
    register_report(sub)
    register_run(sub)

    dm = sub.add_parser(
        "demo",
        help="run the whole loop on the bundled sample tree and print the report's path",
    )
    dm.add_argument("-o", "--output", default="out/demo", help="output folder (default out/demo)")
    dm.set_defaults(func=cmd_demo)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except TreesimError as exc:
        print(f"treesim: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("treesim: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(
            "treesim: error: out of memory; coarsen the resolution or lower --chunk-rays",
            file=sys.stderr,
        )
        return 1
    except Exception as exc:  # never a traceback for users
        if os.environ.get("TREESIM_DEBUG"):
            raise
        print(
            f"treesim: internal error: {type(exc).__name__}: {exc} "
            "(set TREESIM_DEBUG=1 for a traceback and report it)",
            file=sys.stderr,
        )
        return 3


if __name__ == "__main__":
    sys.exit(main())
