"""A plot station's azimuth sectors: one station's scan cut into parts that each load
only the trees their columns can record (issue 25: a hectare's station holds tens of
millions of triangles; two of them at once do not fit one machine, a quarter of each
does).

A sector is a contiguous range of the scanner's columns, ``c0 <= column < c1``
(:func:`sector_columns`: equal shares of the whole turn). It loads the station's trees
whose box some pulse of its columns can reach (:func:`tree_columns`: the columns the
scanner's own window of the box gives, margins for jitter and the beam included), and
the station's terrain patch whole. Its scene reports the whole station's bounds
(``Scene.extent``: :func:`station_extent`), from which the caster measures its
tolerances and entry distance, so each pulse is cast and refined with the station's
float64 arithmetic (its noise, jitter and time are hashed from its line and column):
the sectors' points, concatenated in order, are the station's pulse for pulse, label for
label and tree for tree. Where a ray passes exactly through an edge two triangles share,
Open3D reports whichever its bounding-volume hierarchy meets first, and a sector's
hierarchy is not the station's: there the point can lie on the other triangle, microns
away (``benchmarks/bench_hectare.py`` counts them). The same
sectors give the same points bit for bit on every executor. A beam of several rays
samples a pulse's neighbours, which may lie in the next sector: :func:`check_sectors`
refuses that. :func:`merged_stats` and :func:`merged_lod` make one station's figures of
its sectors'.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..scan.rays import box_window, windowed_grid
from ..scan.result import StationStats
from ..scan.stations import Station

__all__ = [
    "BYTES_PER_TRIANGLE",
    "check_sectors",
    "memory_advice",
    "sector_columns",
    "station_sectors",
    "tree_columns",
]

#: What a loaded triangle costs at a station's peak while it casts (bytes; Open3D's copy
#: and its hierarchy, the scene's arrays, the default batch's buffers): what
#: ``benchmarks/bench_hectare.py`` prints at the default batch (docs/validation.md),
#: rounded up.
BYTES_PER_TRIANGLE = 220


def box_corners(bounds: np.ndarray) -> np.ndarray:
    """The eight corners (8, 3) of the axis-aligned box ``bounds`` (2, 3).

    Examples
    --------
    >>> box_corners(np.array([[0.0, 0, 0], [1, 2, 3]]))[[0, -1]].tolist()
    [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]
    """
    lo, hi = np.asarray(bounds, dtype=np.float64)
    return np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )


def check_sectors(sectors: Any, spec: Any) -> int:
    """``sectors`` as a checked count: an integer >= 1, and 1 for a beam of several
    rays (its pulses sample their neighbours, across a sector's edge too).

    Examples
    --------
    >>> from treesim.scan import ScannerSpec
    >>> check_sectors(4, ScannerSpec())
    4
    """
    if isinstance(sectors, bool) or not isinstance(sectors, int | np.integer) or sectors < 1:
        raise InvalidParameterError(f"sectors must be an integer >= 1, got {sectors!r}")
    if int(sectors) > 1 and spec.rays_per_pulse > 1:
        raise InvalidParameterError(
            f"sectors split a station's pulses by azimuth, but this scanner's beam casts "
            f"{spec.rays_per_pulse} rays a pulse that depend on the neighbouring pulses: "
            "scan with sectors=1 (--sectors 1), or with one ray a pulse"
        )
    if int(sectors) > spec.n_azimuth:
        raise InvalidParameterError(
            f"sectors must be at most the scanner's {spec.n_azimuth} columns, got {sectors}"
        )
    return int(sectors)


def sector_columns(spec: Any, sectors: int) -> list[tuple[int, int]]:
    """The column ranges ``(c0, c1)`` of ``sectors`` equal shares of the scanner's
    columns, in order.

    Examples
    --------
    >>> from treesim.scan import ScannerSpec
    >>> sector_columns(ScannerSpec(horizontal_resolution_deg=45.0), 2)  # 8 columns
    [(0, 4), (4, 8)]
    """
    n = spec.n_azimuth
    edges = [(n * j) // sectors for j in range(sectors + 1)]
    return [(edges[j], edges[j + 1]) for j in range(sectors)]


def tree_columns(bounds: np.ndarray, station: Station, spec: Any) -> np.ndarray:
    """The scan columns (sorted int64) whose pulses can reach the box ``bounds`` (2, 3)
    from ``station``: the scanner's window of the box (exact angles of the box's corners
    in the scanner frame, with the margins for jitter and the beam of
    :func:`~treesim.scan.rays.windowed_grid`).

    Examples
    --------
    >>> import numpy as np
    >>> from treesim.scan import ScannerSpec, Station
    >>> spec = ScannerSpec(horizontal_resolution_deg=1.0, vertical_resolution_deg=1.0)
    >>> box = np.array([[-1.0, 9.0, 0.0], [1.0, 11.0, 3.0]])  # 10 m north (+y)
    >>> cols = tree_columns(box, Station(position_m=(0.0, 0.0, 1.5)), spec)
    >>> int(cols.min()), int(cols.max())  # azimuth 90 deg ± 5.7 deg and the margins
    (81, 99)
    """
    rel = (box_corners(bounds) - station.position) @ station.rotation
    return windowed_grid(spec, box_window(rel.min(axis=0), rel.max(axis=0))).columns


def station_sectors(
    plot: Any, station: Station, spec: Any, ids: Sequence[int], sectors: int
) -> list[tuple[tuple[int, int] | None, list[int]]]:
    """The sectors of a station that records the trees ``ids``: ``(columns, trees)``
    each, in column order; one ``(None, ids)`` when ``sectors`` is 1. A tree goes to
    every sector its columns (:func:`tree_columns`) meet."""
    ids = list(ids)
    if sectors <= 1:
        return [(None, ids)]
    ranges = sector_columns(spec, sectors)
    edges = np.array([c0 for c0, _ in ranges] + [ranges[-1][1]])
    members: list[list[int]] = [[] for _ in ranges]
    for tid in ids:
        cols = tree_columns(plot.tree_bounds(tid), station, spec)
        if not len(cols):
            continue
        hit = np.unique(np.searchsorted(edges, cols, side="right") - 1)
        for j in hit[(hit >= 0) & (hit < len(ranges))]:
            members[int(j)].append(tid)
    return list(zip(ranges, members, strict=True))


def station_extent(plot: Any, ids: Sequence[int], patch: Any) -> np.ndarray | None:
    """(2, 3) bounds of a station's whole scene: its trees ``ids`` (their placed
    bounds) and its terrain ``patch`` (None: none); None when it holds nothing."""
    boxes = [plot.tree_bounds(t) for t in ids]
    if patch is not None and len(patch.faces):
        used = np.asarray(patch.vertices)[np.unique(np.asarray(patch.faces))]
        boxes.append(np.stack([used.min(axis=0), used.max(axis=0)]))
    if not boxes:
        return None
    stack = np.stack(boxes)
    return np.stack([stack[:, 0].min(axis=0), stack[:, 1].max(axis=0)])


def _azimuth_union(windows: list[Any]) -> tuple[float, float] | None:
    """The azimuth window (deg) spanning the sectors' windows; None (the whole turn)
    when one is, or when they span a turn."""
    if any(w is None for w in windows):
        return None
    ref = windows[0][0]
    lo = hi = None
    for a, b in windows:
        shift = 360.0 * np.floor((a - ref + 180.0) / 360.0)
        a, b = a - shift, b - shift
        lo = a if lo is None else min(lo, a)
        hi = b if hi is None else max(hi, b)
    assert lo is not None and hi is not None
    return None if hi - lo >= 360.0 else (float(lo), float(hi))


def merged_stats(parts: Sequence[StationStats]) -> StationStats:
    """One station's figures from its sectors' (counts and times summed, windows
    spanned)."""
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    cast = [p for p in parts if p.pulses_window]
    reasons: dict[str, int] = {}
    for p in parts:
        for key, value in (p.subray_reasons or {}).items():
            reasons[key] = reasons.get(key, 0) + value
    return StationStats(
        index=first.index,
        position_m=first.position_m,
        pulses_full_fov=first.pulses_full_fov,
        pulses_window=sum(p.pulses_window for p in parts),
        pulses_cast=sum(p.pulses_cast for p in parts),
        rays_cast=sum(p.rays_cast for p in parts),
        points=sum(p.points for p in parts),
        azimuth_window_deg=(_azimuth_union([p.azimuth_window_deg for p in cast]) if cast else None),
        elevation_window_deg=(
            (
                min(p.elevation_window_deg[0] for p in cast),
                max(p.elevation_window_deg[1] for p in cast),
            )
            if cast
            else first.elevation_window_deg
        ),
        time_s=sum(p.time_s for p in parts),
        pulses_subrays=sum(p.pulses_subrays for p in parts),
        subray_reasons=reasons or None,
        scan_duration_s=first.scan_duration_s,
    )


def merged_lod(parts: Sequence[dict[str, Any]], columns: Sequence[Any]) -> dict[str, Any]:
    """One station's level-of-detail account from its sectors' (each kept, with its
    columns)."""
    if len(parts) == 1:
        return parts[0]
    return {
        "mode": parts[0].get("mode"),
        "sectors": [
            {"columns": None if c is None else list(c), **lod}
            for c, lod in zip(columns, parts, strict=True)
        ],
    }


def memory_advice(
    triangles: Sequence[int], concurrent: int, sectors: int, available: int | None
) -> str | None:
    """A warning when the largest of ``triangles`` (each scene's: a station's, or a
    sector's) held ``concurrent`` times at once would take more than the ``available``
    memory (bytes; None: not known, no warning), with the number of sectors that would
    fit; None when it fits.

    Examples
    --------
    >>> memory_advice([80_000_000], 2, 1, 24 * 2**30) is not None
    True
    >>> memory_advice([5_000_000], 2, 1, 24 * 2**30) is None
    True
    """
    if available is None or not triangles:
        return None
    top = max(triangles)
    need = top * BYTES_PER_TRIANGLE * max(1, concurrent)
    if need <= available:
        return None
    # a sector holds about its share of the station's trees: a first guess, doubled for
    # the trees that straddle sectors and for stations that see most trees to one side
    suggest = int(min(64, 2 ** math.ceil(math.log2(2.0 * sectors * need / max(available, 1)))))
    what = "station" if sectors == 1 else "sector"
    return (
        f"a {what} holds up to {top / 1e6:.1f} M triangles: ~{need / 2**30:.1f} GiB while "
        f"{max(1, concurrent)} cast at once (~{BYTES_PER_TRIANGLE} B a triangle), more than "
        f"the {available / 2**30:.1f} GiB available; scan with sectors={suggest} "
        f"(--sectors {suggest}): each sector loads only the trees it can record"
    )
