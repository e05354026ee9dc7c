"""The ground of a field plot cloud: which points are ground, and a DTM raster of it.

A TLS plot cloud (ground, understory, stems, crowns; possibly at a 5e6 m projected-CRS
offset) is worked on in a local frame (the grid's lower-left corner and the lowest point
subtracted) in three steps:

1. **Seeds** (:func:`classify_ground`): the lowest point of every 5 cm column
   (:data:`SEED_CELL_M`) goes to the Cloth Simulation Filter (CSF, Zhang et al. 2016,
   the ``cloth-simulation-filter`` package), which drapes a cloth under the inverted
   cloud and calls ground what lies within ``class_threshold_m`` of it. Thinning to the
   lowest point per column keeps the cloth off stems and shrubs (CSF pins each cloth
   node to its *nearest* point) and makes a 20-million-point plot a few-second job.
2. **DTM** (:func:`build_dtm`): per cell the median of the ground heights, then the ground
   points more than ``class_threshold_m`` off it are dropped and each cell takes the
   :data:`DTM_PERCENTILE` of its points' heights *detrended* by the local slope (on a 15°
   slope a 0.5 m cell spans 13 cm of height; without detrending any percentile but the
   median is biased). Cells without ground are filled linearly from those with it, the
   nearest value outside their hull.
3. **Labels**: every point of the cloud within ``class_threshold_m`` of the DTM is ground.

:func:`ground_and_dtm` does all three and refuses a cloud that has no ground (see
:func:`check_ground`).
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import EmptyInputError, InputFormatError, InvalidGeometryError, InvalidParameterError
from ._surface import surface_from_grid
from ._surface import write_asc as _write_asc

__all__ = [
    "DTM_PERCENTILE",
    "SEED_CELL_M",
    "Dtm",
    "build_dtm",
    "check_ground",
    "classify_ground",
    "ground_and_dtm",
    "heights_above_ground",
]

#: CSF sees the lowest point of each column this wide (m).
SEED_CELL_M = 0.05
#: The percentile of a cell's slope-detrended ground heights its DTM value is: low enough
#: that the foot of a stem (its lowest 15 cm is within the ground threshold) and leaf
#: litter do not lift it (median: 11 cm too high beside a stem in the synthetic test plot;
#: 20th percentile: 3 cm), at the cost of ~0.8 sigma of the scanner's noise low.
DTM_PERCENTILE = 20.0
#: Times the cells are detrended by the slope of the grid before (the first: of the medians).
DETREND_PASSES = 3
#: Rounds of "DTM of the ground, then ground = within the threshold of it" after CSF (the
#: second reaches ground the cloth missed, e.g. where it hung on crowns at the plot's edge).
LABEL_PASSES = 2
#: Fewer ground points than this is no ground.
MIN_GROUND_POINTS = 30
#: Points this far below the DTM (m) are "under the ground" for :func:`check_ground`.
BELOW_M = 0.5
#: More than this share of the cloud under the ground: the "ground" is not the ground.
MAX_BELOW_SHARE = 0.02
#: Ground in less than this share of the cells the cloud occupies: no ground (a synthetic
#: plot with its ground cut off keeps "ground" at stem feet and shrub bottoms in ~10 %).
MIN_GROUND_COVER = 0.25


@dataclass(frozen=True, eq=False)
class Dtm:
    """A digital terrain model: ground heights on a square grid.

    Attributes
    ----------
    x0_m, y0_m : float
        The grid's lower-left corner, in the cloud's coordinates (:func:`build_dtm` puts
        the cell centres on multiples of ``cell_m``).
    cell_m : float
        The cell size.
    z : (ny, nx) float64
        Heights at the cell centres; row 0 is the southern row (y ascending, as
        :func:`treesim.plot._surface.read_asc` returns them, whose ``z`` is ``Dtm.z.T``).
    coverage : float
        Share of the cells that held ground points (the others are interpolated).
    ground_points : int
        Ground points the heights came from.

    Examples
    --------
    >>> import numpy as np
    >>> d = Dtm(0.0, 0.0, 1.0, np.array([[0.0, 1.0], [2.0, 3.0]]))
    >>> float(d.height_at(1.0, 1.0))
    1.5
    """

    x0_m: float
    y0_m: float
    cell_m: float
    z: np.ndarray
    coverage: float = 1.0
    ground_points: int = 0

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``."""
        return self.z.shape

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre x (nx,) and y (ny,), computed as ``read_asc`` computes them."""
        ny, nx = self.z.shape
        xs = (self.x0_m + 0.5 * self.cell_m) + self.cell_m * np.arange(nx)
        ys = (self.y0_m + 0.5 * self.cell_m) + self.cell_m * np.arange(ny)
        return xs, ys

    def height_at(self, x, y) -> np.ndarray:
        """The ground height at ``x, y`` (bilinear between cell centres, clamped outside;
        the same function :func:`treesim.plot._surface.surface_from_dtm` gives its file)."""
        xs, ys = self.centres()
        return surface_from_grid(xs, ys, self.z.T)(x, y)

    def write_asc(self, path: str | Path) -> Path:
        """Write the DTM as an ESRI ASCII grid (a ``Terrain(kind="dtm")`` reads it)."""
        return _write_asc(path, self.x0_m, self.y0_m, self.cell_m, self.z.T)

    def figures(self) -> dict:
        """Size, cover and height range, for a report."""
        ny, nx = self.z.shape
        return {
            "nx": nx,
            "ny": ny,
            "cell_m": float(self.cell_m),
            "coverage": round(float(self.coverage), 4),
            "ground_points": int(self.ground_points),
            "z_min_m": float(np.min(self.z)),
            "z_max_m": float(np.max(self.z)),
        }


@dataclass(frozen=True)
class _Grid:
    """A grid covering a cloud's xy bounds, and the cloud's local frame (its corner)."""

    x0: float
    y0: float
    z0: float
    cell: float
    nx: int
    ny: int

    @classmethod
    def cover(cls, pts: np.ndarray, cell: float) -> _Grid:
        """Cell centres on multiples of ``cell`` whose rectangle holds every point (so the
        bilinear DTM is never clamped inside the cloud)."""
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        cx, cy = np.floor(lo[0] / cell) * cell, np.floor(lo[1] / cell) * cell
        nx = int(np.ceil((hi[0] - cx) / cell)) + 1
        ny = int(np.ceil((hi[1] - cy) / cell)) + 1
        return cls(
            float(cx - 0.5 * cell), float(cy - 0.5 * cell), float(lo[2]), float(cell), nx, ny
        )

    def local(self, pts: np.ndarray) -> np.ndarray:
        return pts - np.array([self.x0, self.y0, self.z0])

    def cell_of(self, xl: np.ndarray, yl: np.ndarray) -> np.ndarray:
        """Flat cell index (row-major, (ny, nx)) of local x, y."""
        i = np.clip(np.floor(xl / self.cell).astype(np.int64), 0, self.nx - 1)
        j = np.clip(np.floor(yl / self.cell).astype(np.int64), 0, self.ny - 1)
        return j * self.nx + i

    def surface(self, z: np.ndarray):
        """Bilinear height function of a filled (ny, nx) grid, in the local frame."""
        xs = 0.5 * self.cell + self.cell * np.arange(self.nx)
        ys = 0.5 * self.cell + self.cell * np.arange(self.ny)
        return surface_from_grid(xs, ys, z.T)


def _as_points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise InputFormatError(f"a cloud must be an (N, 3) array of x, y, z; got shape {pts.shape}")
    pts = pts[:, :3]
    if len(pts) == 0:
        raise EmptyInputError("the cloud has no points; there is no ground to find")
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise InvalidGeometryError(
            f"{int(bad.sum())} of {len(pts)} points have NaN or infinite coordinates; "
            "drop them before looking for the ground"
        )
    return pts


def _check_params(**values: float) -> None:
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            raise InvalidParameterError(f"{name} must be a positive number of metres, got {v}")


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Send the C-level stdout (file descriptor 1) to the null device for a while."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            try:
                yield
            finally:
                _flush_c_stdout()
                os.dup2(saved, 1)
    finally:
        os.close(saved)


def _flush_c_stdout() -> None:
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).fflush(None)


def _lowest_per_column(local: np.ndarray, cell: float) -> np.ndarray:
    """Indices of the lowest point of each ``cell``-wide xy column."""
    ij = np.floor(local[:, :2] / cell).astype(np.int64)
    key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    order = np.lexsort((local[:, 2], key))
    ks = key[order]
    first = np.ones(len(ks), dtype=bool)
    first[1:] = ks[1:] != ks[:-1]
    return order[first]


def _csf_ground(
    local: np.ndarray, resolution: float, threshold: float, rigidness: int, smooth: bool
):
    """Indices of the points of ``local`` that CSF calls ground (its prints silenced)."""
    import CSF

    csf = CSF.CSF()
    csf.params.cloth_resolution = float(resolution)
    csf.params.class_threshold = float(threshold)
    csf.params.rigidness = int(rigidness)
    csf.params.bSloopSmooth = bool(smooth)
    ground, other = CSF.VecInt(), CSF.VecInt()
    with _quiet_stdout():
        csf.setPointCloud(np.ascontiguousarray(local))
        csf.do_filtering(ground, other, exportCloth=False)
    return np.fromiter(ground, dtype=np.int64, count=len(ground))


def _cell_percentile(key: np.ndarray, r: np.ndarray, n_cells: int, q: float) -> np.ndarray:
    """The ``q``-th percentile (linear) of ``r`` in each cell; NaN for empty cells."""
    out = np.full(n_cells, np.nan)
    if len(r) == 0:
        return out
    order = np.lexsort((r, key))
    rs = r[order]
    count = np.bincount(key, minlength=n_cells)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    has = count > 0
    pos = start[has] + q / 100.0 * (count[has] - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, start[has] + count[has] - 1)
    t = pos - lo
    out[has] = rs[lo] * (1 - t) + rs[hi] * t
    return out


def _fill(zc: np.ndarray) -> np.ndarray:
    """Fill NaN cells linearly from the others (Delaunay in cell indices), the nearest
    cell's value outside their hull."""
    have = np.isfinite(zc)
    if have.all():
        return zc
    from scipy.interpolate import LinearNDInterpolator
    from scipy.ndimage import distance_transform_edt
    from scipy.spatial import QhullError

    out = zc.copy()
    jj, ii = np.nonzero(have)
    mj, mi = np.nonzero(~have)
    if len(ii) >= 3:
        try:
            lin = LinearNDInterpolator(np.c_[ii, jj].astype(np.float64), zc[have])
            out[mj, mi] = lin(np.c_[mi, mj].astype(np.float64))
        except QhullError:  # all on a line: nearest everywhere
            pass
    miss = ~np.isfinite(out)
    if miss.any():
        idx = distance_transform_edt(~have, return_distances=False, return_indices=True)
        out[miss] = zc[tuple(idx)][miss]
    return out


