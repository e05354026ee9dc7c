"""``treesim validate REAL SIMULATED``: how closely a simulated plot scan reproduces the
field scan, from the stations actually used (density by height and range per station,
each twin tree's coverage, stem and crown apart, and the occlusion profile, distances
both ways). The settings' options come from
:class:`~treesim.plot.validate.ValidateParams`; ``--tau-mm`` is kept, deprecated, for
scripts written before ``--tau-m``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from ..errors import InputFormatError
from ._options import collect, param_option, param_options
from ._outputs import output_folder
from .progress import print_warnings


def _tau_mm(text: str) -> float:
    """The deprecated ``--tau-mm``: τ in millimetres, read as metres within the range
    :class:`~treesim.plot.validate.ValidateParams` declares for ``tau_m``."""
    from dataclasses import replace

    from ..params import field_info
    from ..plot.validate import ValidateParams

    info = field_info(ValidateParams, "tau_m")
    in_mm = replace(info, bounds=tuple(None if b is None else 1000.0 * b for b in info.bounds))
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not in_mm.in_range(v):
        raise argparse.ArgumentTypeError(f"expected {in_mm.range_text()} (mm), got {text!r}")
    return v / 1000.0


def _read_cloud(path: str, what: str) -> Any:
    from ..io import read_cloud

    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"{p}: the {what} file does not exist; check the path")
    try:
        return read_cloud(p)
    except InputFormatError as exc:
        raise InputFormatError(f"the {what} is not a point cloud treesim can read: {exc}") from exc


def _sidecar_stations(cloud: Any, path: str) -> None:
    """A simulated cloud without stations in its metadata takes them from the JSON
    ``treesim plot scan`` writes beside it (``plot_scan.json``)."""
    from ..plot.validate import station_positions

    if station_positions(cloud) is not None:
        return
    side = Path(path).with_suffix(".json")
    try:
        data = json.loads(side.read_text(encoding="utf-8"))
        stations = [s["position_m"] for s in data["stations"]]
    except (OSError, ValueError, KeyError, TypeError):
        return
    cloud.metadata = {**dict(cloud.metadata or {}), "stations": stations}


def _stations(path: str, plot: Any) -> list[Any]:
    """The field's stations from an E57's scan poses or a stations CSV."""
    import csv

    from ..plot import Plot
    from ..plot.scan import read_stations

    p = Path(path)
    if plot is not None:
        return read_stations(p, plot)
    if p.suffix.lower() in (".csv", ".txt"):
        try:
            head = next(csv.reader([p.read_text(encoding="utf-8-sig").splitlines()[0]]))
        except (OSError, UnicodeDecodeError, IndexError) as exc:
            raise InputFormatError(f"{p}: cannot read the stations CSV ({exc})") from exc
        if "z_m" not in head:
            raise InputFormatError(
                f"{p}: without --plot (the twin's terrain) a stations CSV needs a z_m column "
                "(absolute heights); give --plot or add z_m"
            )
    # a plot without trees only bounds the check that the stations are near it
    return read_stations(p, Plot([], radius_m=1e6))


def cmd_validate(args: argparse.Namespace) -> int:
    from ..params import merge
    from ..plot.io import read_plot
    from ..plot.validate import VALIDATION_FILES, ValidateParams, validate_scans
    from ..plot.validate_report import write_validation

    out = output_folder(args.output, files=list(VALIDATION_FILES.values()))
    real = _read_cloud(args.real, "field scan")
    sim = _read_cloud(args.simulated, "simulated scan")
    _sidecar_stations(sim, args.simulated)
    plot = read_plot(args.plot) if args.plot else None
    stations = _stations(args.stations_from, plot) if args.stations_from else None
    # unset options keep ValidateParams' own defaults (one place for them)
    given = collect(args)
    if args.tau_from_mm is not None:
        given["tau_m"] = args.tau_from_mm
        print(
            f"note: --tau-mm is deprecated; give --tau-m {args.tau_from_mm:g} (τ in metres)",
            file=sys.stderr,
        )
    params = merge(ValidateParams(), given)
    result = validate_scans(real, sim, params, plot=plot, stations=stations)
    written = write_validation(result, out, names=(Path(args.real).name, Path(args.simulated).name))
    for g in result.groups:
        d = result.density["per_station"][g]
        ratio = "n/a" if d["density_ratio"] is None else f"{d['density_ratio']:.2f}"
        print(
            f"{'all stations' if g == 'all' else 'station ' + g}: {d['points_real']:,} field "
            f"points, {d['points_simulated']:,} simulated, density ratio {ratio}"
        )
    for n in result.notes:
        print(f"note: {n}")
    print_warnings(result.warnings)
    print(result.summary)
    if result.verdict["failed"]:
        print(f"criteria not met: {', '.join(result.verdict['failed'])}")
    html = out / VALIDATION_FILES["html"]
    print(f"wrote {len(written)} files into {out}; report: {html} (open it in a browser)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``validate`` to ``treesim``'s parser."""
    v = sub.add_parser(
        "validate",
        help="check a simulated plot scan against the field scan",
        description="How closely does SIMULATED (treesim plot scan's cloud) reproduce REAL "
        "(the field scan: an E57 with one scan per station, or a LAS/LAZ), from the stations "
        "actually used? Per station: point density by height and by range, real and "
        "simulated, and their ratio; per twin tree (--plot): coverage at τ, of the whole tree, "
        "its stem and its crown, and the occlusion profile; nearest-neighbour distances both "
        "ways. Writes validation.json, the figures and validation.html into -o.",
    )
    v.add_argument("real", metavar="REAL", help="the field scan (.e57, .laz, .las, .ply, ...)")
    v.add_argument("simulated", metavar="SIMULATED", help="the simulated scan (plot_scan.laz)")
    v.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    v.add_argument("--plot", metavar="PLOT", help="the plot's digital twin (plot.toml)")
    v.add_argument(
        "--stations-from",
        metavar="FILE",
        help="the field's stations: an E57's scan poses or a CSV with x_m, y_m and z_m (or "
        "height_m above the twin's terrain) columns; default the REAL cloud's own",
    )
    from ..plot.validate import ValidateParams

    settings = v.add_argument_group("settings")
    tau = settings.add_mutually_exclusive_group()
    param_option(tau, ValidateParams, "tau_m")
    tau.add_argument(
        "--tau-mm",
        dest="tau_from_mm",
        type=_tau_mm,
        metavar="MM",
        help="deprecated: τ in millimetres (give --tau-m)",
    )
    param_options(settings, ValidateParams, exclude=("tau_m",))
    v.set_defaults(func=cmd_validate)
