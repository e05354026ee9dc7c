"""Ray generation: the scan grid, the angular window a scene subtends, seeded noise.

The scan grid of a station is fixed by its ``ScannerSpec``: pulse ``(line, column)``
points at elevation ``vfov[0] + line * vres`` and azimuth ``hfov[0] + column * hres``
(scanner frame). Windowing only chooses *which* grid pulses are cast, so a windowed
scan and a full-field scan give the same pulses the same indices and the same points.

Random models (range noise, angular jitter) draw from a counter-based generator keyed
by ``(seed, stream, station, line, column)``: each pulse's noise is independent of
chunking and windowing, so results are reproducible however the work is split.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..params import ScannerSpec

_U64 = np.uint64


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """Vectorised SplitMix64 finaliser on uint64 arrays (wrapping arithmetic)."""
    with np.errstate(over="ignore"):
        x = x + _U64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> _U64(27))) * _U64(0x94D049BB133111EB)
        return x ^ (x >> _U64(31))


def hashed_uniform(
    seed: int,
    stream: int,
    station: int,
    line: np.ndarray,
    column: np.ndarray,
    sub: int | np.ndarray = 0,
) -> np.ndarray:
    """Uniform (0, 1) float64 per pulse, a pure function of its key.

    ``sub`` separates draws of one pulse (e.g. per return); it may be an array.
    """
    key = _splitmix64(np.array([seed * 1_000_003 + stream], dtype=np.uint64))[0]
    sk = np.asarray(sub, dtype=np.uint64) + _U64(station * 65_537)
    k2 = _splitmix64(sk ^ key)
    lc = (np.asarray(line, dtype=np.uint64) << _U64(32)) | np.asarray(column, dtype=np.uint64)
    h = _splitmix64(lc ^ k2)
    return ((h >> _U64(11)).astype(np.float64) + 0.5) * (1.0 / 9007199254740992.0)


def hashed_normal(
    seed: int,
    stream: int,
    station: int,
    line: np.ndarray,
    column: np.ndarray,
    sub: int | np.ndarray = 0,
) -> np.ndarray:
    """Standard normal float64 per pulse (Box-Muller on two hashed uniforms)."""
    u1 = hashed_uniform(seed, 2 * stream, station, line, column, sub)
    u2 = hashed_uniform(seed, 2 * stream + 1, station, line, column, sub)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)


def _wrap180(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class AngularWindow:
    """Azimuth/elevation bounds (deg, scanner frame) of what a station can see."""

    azimuth_deg: tuple[float, float] | None  # None: the whole turn
    elevation_deg: tuple[float, float]
    min_distance_m: float
    max_distance_m: float


def box_window(lo: np.ndarray, hi: np.ndarray) -> AngularWindow:
    """Exact angular bounds of an axis-aligned box seen from the origin.

    ``lo`` and ``hi`` are the box corners in the scanner frame (station at the origin).
    """
    x0, y0, z0 = (float(v) for v in lo)
    x1, y1, z1 = (float(v) for v in hi)
    dx = max(x0, 0.0, -x1)
    dy = max(y0, 0.0, -y1)
    d_min_xy = math.hypot(dx, dy)
    cx = np.array([x0, x1, x1, x0])
    cy = np.array([y0, y0, y1, y1])
    d_max_xy = float(np.hypot(cx, cy).max())
    inside_xy = d_min_xy == 0.0
    if inside_xy:
        az = None
    else:
        ref = math.degrees(math.atan2(0.5 * (y0 + y1), 0.5 * (x0 + x1)))
        rel = _wrap180(np.degrees(np.arctan2(cy, cx)) - ref)
        az = (ref + float(rel.min()), ref + float(rel.max()))
    el_hi = math.degrees(math.atan2(z1, d_min_xy if z1 >= 0 else d_max_xy))
    el_lo = math.degrees(math.atan2(z0, d_max_xy if z0 >= 0 else d_min_xy))
    dz = max(z0, 0.0, -z1)
    dmin = math.sqrt(d_min_xy**2 + dz**2)
    dmax = math.sqrt(d_max_xy**2 + max(z0 * z0, z1 * z1))
    return AngularWindow(az, (el_lo, el_hi), dmin, dmax)


@dataclass(frozen=True)
class PulseGrid:
    """The pulses one station casts: every (line, column) in ``lines × columns``."""

    lines: np.ndarray  # (nl,) int64 elevation indices
    columns: np.ndarray  # (nc,) int64 azimuth indices

    @property
    def n_pulses(self) -> int:
        return len(self.lines) * len(self.columns)

    @property
    def offsets(self) -> np.ndarray:
        """(n_columns + 1,) index of each column's first pulse (and the end)."""
        return np.arange(len(self.columns) + 1, dtype=np.int64) * len(self.lines)

    def indices(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """(line, column) of pulses ``start:stop`` in column-major order (a scanner
        sweeps one vertical line per azimuth step)."""
        k = np.arange(start, stop, dtype=np.int64)
        nl = len(self.lines)
        return self.lines[k % nl], self.columns[k // nl]


def full_grid(spec: ScannerSpec) -> PulseGrid:
    """Every pulse of the field of view."""
    return PulseGrid(
        np.arange(spec.n_elevation, dtype=np.int64), np.arange(spec.n_azimuth, dtype=np.int64)
    )


def windowed_grid(spec: ScannerSpec, window: AngularWindow, margin_steps: float = 2.0) -> PulseGrid:
    """The grid pulses whose direction falls inside ``window`` plus a margin.

    The margin (in angular steps, plus any angular jitter's 6σ) absorbs the tiny
    difference between a pulse direction and its grid angle.
    """
    if window.min_distance_m > spec.max_range_m:
        return PulseGrid(np.empty(0, np.int64), np.empty(0, np.int64))
    vres, hres = spec.vertical_resolution_deg, spec.horizontal_resolution_deg
    jitter = 6.0 * spec.angular_jitter_sd_deg
    beam = math.degrees(spec.beam_divergence_mrad * 1e-3)  # full angle covers half-angle x2
    m_el = margin_steps * vres + jitter + beam
    v0 = spec.vertical_fov_deg[0]
    el_lo, el_hi = window.elevation_deg
    i0 = max(0, math.floor((el_lo - m_el - v0) / vres))
    i1 = min(spec.n_elevation - 1, math.ceil((el_hi + m_el - v0) / vres))
    if i1 < i0:
        return PulseGrid(np.empty(0, np.int64), np.empty(0, np.int64))
    lines = np.arange(i0, i1 + 1, dtype=np.int64)
    n_az = spec.n_azimuth
    if window.azimuth_deg is None:
        return PulseGrid(lines, np.arange(n_az, dtype=np.int64))
    # near the zenith/nadir a small azimuth margin is not enough: widen by 1/cos(el)
    el_max_abs = min(89.0, max(abs(el_lo), abs(el_hi)))
    m_az = (margin_steps * hres + jitter + beam) / math.cos(math.radians(el_max_abs))
    a_lo, a_hi = window.azimuth_deg
    h0 = spec.horizontal_fov_deg[0]
    rel_lo = (a_lo - m_az - h0) % 360.0
    rel_hi = rel_lo + (a_hi - a_lo) + 2 * m_az
    if rel_hi - rel_lo >= 360.0:
        return PulseGrid(lines, np.arange(n_az, dtype=np.int64))
    j0 = math.floor(rel_lo / hres)
    j1 = math.ceil(rel_hi / hres)
    cols = np.arange(j0, j1 + 1, dtype=np.int64)
    if spec.full_turn:
        cols = np.unique(cols % n_az)
    else:
        steps_per_turn = 360.0 / hres
        shifted = np.round(cols - steps_per_turn).astype(np.int64)
        cols = np.unique(np.concatenate([cols, shifted]))
        cols = cols[(cols >= 0) & (cols < n_az)]
    return PulseGrid(lines, cols)


def column_azimuth_rad(
    spec: ScannerSpec, columns: np.ndarray, heading_deg: float = 0.0
) -> np.ndarray:
    """Azimuth of scan columns (rad, float64): ``radians(h0 + heading_deg + column ×
    horizontal_resolution_deg)``, ``h0`` the start of ``spec.horizontal_fov_deg``.

    Parameters
    ----------
    spec : ScannerSpec
    columns : (n,) int
        Column indices (0 at ``h0``).
    heading_deg : float
        Added to ``h0`` first (the station heading, for levelled scanners).

    Returns
    -------
    (n,) float64
    """
    return np.radians(
        spec.horizontal_fov_deg[0] + heading_deg + columns * spec.horizontal_resolution_deg
    )


def line_elevation_rad(spec: ScannerSpec, lines: np.ndarray) -> np.ndarray:
    """Elevation of scan lines (rad, float64): ``radians(v0 + line ×
    vertical_resolution_deg)``, ``v0`` the start of ``spec.vertical_fov_deg``.

    Parameters
    ----------
    spec : ScannerSpec
    lines : (n,) int
        Line indices (0 at ``v0``).

    Returns
    -------
    (n,) float64
    """
    return np.radians(spec.vertical_fov_deg[0] + lines * spec.vertical_resolution_deg)


def pulse_angles(
    spec: ScannerSpec, station_index: int, lines: np.ndarray, columns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad, float64, scanner frame) of pulses, jitter included."""
    el = line_elevation_rad(spec, lines)
    az = column_azimuth_rad(spec, columns)
    if spec.angular_jitter_sd_deg > 0:
        sd = math.radians(spec.angular_jitter_sd_deg)
        az = az + sd * hashed_normal(spec.seed, 2, station_index, lines, columns)
        el = el + sd * hashed_normal(spec.seed, 3, station_index, lines, columns)
    return az, el


def directions(az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """Unit vectors (n, 3) float64 in the scanner frame."""
    ce = np.cos(el)
    return np.stack([ce * np.cos(az), ce * np.sin(az), np.sin(el)], axis=1)
