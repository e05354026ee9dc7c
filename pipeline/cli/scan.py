"""``treesim scan``: scan meshes with the virtual TLS scanner."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..errors import InvalidParameterError
from ..params import (
    GENERIC_TLS,
    INSTRUMENTS,
    SETTINGS,
    RunParams,
    ScannerSpec,
    ScanParams,
    merge,
    scan_params,
)
from ._options import collect, floats_type, number_type, param_option, param_options
from ._outputs import output_file
from .progress import print_warnings, progress_printer

#: ScannerSpec fields without a flag (set them in code or a TOML file).
_NO_FLAG = ("reflectance",)


def _instrument_list() -> str:
    return "; ".join(f"{p.name}: {p.description}" for p in INSTRUMENTS.values())


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``scan`` to ``treesim``'s parser."""
    p = sub.add_parser(
        "scan",
        help="scan meshes with a virtual TLS scanner",
        description="Scan one or more meshes (OBJ, PLY, STL, OFF, GLB) from one "
        "or more stations and write the simulated cloud (LAZ, LAS, PLY, XYZ). Stations "
        "stand on a ring placed by the station rule (see 'treesim run --help') unless "
        "--distance-m or --station is given.",
    )
    p.add_argument("meshes", nargs="*", metavar="MESH")
    p.add_argument("-o", "--output", metavar="OUT.laz")
    p.add_argument(
        "--label",
        choices=["wood", "leaf", "ground", "other"],
        help="label every part of the meshes (default: from group/material names)",
    )
    p.add_argument(
        "--list-instruments",
        "--list-presets",
        dest="list_instruments",
        action="store_true",
        help="list the scanner instruments and exit",
    )
    g = p.add_argument_group("stations")
    g.add_argument(
        "--layout",
        choices=["ring", "list"],
        default=None,
        help="ring: N stations around the scene centre (default); list: --station",
    )
    param_options(g, ScanParams, ["n_stations", "distance_m", "min_distance_m", "height_m"])
    param_option(g, ScanParams, "start_angle_deg")
    g.add_argument(
        "--station",
        action="append",
        default=[],
        type=floats_type(3, "--station"),
        metavar="X,Y,Z",
        help="an explicit station position in scene coordinates (repeatable)",
    )
    s = p.add_argument_group("scanner")
    s.add_argument(
        "--instrument",
        choices=list(INSTRUMENTS),
        help=f"start from a real instrument's figures ({_instrument_list()})",
    )
    g = GENERIC_TLS
    s.add_argument(
        "--beam",
        action="store_true",
        help="turn on the beam divergence model: the instrument's divergence, or without "
        f"--instrument a generic TLS's {g['beam_divergence_mrad']:g} mrad, sampled with "
        f"--subrays (default {ScannerSpec().subrays}) rays per pulse",
    )
    s.add_argument(
        "--noise",
        action="store_true",
        help="turn on range noise and angular jitter: the instrument's, or without "
        f"--instrument a generic TLS's σ {g['range_noise_sd_m'] * 1000:g} mm and "
        f"{g['angular_jitter_sd_deg']:g}°",
    )
    s.add_argument(
        "--resolution-deg",
        type=number_type(SETTINGS["resolution_deg"].info),
        metavar="DEG",
        help=f"{SETTINGS['resolution_deg'].help} (deg; sets both of the steps below)",
    )
    param_options(s, ScannerSpec, path=("scanner",), exclude=_NO_FLAG)
    param_option(s, ScanParams, "lod")
    x = p.add_argument_group("execution")
    x.add_argument(
        "--full-fov",
        action="store_true",
        help="cast the whole field of view instead of the scene's window",
    )
    param_options(x, ScanParams, ["max_rays", "chunk_rays"])
    param_option(x, RunParams, "threads")
    x.add_argument(
        "--dry-run",
        action="store_true",
        help="plan the scan, estimate its rays, points, file size and time from a sample "
        "cast on this machine, print them with each station's window, and exit without "
        "scanning or writing anything (-o only picks the format)",
    )
    p.set_defaults(func=cmd_scan)


#: Scans estimated to take longer than this (s) say so on stderr before they start.
LONG_SCAN_S = 10.0


