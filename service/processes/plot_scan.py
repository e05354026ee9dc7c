"""``plot-scan``: scan a plot from stations, one at a time, and measure every tree in it
against its own mesh (as ``treesim plot scan``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from treesim.params import CompareParams, ScanParams, json_schema, merge

from .base import Input, Process, Progress, field_error, job_schema
from .scan import parse_scan, scan_extra
from .sources import PLOT_INPUTS, STAND_OUTPUTS, pop_source, source_schema


@dataclass(frozen=True)
class PlotScanJob:
    """A plot scan job's parameters: the scan's, the stations given (or None: the ring,
    or inputs.stations), the per-tree comparison's, whether to measure the trees, and
    where the plot comes from."""

    scan: ScanParams
    stations: tuple[tuple[float, ...], ...] | None
    compare: CompareParams
    figures: bool
    source: Any  # PlotSource
    #: azimuth sectors a station is scanned in (treesim.plot.sectors)
    sectors: int = 1


#: ScanParams fields a plot scan does not use (the station rule is one tree's).
_NOT_FOR_PLOTS = ("min_distance_m",)

#: The most stations one plot scan takes (given as positions or as a stations CSV).
MAX_STATIONS = 1000
#: The most azimuth sectors a station is scanned in.
MAX_SECTORS = 64
#: The largest magnitude of a station's coordinate (m): every projected coordinate on
#: Earth fits (UTM northings reach 1e7 m); a larger one is a unit or typing error.
STATION_COORD_MAX_M = 1e8


def _plot_scan_schema() -> dict[str, Any]:
    schema = job_schema(ScanParams)
    for key in _NOT_FOR_PLOTS:
        schema["properties"].pop(key, None)
    props = schema["properties"]
    props["distance_m"]["description"] = (
        "distance of the ring's stations from the plot centre (null: half the plot's radius)"
    )
    props["height_m"]["description"] = "instrument height above the terrain"
    return schema


def _plot_scan_extra() -> dict[str, Any]:
    tol = json_schema(CompareParams)["properties"]["tolerance_m"]
    tol["description"] = "the per-tree comparison's " + tol["description"]
    return {
        **scan_extra(),
        "stations": {
            "type": "array",
            "minItems": 1,
            "maxItems": MAX_STATIONS,
            "items": {
                "type": "array",
                "items": {
                    "type": "number",
                    "minimum": -STATION_COORD_MAX_M,
                    "maximum": STATION_COORD_MAX_M,
                },
                "minItems": 2,
                "maxItems": 3,
            },
            "description": "station positions in the plot's frame (m): [x, y] stands "
            "height_m above the terrain, [x, y, z] where given (default a ring of n_stations "
            "at distance_m; or inputs.stations, a plan job's stations.csv); each within the "
            "plot's radius plus the scanner's max_range_m of its centre",
        },
        "tolerance_m": tol,
        "figures": {
            "type": "boolean",
            "default": True,
            "description": "measure every tree against its own mesh (tree_figures.csv); "
            "false: scan only",
        },
        "sectors": {
            "type": "integer",
            "minimum": 1,
            "maximum": MAX_SECTORS,
            "default": 1,
            "description": "scan each station in this many azimuth sectors, one after "
            "another, each loading only the trees it can record: less memory at once for "
            "a large plot (one ray a pulse only)",
        },
        **source_schema(),
    }


def _parse_plot_scan(parameters: Mapping[str, Any]) -> PlotScanJob:
    import math

    data = dict(parameters)
    source = pop_source(data)
    stations = data.pop("stations", None)
    if stations is not None:
        try:
            stations = tuple(tuple(float(c) for c in s) for s in stations)
        except (TypeError, ValueError, OverflowError):
            stations = ((math.nan,),)
        _check_station_values(stations)
    tol = data.pop("tolerance_m", None)
    compare = merge(CompareParams(), {} if tol is None else {"tolerance_m": tol})
    figures = bool(data.pop("figures", True))
    sectors = data.pop("sectors", 1)
    scan = parse_scan(data)
    from treesim.errors import InvalidParameterError
    from treesim.plot.sectors import check_sectors

    try:
        sectors = check_sectors(sectors, scan.scanner)
    except InvalidParameterError as exc:
        raise field_error("sectors", f"sectors: {exc}") from None
    return PlotScanJob(scan, stations, compare, figures, source, sectors)


def _check_station_values(stations: tuple[tuple[float, ...], ...]) -> None:
    """At most :data:`MAX_STATIONS`, every coordinate finite and within
    :data:`STATION_COORD_MAX_M` (the schema's range; the model words it)."""
    import math

    if len(stations) > MAX_STATIONS:
        raise field_error(
            "stations", f"stations: {len(stations)} given; a plot scan takes at most {MAX_STATIONS}"
        )
    if not all(math.isfinite(c) for s in stations for c in s):
        raise field_error("stations", "stations: every coordinate must be a finite number")
    far = [c for s in stations for c in s if abs(c) > STATION_COORD_MAX_M]
    if far:
        raise field_error(
            "stations",
            f"stations: a coordinate of {far[0]:g} m is past {STATION_COORD_MAX_M:g} m, "
            "farther than any place on Earth in a projected frame; give the stations in "
            "metres in the plot's frame",
        )


def check_stations_reach(
    stations: list[Any], centre_xy: tuple[float, float], radius_m: float, max_range_m: float
) -> None:
    """Refuse stations that could record no tree of the plot: farther (horizontally) from
    its centre than its radius plus the scanner's ``max_range_m`` (a unit or frame error,
    e.g. local coordinates for a plot in UTM); at most :data:`MAX_STATIONS`.

    Examples
    --------
    >>> from treesim.plot.scan import Station
    >>> check_stations_reach([Station(position_m=(10.0, 0.0, 1.5))], (0.0, 0.0), 15.0, 100.0)
    >>> check_stations_reach([Station(position_m=(500.0, 0.0, 1.5))], (0.0, 0.0), 15.0, 100.0)
    Traceback (most recent call last):
    ...
    treesim.errors.InvalidParameterError: stations: station 1 at (500, 0) is 500 m from the plot's centre (0, 0), farther than its radius plus the scanner's max_range_m (115 m): it can record no tree of this plot; give the stations in the plot's frame
    """  # noqa: E501
    import math

    if len(stations) > MAX_STATIONS:
        raise field_error(
            "stations", f"stations: {len(stations)} given; a plot scan takes at most {MAX_STATIONS}"
        )
    cx, cy = (float(c) for c in centre_xy)
    reach_m = float(radius_m) + float(max_range_m)
    for i, st in enumerate(stations, start=1):
        x, y = float(st.position_m[0]), float(st.position_m[1])
        d_m = math.hypot(x - cx, y - cy)
        if not d_m <= reach_m:
            raise field_error(
                "stations",
                f"stations: station {i} at ({x:g}, {y:g}) is {d_m:.4g} m from the plot's "
                f"centre ({cx:g}, {cy:g}), farther than its radius plus the scanner's "
                f"max_range_m ({reach_m:.4g} m): it can record no tree of this plot; give "
                "the stations in the plot's frame",
            )


def _check_plot_scan(inputs: frozenset[str], job: PlotScanJob) -> None:
    job.source.check(inputs - {"stations"})
    if "stations" in inputs and job.stations is not None:
        raise field_error(
            "inputs.stations", "give the stations once: inputs.stations or parameters.stations"
        )


def _execute_plot_scan(
    inputs: Mapping[str, Path],
    job: PlotScanJob,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.plot.scan import plot_scan_files, plot_stations, read_stations_csv

    from ..plots import open_plot

    plot_inputs = {k: v for k, v in inputs.items() if k != "stations"}
    sp = job.scan
    with open_plot(job.source, plot_inputs, out) as (plot, _single, what):
        if "stations" in inputs:
            stations = read_stations_csv(inputs["stations"], plot, height_m=sp.height_m)
        else:
            stations = plot_stations(
                plot,
                positions=job.stations,
                n=sp.n_stations,
                distance_m=sp.distance_m,
                height_m=sp.height_m,
                start_angle_deg=sp.start_angle_deg,
            )
        check_stations_reach(stations, plot.centre_xy, plot.radius_m, sp.scanner.max_range_m)
        step = plot_scan_files(
            plot,
            out,
            sp,
            stations=stations,
            compare=job.compare,
            figures=job.figures,
            threads=threads,
            progress=progress,
            sectors=job.sectors,
        )
    s = step.summary
    rows = step.details["trees"]
    cov = [r["coverage"] for r in rows]
    return {
        "inputs": what,
        "plot": s["plot"],
        "points": s["points"],
        "rays_cast": s["rays_cast"],
        "stations": [
            {
                "position_m": st["position_m"],
                "points": st["points"],
                "trees_loaded": len(st["trees_loaded"]),
            }
            for st in s["stations"]
        ],
        "trees_measured": len(rows),
        "coverage": (
            {"min": min(cov), "mean": sum(cov) / len(cov), "max": max(cov)} if cov else None
        ),
        "warnings": s["warnings"],
        "timings_s": s["timings_s"],
    }


PROCESS = Process(
    id="plot-scan",
    title="Scan a plot and measure every tree in it",
    description="Scan a plot from stations, one at a time, loading only the trees "
    "each station can record; label every point with its tree_id; measure each "
    "tree's points against its own mesh (as treesim plot scan).",
    inputs=(
        *PLOT_INPUTS,
        Input(
            "stations",
            ("table",),
            "station positions: a plan job's stations.csv (x_m, y_m and z_m or "
            "height_m), instead of parameters.stations or the ring",
            required=False,
        ),
    ),
    outputs=(
        ("plot_scan.laz", "the simulated cloud with tree_id and station per point"),
        ("plot_scan.json", "scanner, stations, trees loaded, truth and figures"),
        ("tree_figures.csv", "one row per tree: points, coverage, AVOHD, DBH, height"),
        *STAND_OUTPUTS,
    ),
    extra_schema=_plot_scan_extra,
    base_schema=_plot_scan_schema,
    parse=_parse_plot_scan,
    execute=_execute_plot_scan,
    check_inputs=_check_plot_scan,
)