def _grid_heights(grid: _Grid, local: np.ndarray, threshold: float) -> tuple[np.ndarray, int, int]:
    """Robust DTM (ny, nx) of local ground points, the number of cells that held ground
    and the number of ground points kept."""
    n = grid.nx * grid.ny
    key = grid.cell_of(local[:, 0], local[:, 1])
    first = _fill(_cell_percentile(key, local[:, 2], n, 50.0).reshape(grid.ny, grid.nx))
    h = local[:, 2] - grid.surface(first)(local[:, 0], local[:, 1])
    keep = np.abs(h) <= threshold
    if keep.sum() < 3:  # nothing agrees: keep the medians
        return first, int(np.isfinite(first).sum()), int(len(local))
    k, pk = key[keep], local[keep]
    dx = pk[:, 0] - (k % grid.nx + 0.5) * grid.cell
    dy = pk[:, 1] - (k // grid.nx + 0.5) * grid.cell
    z = first
    for _ in range(DETREND_PASSES):  # the slope of the last grid, then the cells again
        gy, gx = _gradient(z, grid.cell)
        r = pk[:, 2] - gx.ravel()[k] * dx - gy.ravel()[k] * dy
        zc = _cell_percentile(k, r, n, DTM_PERCENTILE).reshape(grid.ny, grid.nx)
        z = _fill(zc)
    return z, int(np.isfinite(zc).sum()), int(keep.sum())


def _gradient(z: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """``np.gradient`` (d/dy, d/dx) of a grid, zero across a direction one cell wide."""
    gy = np.gradient(z, cell, axis=0) if z.shape[0] > 1 else np.zeros_like(z)
    gx = np.gradient(z, cell, axis=1) if z.shape[1] > 1 else np.zeros_like(z)
    return gy, gx


def _classify(pts: np.ndarray, res: float, thr: float, rigidness: int, smooth: bool) -> np.ndarray:
    grid = _Grid.cover(pts, res)
    local = grid.local(pts)
    seeds = _lowest_per_column(local, SEED_CELL_M)
    ground = seeds[_csf_ground(local[seeds], res, thr, rigidness, smooth)]
    if len(ground) < 3:
        return np.zeros(len(pts), dtype=bool)
    for _ in range(LABEL_PASSES):  # DTM of the ground so far, then every point by it
        z, _, _ = _grid_heights(grid, local[ground], thr)
        mask = np.abs(local[:, 2] - grid.surface(z)(local[:, 0], local[:, 1])) <= thr
        ground = np.flatnonzero(mask)
        if len(ground) < 3:
            break
    return mask


def classify_ground(
    points,
    *,
    cloth_resolution_m: float = 0.5,
    class_threshold_m: float = 0.15,
    rigidness: int = 2,
    slope_smooth: bool = True,
) -> np.ndarray:
    """Which points of a plot cloud are ground (the Cloth Simulation Filter, then a DTM).

    Parameters
    ----------
    points : (N, 3) array
        The cloud, in metres (any offset: the work is done in a local frame).
    cloth_resolution_m : float
        CSF's cloth grid spacing, also the cell of the DTM the points are labelled by.
    class_threshold_m : float
        Ground is within this height of the cloth (CSF) and then of the DTM.
    rigidness : {1, 2, 3}
        CSF's cloth stiffness: 1 steep terrain, 2 gentle relief, 3 flat.
    slope_smooth : bool
        CSF's post-processing of steep slopes.

    Returns
    -------
    (N,) bool
        True for ground. The same cloud always gives the same mask (CSF is deterministic).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(0, 10, (5000, 2))
    >>> ground = np.c_[xy, 0.1 * xy[:, 0]]
    >>> stem = np.c_[np.full(500, 5.0), np.full(500, 5.0), rng.uniform(1.0, 8, 500)]
    >>> mask = classify_ground(np.r_[ground, stem])
    >>> bool(mask[:5000].all()), bool(mask[5000:].any())
    (True, False)
    """
    pts = _as_points(points)
    _check_params(cloth_resolution_m=cloth_resolution_m, class_threshold_m=class_threshold_m)
    if rigidness not in (1, 2, 3):
        raise InvalidParameterError(
            f"rigidness must be 1 (steep), 2 (gentle relief) or 3 (flat), got {rigidness}"
        )
    return _classify(pts, cloth_resolution_m, class_threshold_m, rigidness, slope_smooth)


def build_dtm(points, ground_mask, *, cell_m: float = 0.5, class_threshold_m: float = 0.15) -> Dtm:
    """A DTM raster over a cloud's xy bounds from its ground points.

    Per cell the :data:`DTM_PERCENTILE` of the ground heights detrended by the local slope
    (after dropping ground points more than ``class_threshold_m`` off a first, median DTM);
    cells without ground filled linearly from those with it, the nearest value outside
    their hull.

    Parameters
    ----------
    points : (N, 3) array
        The cloud.
    ground_mask : (N,) bool
        Its ground points (:func:`classify_ground`).
    cell_m : float
        The cell size; the cell centres are multiples of it, the outer ones on or beyond
        the cloud's bounds (so the DTM interpolates, never clamps, inside the cloud).
    class_threshold_m : float
        Ground points further than this from the first DTM are dropped.

    Returns
    -------
    Dtm

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> xy = rng.uniform(0, 4, (4000, 2))
    >>> pts = np.c_[xy, 2.0 + 0.5 * xy[:, 1]]
    >>> d = build_dtm(pts, np.ones(len(pts), bool), cell_m=1.0)
    >>> d.shape, round(float(d.height_at(2.0, 3.0)), 2)
    ((5, 5), 3.5)
    """
    pts = _as_points(points)
    _check_params(cell_m=cell_m, class_threshold_m=class_threshold_m)
    mask = np.asarray(ground_mask, dtype=bool)
    if mask.shape != (len(pts),):
        raise InvalidParameterError(
            f"the ground mask has shape {mask.shape}; it must have one entry per point ({len(pts)})"
        )
    if mask.sum() < 3:
        raise InputFormatError(
            f"no ground found under the plot: {int(mask.sum())} ground points; "
            "is the ground cropped off the cloud?"
        )
    grid = _Grid.cover(pts, cell_m)
    z, cells, n_ground = _grid_heights(grid, grid.local(pts[mask]), class_threshold_m)
    return Dtm(
        x0_m=grid.x0,
        y0_m=grid.y0,
        cell_m=float(cell_m),
        z=z + grid.z0,
        coverage=cells / (grid.nx * grid.ny),
        ground_points=n_ground,
    )


def heights_above_ground(points, dtm: Dtm) -> np.ndarray:
    """Each point's height above the DTM (negative below it).

    Examples
    --------
    >>> import numpy as np
    >>> d = Dtm(0.0, 0.0, 1.0, np.full((2, 2), 10.0))
    >>> heights_above_ground(np.array([[0.5, 0.5, 12.0]]), d).tolist()
    [2.0]
    """
    pts = _as_points(points)
    return pts[:, 2] - dtm.height_at(pts[:, 0], pts[:, 1])


def check_ground(points, ground_mask, dtm: Dtm) -> list[str]:
    """Refuse a cloud whose "ground" is not a ground; warnings for a doubtful one.

    The rule: there is no ground under the plot when fewer than :data:`MIN_GROUND_POINTS`
    points are ground, when ground lies in less than :data:`MIN_GROUND_COVER` of the
    (``dtm.cell_m``) cells the cloud occupies, or when more than :data:`MAX_BELOW_SHARE`
    of the cloud lies over :data:`BELOW_M` *below* the DTM: a real ground has nothing
    under it but noise, a surface draped over stem ends, shrubs or crown bottoms of a
    cloud cropped above the ground has the rest of those stems below it.

    Raises
    ------
    InputFormatError
        No ground.

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 5, (2000, 2))
    >>> pts = np.c_[xy, np.zeros(2000)]
    >>> check_ground(pts, np.ones(2000, bool), Dtm(-0.25, -0.25, 0.5, np.zeros((11, 11))))
    []
    """
    pts = _as_points(points)
    mask = np.asarray(ground_mask, dtype=bool)
    n_ground = int(mask.sum())
    hint = "is the ground cropped off the cloud, or is this a single tree without its foot?"
    if n_ground < MIN_GROUND_POINTS:
        raise InputFormatError(
            f"no ground found under the plot: {n_ground} ground points (at least "
            f"{MIN_GROUND_POINTS} needed); {hint}"
        )
    grid = _Grid(dtm.x0_m, dtm.y0_m, 0.0, dtm.cell_m, dtm.shape[1], dtm.shape[0])
    cells = grid.cell_of(pts[:, 0] - grid.x0, pts[:, 1] - grid.y0)
    occupied = np.unique(cells)
    cover = len(np.unique(cells[mask])) / len(occupied)
    if cover < MIN_GROUND_COVER:
        raise InputFormatError(
            f"no ground found under the plot: ground in {cover:.1%} of the {len(occupied)} "
            f"{dtm.cell_m:g} m cells the cloud covers; {hint}"
        )
    below = float(np.mean(heights_above_ground(pts, dtm) < -BELOW_M))
    if below > MAX_BELOW_SHARE:
        raise InputFormatError(
            f"no ground found under the plot: the lowest surface found has {below:.1%} of the "
            f"points more than {BELOW_M:g} m below it, so it lies on stems, shrubs or crowns, "
            f"not on the ground; {hint}"
        )
    warnings = []
    if cover < 0.5:
        warnings.append(
            f"ground seen in only {cover:.0%} of the plot's cells; the DTM elsewhere is "
            "interpolated and may be off by decimetres on sloping ground"
        )
    return warnings


def ground_and_dtm(
    points,
    *,
    cell_m: float = 0.5,
    cloth_resolution_m: float = 0.5,
    class_threshold_m: float = 0.15,
    rigidness: int = 2,
    slope_smooth: bool = True,
) -> tuple[np.ndarray, Dtm, list[str]]:
    """The ground points of a plot cloud, its DTM and warnings (:func:`classify_ground`,
    :func:`build_dtm`, :func:`check_ground`).

    Returns
    -------
    mask : (N,) bool
        Ground points.
    dtm : Dtm
        The terrain, ``cell_m`` cells over the cloud's xy bounds.
    warnings : list of str
        Doubts about the result (little ground seen).

    Raises
    ------
    InputFormatError
        The cloud has no ground under it (see :func:`check_ground`).

    Examples
    --------
    >>> mask, dtm, warnings = ground_and_dtm(cloud.points)  # doctest: +SKIP
    >>> dtm.write_asc("twin/dtm.asc")  # doctest: +SKIP
    """
    pts = _as_points(points)
    mask = classify_ground(
        pts,
        cloth_resolution_m=cloth_resolution_m,
        class_threshold_m=class_threshold_m,
        rigidness=rigidness,
        slope_smooth=slope_smooth,
    )
    if mask.sum() < MIN_GROUND_POINTS:
        check_ground(pts, mask, Dtm(0.0, 0.0, cell_m, np.zeros((1, 1))))  # raises
    dtm = build_dtm(pts, mask, cell_m=cell_m, class_threshold_m=class_threshold_m)
    return mask, dtm, check_ground(pts, mask, dtm)