def estimate_printer(min_seconds: float | None = None):
    """An ``estimate(ScanEstimate)`` callback printing one line on stderr before a scan
    estimated to take at least ``min_seconds`` (default :data:`LONG_SCAN_S`)."""

    def show(est: Any) -> None:
        if est.seconds >= (LONG_SCAN_S if min_seconds is None else min_seconds):
            print(f"treesim scan: estimate: {est.line()}", file=sys.stderr, flush=True)

    return show


def params_from_args(args: argparse.Namespace) -> tuple[ScanParams, int]:
    """ScanParams from the defaults, the instrument, then the flags (the rule is
    :func:`treesim.params.scan_params`'s); and the threads."""
    given = collect(args)
    # --threads is RunParams.threads (validated there); the rest is ScanParams
    threads = merge(RunParams(), {k: given.pop(k) for k in ("threads",) if k in given}).threads
    params = scan_params(
        given,
        instrument=args.instrument,
        beam=args.beam,
        noise=args.noise,
        resolution_deg=args.resolution_deg,
    )
    return params, threads


def _stations(args: argparse.Namespace) -> list[tuple[float, float, float]] | None:
    if args.station and args.layout == "ring":
        raise InvalidParameterError("give either --layout ring or --station positions, not both")
    if args.station:
        return list(args.station)
    if args.layout == "list":
        raise InvalidParameterError("--layout list needs at least one --station X,Y,Z")
    return None


def companion_table(meshes: Sequence[Path]) -> Path | None:
    """The cylinder table beside a mesh: ``treesim model``'s ``OUT.cylinders.csv`` beside
    ``OUT.obj``, or ``treesim reconstruct``'s ``cylinders.csv`` in the mesh's folder (the
    first found, meshes in order); None when there is none."""
    for mesh in meshes:
        mesh = Path(mesh)
        for cand in (mesh.with_name(mesh.stem + ".cylinders.csv"), mesh.with_name("cylinders.csv")):
            if cand.is_file():
                return cand
    return None


def with_wind_table(params: ScanParams, meshes: Sequence[Path]) -> ScanParams:
    """``params`` with the swaying tree's table found beside the meshes when a wind blows
    and no ``--wind-cylinders`` was given (unchanged otherwise: a plain mesh scans still,
    and the scan warns)."""
    spec = params.scanner
    if spec.wind_speed_m_s <= 0 or spec.wind_cylinders is not None:
        return params
    table = companion_table(meshes)
    if table is None:
        return params
    return replace(params, scanner=spec.with_(wind_cylinders=str(table)))


def _step_args(
    args: argparse.Namespace, label: str | None, meshes: Sequence[Path] = ()
) -> dict[str, Any]:
    """The arguments :func:`treesim.steps.scan_files` and
    :func:`~treesim.steps.estimate_scan_files` take from the flags (all but the meshes
    and the output); a wind's cylinder table found beside ``meshes``."""
    params, threads = params_from_args(args)
    params = with_wind_table(params, meshes)
    return {
        "params": params,
        "stations": _stations(args),
        "label": label,
        "window": not args.full_fov,
        "threads": threads,
    }


def run_scan(
    args: argparse.Namespace, meshes: Sequence[Path], out: Path, label: str | None = None
) -> dict[str, Any]:
    """Scan (:func:`treesim.steps.scan_files`), then print a per-station table."""
    from ..scan._open3d import load_open3d
    from ..steps import scan_files

    output_file(out, inputs=meshes)
    output_file(out.with_name(out.stem + ".json"), flag="-o (its .json beside it)")
    load_open3d()  # before the step's own import of it: without Plotly and Dash (~0.8 s)
    step = scan_files(
        meshes,
        out_path=out,
        **_step_args(args, label, meshes),
        progress=progress_printer(label="scan"),
        estimate=estimate_printer(),
    )
    result, scene = step.result, step.details["scene"]
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
        f"total: {result.n_points:,} points from {result.rays_cast:,} rays "
        f"(full field of view would be {result.rays_full_fov:,}) in {result.total_s:.2f} s; "
        f"models: {models}"
    )
    m = result.spec.mechanics()
    print(
        f"in the field each station's scan takes {m.duration_s:.1f} s ({m.n_lines:,} lines at "
        f"{m.line_rate_hz:.3g} lines/s, a pulse every {m.pulse_period_s * 1e6:.3g} µs); "
        "each point's time_s (LAZ gps_time) is seconds since its station's start"
    )
    if result.wind is not None:
        print(wind_line(result.wind))
    if result.n_points == 0:  # a valid result, written as an empty cloud: say why
        from ..report.text import lod_reasons

        why = "; ".join(f"{what}: {reason}" for what, reason in lod_reasons(result.lod))
        print(f"treesim scan: no points were recorded ({why})", file=sys.stderr)
    print_warnings(result.warnings)
    print(f"wrote {step.outputs['cloud']} and {step.outputs['json']}")
    return step.summary


def wind_line(wind: dict[str, Any]) -> str:
    """One line on a windy scan: the tree's sway and the time slices it was cast in."""
    slices = sum(s["slices"] for s in wind["stations"])
    shortest = min(s["slice_s"] for s in wind["stations"])
    speed = wind.get("wind_speed_m_s")
    what = f"wind {speed:g} m/s" if speed is not None else "a steady sway"
    return (
        f"{what}: stem {wind['stem_frequency_hz']:.2f} Hz (DBH {wind['dbh_m']:.2f} m, "
        f"height {wind['height_m']:.1f} m), stem top {wind['stem_tip_mean_m']:.3f} m "
        f"downwind ± {wind['stem_tip_swing_3sigma_m']:.3f} m (3σ); cast in {slices:,} "
        f"time slices (≥ {shortest * 1000:.3g} ms); the model and the slices: scan.json's "
        "'wind'"
    )


def dry_run(
    args: argparse.Namespace, meshes: Sequence[Path], out: Path, label: str | None = None
) -> dict[str, Any]:
    """Plan and estimate the scan (:func:`treesim.steps.estimate_scan_files`), print
    the stations' windows and the estimate; nothing is scanned or written."""
    from ..steps import estimate_scan_files

    step = estimate_scan_files(meshes, out_path=out, **_step_args(args, label, meshes))
    est, scene = step.result, step.details["scene"]
    print(
        f"dry run of treesim scan: {', '.join(Path(m).name for m in meshes)}, "
        f"{scene.n_triangles:,} triangles; nothing scanned or written"
    )
    print(
        f"{'station':>7}  {'position (m)':>34}  {'azimuth (deg)':>17}  {'elevation (deg)':>15}"
        f"  {'window pulses':>13}  {'to cast':>11}"
    )
    for st in est.stations:
        pos = ", ".join(f"{c:.2f}" for c in st["position_m"])
        az = st["azimuth_window_deg"]
        az_s = f"{az[0]:.1f}..{az[1]:.1f}" if az else "all"
        el = st["elevation_window_deg"]
        el_s = f"{el[0]:.1f}..{el[1]:.1f}"
        print(
            f"{st['index']:>7}  {pos:>34}  {az_s:>17}  {el_s:>15}"
            f"  {st['pulses_window']:>13,}  {st['pulses_cast']:>11,}"
        )
    print(f"estimate: {est.line()}")
    for note in est.notes:
        print(f"  note: {note}")
    if est.over_limit:
        print(
            f"  the scan would be refused: up to {est.rays_upper:.3g} rays, over --max-rays "
            f"{est.max_rays:.3g}"
        )
    return step.summary


def cmd_scan(args: argparse.Namespace) -> int:
    if args.list_instruments:
        for p in INSTRUMENTS.values():
            print(
                f"{p.name:20} {p.description}; "
                f"FOV {p.vertical_fov_deg[0]:g}..{p.vertical_fov_deg[1]:g}°, "
                f"{p.min_range_m:g}-{p.max_range_m:g} m, divergence {p.beam_divergence_mrad} mrad, "
                f"range noise {p.range_noise_sd_m * 1000:g} mm ({p.source})"
            )
        return 0
    if not args.meshes:
        raise InvalidParameterError("give at least one MESH file")
    if args.dry_run:
        out = Path(args.output or "scan.laz")
        dry_run(args, [Path(m) for m in args.meshes], out, label=args.label)
        return 0
    if args.output is None:
        raise InvalidParameterError("give the output cloud with -o OUT.laz")
    run_scan(args, [Path(m) for m in args.meshes], Path(args.output), label=args.label)
    return 0
