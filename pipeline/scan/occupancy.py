"""Where the scene can be: a conservative raster of each station's angular window.

A station's window (:func:`~treesim.scan.rays.windowed_grid`) is the rectangle of scan
lines × columns that the scene's bounding box subtends. For a tree most of that rectangle
is sky between the branches. This module finds, per station, the cells of the window that
some triangle can occupy, so that the scanner casts the fine grid only there.

**Conservative bounds.** For a triangle seen from the station (scanner frame, station at
the origin) the directions to its points form a spherical triangle. Its bounds are
computed without approximation in the safe direction:

* azimuth: the triangle's projection on the horizontal plane is convex; if it contains
  the vertical axis through the station every azimuth is possible, otherwise its
  azimuths lie between those of its vertices (a span < 180°);
* elevation: over the triangle ``z ∈ [z_min, z_max]`` and the horizontal distance
  ``r ∈ [r_min, r_max]``, ``r_min`` the exact distance from the axis to the projected
  triangle and ``r_max`` the largest vertex distance; ``atan2(z_max, r_min)`` (or
  ``r_max`` when ``z_max < 0``) bounds the elevation from above, and likewise below.

Each bound is widened by a margin covering every way a cast ray can depart from its
grid direction: float32 directions (~1e-7 rad), float32 vertices and ray origins (an
absolute error divided by the triangle's nearest distance), the beam's half-angle (its
sub-rays) and the largest angular jitter the hashed normal generator can draw
(:data:`JITTER_BOUND_SD`). A pulse outside every widened triangle cannot hit anything,
so skipping it changes no point: the tests compare with casting the whole window, bit
for bit.

**Long thin triangles** (tube facets, seen diagonally) have bounding boxes far larger than
themselves; pieces whose box covers more than :data:`MAX_PIECE_CELLS` raster cells are
bisected at their longest edge (the union of the halves is the triangle, so bounds stay
conservative) until the boxes are small.

**The raster** has at most :data:`MAX_CELLS` cells per station (cells of ``k × k`` grid
pulses when the window is larger), so its memory is bounded at any resolution; the pulses
are generated from it a chunk at a time (:class:`SparseGrid`), never all at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..params import ScannerSpec
from .rays import PulseGrid

#: Largest |hashed normal| the noise generator can return: its uniforms are at least
#: 2^-54, so sqrt(-2 ln u) <= 8.64; angular jitter never exceeds this many σ.
JITTER_BOUND_SD = 8.65
#: Largest raster per station (cells); larger windows get cells of k × k pulses.
MAX_CELLS = 1 << 22
#: Pieces whose box covers more cells than this are bisected (if not too many pieces).
MAX_PIECE_CELLS = 512
#: Cap on pieces after bisection (memory: ~200 B each).
MAX_PIECES = 1 << 21
#: Pieces bounded at once (bounds the temporaries of :func:`occupancy_grid`).
_PIECE_CHUNK = 1 << 18
#: Box corners buffered by the occupancy raster before they are counted (at least; a
#: quarter of the raster's cells when more): bounds the buffer whatever the triangles.
_FLUSH_CORNERS = 1 << 18
#: Direction error of float32 unit vectors and their products (rad), with room to spare.
_DIR_EPS_RAD = 1e-6


def pointing_margin_rad(spec: ScannerSpec) -> float:
    """How far (rad) a cast ray of ``spec`` can depart from its grid direction: float32
    rounding, the beam's half-angle (sub-rays) and the largest possible jitter."""
    half_beam = 0.5 * spec.beam_divergence_mrad * 1e-3 if spec.beam_model else 0.0
    jitter = JITTER_BOUND_SD * math.radians(spec.angular_jitter_sd_deg) * math.sqrt(2.0)
    return _DIR_EPS_RAD + 1.01 * half_beam + jitter


@dataclass(frozen=True)
class TriangleBounds:
    """Conservative angular bounds of triangles seen from a station (radians).

    ``az_lo``/``az_hi`` are meaningful where ``full_az`` is False (``az_hi - az_lo`` <
    π); ``d_min`` is a lower bound of each triangle's distance from the station.
    """

    az_lo: np.ndarray
    az_hi: np.ndarray
    full_az: np.ndarray
    el_lo: np.ndarray
    el_hi: np.ndarray
    d_min: np.ndarray


def _min_dist_to_origin_2d(x: Sequence[np.ndarray], y: Sequence[np.ndarray]) -> np.ndarray:
    """Exact distance from (0, 0) to each 2-D triangle (``x``, ``y``: its three corners'
    coordinates, (n,) each); 0 where a triangle contains the origin."""
    best = None
    for i in range(3):
        j = (i + 1) % 3
        ax, ay = x[i], y[i]
        ex, ey = x[j] - ax, y[j] - ay
        ee = ex * ex + ey * ey
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(ee > 0, -(ax * ex + ay * ey) / ee, 0.0)
        np.clip(t, 0.0, 1.0, out=t)
        d = np.hypot(ax + t * ex, ay + t * ey)
        best = d if best is None else np.minimum(best, d, out=best)
    # inside (or on the boundary): the three edge cross products do not change sign
    c = [x[i] * y[(i + 1) % 3] - y[i] * x[(i + 1) % 3] for i in range(3)]
    inside = ((c[0] >= 0) & (c[1] >= 0) & (c[2] >= 0)) | ((c[0] <= 0) & (c[1] <= 0) & (c[2] <= 0))
    best[inside] = 0.0
    return best


def _max3(a: Sequence[np.ndarray]) -> np.ndarray:
    return np.maximum(np.maximum(a[0], a[1]), a[2])


def _min3(a: Sequence[np.ndarray]) -> np.ndarray:
    return np.minimum(np.minimum(a[0], a[1]), a[2])


def triangle_bounds(tri: np.ndarray) -> TriangleBounds:
    """Conservative azimuth/elevation bounds of triangles ``tri`` (n, 3, 3) float64 in
    the scanner frame (station at the origin). See the module notes.

    Examples
    --------
    >>> import numpy as np
    >>> b = triangle_bounds(np.array([[[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 1.0]]]))
    >>> float(np.degrees(b.az_hi[0])), float(np.degrees(b.el_hi[0])), float(b.d_min[0])
    (45.0, 45.0, 1.0)
    """
    # corner by corner, coordinate by coordinate: (3, 3, n) contiguous rows
    return _rows_bounds(np.ascontiguousarray(np.asarray(tri, np.float64).transpose(1, 2, 0)))


def face_bounds(vertices: np.ndarray, faces: np.ndarray) -> TriangleBounds:
    """:func:`triangle_bounds` of the triangles ``faces`` (n, 3) of ``vertices`` (v, 3)
    float64 in the scanner frame, from their corner rows (:func:`face_rows`; no
    (n, 3, 3) array: the same figures, issue 25).

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 1.0]])
    >>> float(np.degrees(face_bounds(v, np.array([[0, 1, 2]])).az_hi[0]))
    45.0
    """
    return _rows_bounds(face_rows(vertices, faces))


def face_rows(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The triangles ``faces`` (n, 3) of ``vertices`` (v, 3) as corner rows (3, 3, n):
    corner, coordinate, triangle (``vertices[faces].transpose(1, 2, 0)``, each row
    contiguous).

    Examples
    --------
    >>> import numpy as np
    >>> v = np.arange(12.0).reshape(4, 3)
    >>> f = np.array([[0, 2, 3]])
    >>> bool((face_rows(v, f) == v[f].transpose(1, 2, 0)).all())
    True
    """
    return np.stack([np.take(vertices, faces[:, k], axis=0).T for k in range(3)])


def _rows_bounds(rows: np.ndarray) -> TriangleBounds:
    """:func:`triangle_bounds` of corner rows (3, 3, n)."""
    return _corner_bounds(rows[:, 0], rows[:, 1], rows[:, 2])


def _corner_bounds(
    x: Sequence[np.ndarray], y: Sequence[np.ndarray], z: Sequence[np.ndarray]
) -> TriangleBounds:
    """:func:`triangle_bounds` from the corners' coordinates (three (n,) each): every figure
    corner by corner (never an (n, 3) reduction; the same figures, issue 25)."""
    r_max = _max3([np.hypot(x[k], y[k]) for k in range(3)])
    r_min = _min_dist_to_origin_2d(x, y)
    z_min, z_max = _min3(z), _max3(z)
    el_hi = np.arctan2(z_max, np.where(z_max >= 0, r_min, r_max))
    el_lo = np.arctan2(z_min, np.where(z_min >= 0, r_max, r_min))
    # a triangle whose projection passes the vertical axis within rounding may contain
    # it: every azimuth (also ends the bisection of pieces around the axis)
    full = r_min <= 1e-12 * r_max
    az0 = np.arctan2(y[0], x[0])
    # each corner's azimuth from the first's, in [-π, π) (the first's own is 0: its
    # (a - a + π) % 2π - π is exactly 0, and a NaN first azimuth makes both ends NaN)
    rel = [(np.arctan2(y[k], x[k]) - az0 + np.pi) % (2 * np.pi) - np.pi for k in (1, 2)]
    az_lo = az0 + np.minimum(np.minimum(0.0, rel[0]), rel[1])
    az_hi = az0 + np.maximum(np.maximum(0.0, rel[0]), rel[1])
    dz = np.where((z_min <= 0) & (z_max >= 0), 0.0, np.minimum(np.abs(z_min), np.abs(z_max)))
    return TriangleBounds(az_lo, az_hi, full, el_lo, el_hi, np.hypot(r_min, dz))


def _length(d: np.ndarray) -> np.ndarray:
    """Lengths (n,) of vectors given as coordinate rows (3, n): the squares summed in
    order, the figure ``np.linalg.norm(e, axis=1)`` gives for the same vectors (n, 3)."""
    return np.sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2])


def _bisect_longest(rows: np.ndarray) -> np.ndarray:
    """Split each triangle, as corner rows (3, 3, n), at the midpoint of its longest
    edge: (3, 3, 2n), the first halves then the second ones."""
    e = np.stack([_length(rows[(j + 1) % 3] - rows[j]) for j in range(3)])
    k = e.argmax(axis=0)  # edge k runs from vertex k to vertex k+1 (the first longest)
    a, b, c = (np.take_along_axis(rows, ((k + j) % 3)[None, None], axis=0)[0] for j in range(3))
    n = rows.shape[2]
    out = np.empty((3, 3, 2 * n))
    out[0, :, :n], out[1, :, :n], out[2, :, :n] = a, 0.5 * (a + b), c
    out[0, :, n:], out[1, :, n:], out[2, :, n:] = out[1, :, :n], b, c
    return out


@dataclass(frozen=True)
class _Raster:
    """The window's geometry in raster terms."""

    line0: int  # first line of the window
    n_lines: int
    cell: int  # pulses per cell side
    rel_deg: np.ndarray  # (nc,) column angles from the window's start, sorted
    order: np.ndarray  # (nc,) window column indices in that (angular) order
    v0: float
    vres: float

    @property
    def shape(self) -> tuple[int, int]:
        return (-(-self.n_lines // self.cell), -(-len(self.order) // self.cell))


def _raster_for(spec: ScannerSpec, grid: PulseGrid, a_ref_deg: float) -> _Raster:
    h0, hres = spec.horizontal_fov_deg[0], spec.horizontal_resolution_deg
    rel = (h0 + grid.columns * hres - a_ref_deg) % 360.0
    order = np.argsort(rel, kind="stable")
    n_l, n_c = len(grid.lines), len(grid.columns)
    cell = max(1, math.ceil(math.sqrt(n_l * n_c / MAX_CELLS)))
    return _Raster(
        int(grid.lines[0]),
        n_l,
        cell,
        rel[order],
        order,
        spec.vertical_fov_deg[0],
        spec.vertical_resolution_deg,
    )


def _cell_boxes(
    b: TriangleBounds, margin_rad: np.ndarray, ras: _Raster, a_ref_deg: float
) -> tuple[np.ndarray, ...]:
    """Cell-index boxes of bounded pieces: (row0, row1, col0, col1, wrap_col1, keep);
    ``wrap_col1`` >= 0 adds the columns ``0..wrap_col1`` (an interval past 360°)."""
    m = margin_rad
    el_lo = np.degrees(b.el_lo - m)
    el_hi = np.degrees(b.el_hi + m)
    i_lo = np.floor((el_lo - ras.v0) / ras.vres) - ras.line0
    i_hi = np.ceil((el_hi - ras.v0) / ras.vres) - ras.line0
    keep = (i_hi >= 0) & (i_lo <= ras.n_lines - 1)
    i_lo = np.clip(i_lo, 0, ras.n_lines - 1).astype(np.int64)
    i_hi = np.clip(i_hi, 0, ras.n_lines - 1).astype(np.int64)
    # azimuth margin grows as 1/cos(elevation) towards the poles
    el_abs = np.maximum(np.abs(b.el_lo), np.abs(b.el_hi)) + m
    cos_el = np.cos(np.minimum(el_abs, np.pi / 2))
    with np.errstate(divide="ignore", over="ignore"):  # the masked lanes only
        m_az = np.where(cos_el > 1e-3, (m + 1e-12) / cos_el, np.inf)
    a_lo = np.degrees(b.az_lo - m_az)
    span = np.degrees(b.az_hi - b.az_lo + 2 * m_az)
    full = b.full_az | ~np.isfinite(span) | (span >= 360.0 - 1e-9)
    with np.errstate(invalid="ignore"):
        rl = np.where(full, 0.0, (a_lo - a_ref_deg) % 360.0)
    rh = np.where(full, 360.0, rl + np.where(full, 0.0, span))
    rel = ras.rel_deg
    n_c = len(rel)
    c_lo = np.searchsorted(rel, rl, side="left")
    c_hi = np.searchsorted(rel, np.minimum(rh, 360.0), side="right") - 1
    wrap = np.full(len(rh), -1, dtype=np.intp)
    past = ~full & (rh >= 360.0)  # the columns past 360° of those that wrap
    wrap[past] = np.searchsorted(rel, rh[past] - 360.0, side="right") - 1
    keep &= (c_hi >= c_lo) | (wrap >= 0)
    c_lo = np.minimum(c_lo, n_c - 1)
    c_hi = np.maximum(c_hi, -1)
    k = ras.cell
    return (i_lo // k, i_hi // k, c_lo // k, np.where(c_hi >= 0, c_hi // k, -1), wrap, keep)


def occupancy_grid(
    vertices: np.ndarray,
    faces: np.ndarray,
    spec: ScannerSpec,
    window: PulseGrid,
    a_ref_deg: float,
    *,
    abs_error_m: float,
) -> SparseGrid:
    """The window's pulses that some triangle can reach.

    Parameters
    ----------
    vertices : (v, 3) float64
        Vertices in the scanner frame (station at the origin).
    faces : (n, 3) int
        The triangles, ``vertices[faces]``: gathered a chunk at a time (never all at
        once: 72 bytes a triangle).
    spec : ScannerSpec
    window : PulseGrid
        The station's window (contiguous lines; columns sorted).
    a_ref_deg : float
        An azimuth (deg, scanner frame) at or before the window's first column, from
        which column angles are measured without wrapping inside the window.
    abs_error_m : float
        Bound of the absolute position error of float32 vertices and ray origins.
    """
    if window.n_pulses == 0 or len(faces) == 0:
        return SparseGrid.empty()
    occ = Occupancy(spec, window, a_ref_deg, abs_error_m=abs_error_m)
    # the triangles a chunk at a time (the bounds' temporaries are ~200 B a triangle)
    for a in range(0, len(faces), _PIECE_CHUNK):
        f = np.asarray(faces[a : a + _PIECE_CHUNK])
        occ.add(face_bounds(vertices, f), lambda sel, f=f: face_rows(vertices, f[sel]))
    return occ.grid()


class Occupancy:
    """:func:`occupancy_grid` fed from outside: the triangles' bounds a chunk at a time
    (:meth:`add`, e.g. those the planning bounds anyway to choose the triangles to
    load), then :meth:`grid`, which bisects the big pieces and returns the pulses.

    A piece's figures do not depend on the others and the raster counts integers, so
    the chunks' sizes and order change nothing: the same pulses as
    :func:`occupancy_grid` over the same triangles.

    Examples
    --------
    >>> import numpy as np
    >>> from treesim.scan import ScannerSpec
    >>> from treesim.scan.rays import box_window, windowed_grid
    >>> spec = ScannerSpec(horizontal_resolution_deg=1.0, vertical_resolution_deg=1.0)
    >>> tri = np.array([[[5.0, -1.0, 0.0], [5.0, 1.0, 0.0], [5.0, 0.0, 1.0]]])
    >>> win = windowed_grid(spec, box_window(tri[0].min(axis=0), tri[0].max(axis=0)))
    >>> occ = Occupancy(spec, win, 0.0, abs_error_m=1e-6)
    >>> occ.add(triangle_bounds(tri), lambda sel: tri[sel].transpose(1, 2, 0))
    >>> 0 < occ.grid().n_pulses <= win.n_pulses
    True
    """

    def __init__(
        self, spec: ScannerSpec, window: PulseGrid, a_ref_deg: float, *, abs_error_m: float
    ) -> None:
        self.window, self.a_ref_deg, self.abs_error_m = window, a_ref_deg, abs_error_m
        self.ras = _raster_for(spec, window, a_ref_deg)
        self.m_ray = pointing_margin_rad(spec)
        self.diff = _DiffRaster(*self.ras.shape, self.ras.cell)
        # this level's pieces, and the boxes and corners of its big ones (which wait
        # for the level's verdict: bisected, or added as they are)
        self.n_pieces = 0
        self.waiting: list[tuple[np.ndarray, ...]] = []
        self.bigs: list[np.ndarray] = []

    def add(
        self,
        b: TriangleBounds,
        corners: Callable[[np.ndarray], np.ndarray],
        keep: np.ndarray | None = None,
    ) -> None:
        """Pieces with bounds ``b`` (those where ``keep``, default all): the boxes of
        those that are not big are added at once; ``corners(mask)`` gives the corner rows
        (3, 3, k) of the big ones (:func:`face_rows`; kept until :meth:`grid`)."""
        self.n_pieces += len(b.d_min) if keep is None else int(np.count_nonzero(keep))
        margin = self.m_ray + self.abs_error_m / np.maximum(b.d_min, 1e-300)
        r0, r1, c0, c1, w, boxed = _cell_boxes(b, margin, self.ras, self.a_ref_deg)
        if keep is not None:
            boxed &= keep
        # a box past 360° covers its columns up to the seam and those from 0 to w: counted
        # as the whole raster's width, a piece at the seam stayed big however small it
        # was cut, and the seam's pieces doubled every level up to MAX_PIECES
        cells = self.ras.cell
        width = np.where(
            w >= 0, np.maximum(c1 - c0 + 1, 0) + w // cells + 1, np.maximum(c1 - c0 + 1, 1)
        )
        area = (r1 - r0 + 1) * width
        big = boxed & (area > MAX_PIECE_CELLS) & (b.d_min > 0) & ~b.full_az
        small = boxed & ~big
        self.diff.add_boxes(r0[small], r1[small], c0[small], c1[small], w[small])
        if big.any():
            self.waiting.append((r0[big], r1[big], c0[big], c1[big], w[big]))
            self.bigs.append(corners(big))

    def grid(self) -> SparseGrid:
        """The window's pulses that some piece can reach (the big pieces bisected at
        their longest edge, level by level, until none is big)."""
        for halvings in range(41):
            n_big = sum(t.shape[2] for t in self.bigs)
            if n_big == 0 or self.n_pieces + n_big > MAX_PIECES or halvings == 40:
                # a piece's box is conservative however large: keep it
                if self.waiting:
                    boxes = (np.concatenate([x[i] for x in self.waiting]) for i in range(5))
                    self.diff.add_boxes(*boxes)
                break
            bigs = self.bigs[0] if len(self.bigs) == 1 else np.concatenate(self.bigs, axis=2)
            self.bigs, self.waiting, self.n_pieces = [], [], 0
            pieces = _bisect_longest(bigs)
            del bigs
            for a in range(0, pieces.shape[2], _PIECE_CHUNK):
                chunk = pieces[:, :, a : a + _PIECE_CHUNK]
                self.add(_rows_bounds(chunk), lambda sel, chunk=chunk: chunk[:, :, sel])
            del pieces
        n_rows, n_cols = self.ras.shape
        occ = self.diff.counts().cumsum(axis=0).cumsum(axis=1)[:n_rows, :n_cols] > 0
        return SparseGrid.from_raster(self.window, self.ras, occ)


class _DiffRaster:
    """The occupancy raster's difference array, filled box by box: a box of cells adds
    +1 and -1 at its four corners, and the raster's cumulative sums (:meth:`counts`)
    give each cell the boxes over it. Integers, so the order in which boxes come does not
    matter: the corners are buffered and counted (``np.bincount``) whenever the buffer
    holds a quarter of the raster's size, never kept per piece (issue 25: the planning held
    ~150 B a triangle when every box waited for the end)."""

    def __init__(self, n_rows: int, n_cols: int, cell: int) -> None:
        self.shape = (n_rows + 1, n_cols + 1)
        self.n = self.shape[0] * self.shape[1]
        self.cell = cell
        self.diff = np.zeros(self.n, dtype=np.int64)
        self.pending: dict[int, list[np.ndarray]] = {1: [], -1: []}
        self.n_pending = 0
        self.flush_at = max(self.n // 4, _FLUSH_CORNERS)

    def add_boxes(
        self, r0: np.ndarray, r1: np.ndarray, c0: np.ndarray, c1: np.ndarray, w: np.ndarray
    ) -> None:
        """Boxes ``[r0..r1] × [c0..c1]`` of cells (where ``c1 >= c0``), plus
        ``[r0..r1] × [0..w // cell]`` where ``w >= 0`` (an interval past 360°)."""
        stride = self.shape[1]
        wc = np.where(w >= 0, w // self.cell, -1)
        boxes = [(r0, r1, c0, c1, c1 >= c0), (r0, r1, np.zeros_like(wc), wc, wc >= 0)]
        for a0, a1, b0, b1, ok in boxes:
            a0, a1, b0, b1 = a0[ok], a1[ok] + 1, b0[ok], b1[ok] + 1
            for rr, cc, sgn in ((a0, b0, 1), (a0, b1, -1), (a1, b0, -1), (a1, b1, 1)):
                self.pending[sgn].append(rr * stride + cc)
                self.n_pending += len(rr)
        if self.n_pending >= self.flush_at:
            self._flush()

    def _flush(self) -> None:
        for sgn, idx in self.pending.items():
            if idx:
                count = np.bincount(np.concatenate(idx), minlength=self.n)
                if sgn > 0:
                    self.diff += count
                else:
                    self.diff -= count
                idx.clear()
        self.n_pending = 0

    def counts(self) -> np.ndarray:
        """The difference array, (rows + 1, columns + 1) int64, every box counted."""
        self._flush()
        return self.diff.reshape(self.shape)


class SparseGrid:
    """Some pulses of a window, in the window's order (column by column, lines rising).

    Built from an occupancy raster: each window column carries the lines of the occupied
    cells of its raster column. Behaves like :class:`~treesim.scan.rays.PulseGrid`
    (``n_pulses``, ``indices(start, stop)``) without ever holding every pulse.
    """

    def __init__(
        self,
        columns: np.ndarray,
        col_lines: np.ndarray,
        indptr: np.ndarray,
        lines: np.ndarray,
    ) -> None:
        self.columns = columns  # (nc,) window columns, in output order
        self.col_set = col_lines  # (nc,) which line set each column uses
        self.indptr = indptr  # (n_sets + 1,) CSR pointers into ``lines``
        self.lines_data = lines  # concatenated line sets
        counts = (indptr[1:] - indptr[:-1])[col_lines]
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    @classmethod
    def empty(cls) -> SparseGrid:
        return cls(np.empty(0, np.int64), np.empty(0, np.int64), np.zeros(1, np.int64), np.empty(0))

    @classmethod
    def from_raster(cls, window: PulseGrid, ras: _Raster, occ: np.ndarray) -> SparseGrid:
        k = ras.cell
        n_rows, n_cols = occ.shape
        indptr = [0]
        data = []
        for c in range(n_cols):
            rows = np.flatnonzero(occ[:, c])
            if len(rows):
                ln = (rows[:, None] * k + np.arange(k)[None, :]).reshape(-1)
                ln = ln[ln < ras.n_lines] + ras.line0
            else:
                ln = np.empty(0, np.int64)
            data.append(ln.astype(np.int64))
            indptr.append(indptr[-1] + len(ln))
        # column (window order) -> raster column: through its angular position
        pos = np.empty(len(ras.order), np.int64)
        pos[ras.order] = np.arange(len(ras.order))
        col_set = pos // k
        lines = np.concatenate(data) if data else np.empty(0, np.int64)
        return cls(window.columns, col_set, np.asarray(indptr, np.int64), lines)

    @property
    def n_pulses(self) -> int:
        return int(self.offsets[-1])

    def indices(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """(line, column) of pulses ``start:stop``."""
        if stop <= start:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        # the columns the range touches, then each pulse's column by repetition
        c0 = int(np.searchsorted(self.offsets, start, side="right")) - 1
        c1 = int(np.searchsorted(self.offsets, stop - 1, side="right"))
        off = self.offsets[c0 : c1 + 1]
        counts = np.diff(np.clip(off, start, stop))
        ci = np.repeat(np.arange(c0, c1), counts)
        within = np.arange(start, stop, dtype=np.int64) - self.offsets[ci]
        line = self.lines_data[self.indptr[self.col_set[ci]] + within]
        return line, self.columns[ci]


#: Cap on the samples and pulses a thin-geometry mask enumerates (beyond it every cast
#: pulse counts as near thin geometry).
THIN_MAX_PULSES = 1 << 23


def angular_inradius_rad(tri: np.ndarray) -> np.ndarray:
    """Angular inradius (rad) of each triangle ``tri`` (n, 3, 3) seen from the origin:
    the inradius of the triangle of its unit direction vectors (small-angle). A triangle
    whose inradius is at least the angular step contains a grid direction."""
    u = tri / np.maximum(np.linalg.norm(tri, axis=2, keepdims=True), 1e-300)
    area2 = np.linalg.norm(np.cross(u[:, 1] - u[:, 0], u[:, 2] - u[:, 0]), axis=1)
    perimeter = (
        np.linalg.norm(u[:, 1] - u[:, 0], axis=1)
        + np.linalg.norm(u[:, 2] - u[:, 1], axis=1)
        + np.linalg.norm(u[:, 0] - u[:, 2], axis=1)
    )
    return area2 / np.maximum(perimeter, 1e-300)


def seen_sides(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each triangle's longest side as seen from the origin, from its corners' unit
    directions ``u`` (n, 3, 3): the side's end directions (n, 3) each, its angular length
    and the angular distance of the opposite corner from the side's great circle (rad; the
    triangle lies within that distance of the side where the angles at its ends are acute).

    Examples
    --------
    >>> u = np.array([[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]])
    >>> ua, ub, length, width = seen_sides(u)
    >>> bool(np.isclose(length[0], np.pi / 2) and np.isclose(width[0], np.pi / 2))
    True
    """
    side = np.stack(
        [
            np.linalg.norm(u[:, 1] - u[:, 0], axis=1),
            np.linalg.norm(u[:, 2] - u[:, 1], axis=1),
            np.linalg.norm(u[:, 0] - u[:, 2], axis=1),
        ],
        axis=1,
    ).argmax(axis=1)
    rows = np.arange(len(u))
    ua, ub, uc = u[rows, side], u[rows, (side + 1) % 3], u[rows, (side + 2) % 3]
    normal = np.cross(ua, ub)
    nn = np.linalg.norm(normal, axis=1)
    length = np.arctan2(nn, np.einsum("ij,ij->i", ua, ub))
    with np.errstate(invalid="ignore", divide="ignore"):
        width = np.where(
            nn > 0,
            np.arcsin(np.clip(np.abs(np.einsum("ij,ij->i", uc, normal)) / nn, 0.0, 1.0)),
            np.arccos(np.clip(np.einsum("ij,ij->i", ua, uc), -1.0, 1.0)),
        )
    return ua, ub, length, width


#: A closed part is thin where its local thickness subtends fewer angular steps than this.
THIN_STEPS = 1.5


def thin_triangles(tri: np.ndarray, thickness_m: np.ndarray, spec: ScannerSpec) -> np.ndarray:
    """Which triangles (``tri`` (n, 3, 3) in the scanner's frame, the station at the
    origin) are *thin* geometry that central rays can miss between them: of a closed part
    whose local thickness (``thickness_m``, e.g. a branch's diameter) subtends less than
    :data:`THIN_STEPS` angular steps (the coarser of the two), or of an open part
    (``thickness_m`` inf: a leaf) whose own angular inradius is under a step.

    Examples
    --------
    >>> from treesim.params import ScannerSpec
    >>> spec = ScannerSpec(horizontal_resolution_deg=0.1, vertical_resolution_deg=0.1)
    >>> tri = np.array([[[10.0, 0, 0], [10.0, 0.1, 0], [10.0, 0, 0.1]]])
    >>> thin_triangles(tri, np.array([0.01]), spec).tolist()  # a 1 cm twig at 10 m
    [True]
    >>> thin_triangles(tri, np.array([0.5]), spec).tolist()
    [False]
    """
    step = math.radians(max(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
    centroid_m = np.linalg.norm(tri.mean(axis=1), axis=1)
    closed = np.isfinite(thickness_m)
    with np.errstate(invalid="ignore"):
        out = thickness_m < THIN_STEPS * step * centroid_m
    # an open part's triangles alone need their angular inradius
    open_ = np.flatnonzero(~closed)
    out[open_] = angular_inradius_rad(tri[open_]) < step
    return out


def thin_mask(
    tri: np.ndarray,
    spec: ScannerSpec,
    grid: PulseGrid | SparseGrid,
    *,
    abs_error_m: float,
    thickness_m: np.ndarray,
    max_pulses: int = THIN_MAX_PULSES,
) -> np.ndarray | None:
    """Pulses whose beam footprint can touch *thin* geometry, which central rays can
    miss between them while the beam's sub-rays hit it: a triangle of a closed part
    whose local thickness (``thickness_m``, e.g. a branch's diameter) subtends less than
    1.5 angular steps from the station (a twig thinner than the point spacing), or of an
    open part (``thickness_m`` inf: a leaf) whose own angular inradius is under a step.

    Each thin triangle is covered by samples along its longest side's great-circle arc
    (at most half a step apart), each widened by the triangle's angular width, half the
    sample spacing and the margin of :func:`occupancy_grid` (which includes the beam's
    half-angle), at pulse resolution; a twig's facets give the same samples, which are
    merged before the boxes are enumerated.

    Samples and boxes are handled in batches, so memory stays bounded. Returns sorted
    unique keys ``column * n_elevation + line`` (int64), or None when they would be more
    than ``max_pulses`` or :data:`THIN_MAX_PULSES`, or a box reaches a pole: then every
    pulse must be treated as near thin geometry.
    """
    if grid.n_pulses == 0 or len(tri) == 0:
        return np.empty(0, np.int64)
    idx = np.flatnonzero(thin_triangles(tri, thickness_m, spec))
    if len(idx) == 0:
        return np.empty(0, np.int64)
    if max(spec.n_elevation, spec.n_azimuth) >= 1 << 19:
        return None  # the boxes' integer keys give lines and columns 20 bits
    t = tri[idx]
    u = t / np.linalg.norm(t, axis=2, keepdims=True)
    # the longest side of each thin triangle (as seen) and the angular distance of the
    # opposite corner from its great circle: every direction of the triangle is within
    # that distance of the side (the angles at the side's ends are acute)
    ua, ub, length, width = seen_sides(u)
    d_min = triangle_bounds(t).d_min
    margin = pointing_margin_rad(spec) + abs_error_m / np.maximum(d_min, 1e-300)
    vres = math.radians(spec.vertical_resolution_deg)
    hres = math.radians(spec.horizontal_resolution_deg)
    gap = 0.5 * min(vres, hres)
    n_s = np.ceil(length / gap).astype(np.int64) + 1
    # boxes of pulses around samples, in batches of triangles (bounded memory), merged
    # through one integer key each: a twig's facets give the same boxes
    cum = np.cumsum(n_s)
    cuts = np.searchsorted(cum, np.arange(_SAMPLE_BATCH, int(cum[-1]), _SAMPLE_BATCH))
    boxes = []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(t)], strict=True):
        if hi <= lo:
            continue
        sel = slice(int(lo), int(hi))
        got = _sample_boxes(ua[sel], ub[sel], length[sel], width[sel], margin[sel], n_s[sel], spec)
        if got is None:
            return None
        boxes.append(got)
    box = np.unique(np.concatenate(boxes))
    l0, c0 = (box >> 42) - 1, (box >> 22) & ((1 << 20) - 1)
    rl, rc = (box >> 11) & ((1 << 11) - 1), box & ((1 << 11) - 1)
    n = (2 * rl + 1) * (2 * rc + 1)
    cum = np.cumsum(n)
    if int(cum[-1]) > 8 * THIN_MAX_PULSES:
        return None
    cuts = np.searchsorted(cum, np.arange(_SAMPLE_BATCH, int(cum[-1]), _SAMPLE_BATCH))
    keys = np.empty(0, np.int64)
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(box)], strict=True):
        sel = slice(int(lo), int(hi))
        keys = np.union1d(keys, _box_pulses(l0[sel], c0[sel], rl[sel], rc[sel], spec))
        if len(keys) > min(max_pulses, THIN_MAX_PULSES):
            return None
    return keys


#: Samples (and box pulses) handled at once by :func:`thin_mask`.
_SAMPLE_BATCH = 1 << 20


def _sample_boxes(
    ua: np.ndarray,
    ub: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    margin: np.ndarray,
    n_s: np.ndarray,
    spec: ScannerSpec,
) -> np.ndarray | None:
    """Integer keys of the pulse boxes around samples along arcs ``ua`` → ``ub`` (slerp,
    ``n_s`` samples each); None where a box would reach a pole or be too wide."""
    k = np.repeat(np.arange(len(ua)), n_s)
    f = (np.arange(int(n_s.sum())) - np.repeat(np.cumsum(n_s) - n_s, n_s)) / np.maximum(
        n_s[k] - 1, 1
    )
    ang = length[k]
    with np.errstate(invalid="ignore", divide="ignore"):
        sa = np.where(ang > 1e-12, np.sin((1 - f) * ang) / np.sin(ang), 1 - f)
        sb = np.where(ang > 1e-12, np.sin(f * ang) / np.sin(ang), f)
    d = sa[:, None] * ua[k] + sb[:, None] * ub[k]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    el = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
    az = np.arctan2(d[:, 1], d[:, 0])
    radius = margin[k] + 1.01 * width[k] + 0.5 * (length[k] / np.maximum(n_s[k] - 1, 1))
    cos_el = np.cos(np.minimum(np.abs(el) + radius, math.pi / 2))
    if (cos_el < 1e-3).any():
        return None  # at the poles a box of columns is the whole turn: give up the mask
    vres = math.radians(spec.vertical_resolution_deg)
    hres = math.radians(spec.horizontal_resolution_deg)
    v0, h0 = spec.vertical_fov_deg[0], spec.horizontal_fov_deg[0]
    line = (np.degrees(el) - v0) / spec.vertical_resolution_deg
    col = ((np.degrees(az) - h0) % 360.0) / spec.horizontal_resolution_deg
    l0, c0 = np.rint(line).astype(np.int64), np.rint(col).astype(np.int64)
    rl = np.ceil(radius / vres + 0.5).astype(np.int64)
    rc = np.ceil(radius / (hres * cos_el) + 0.5).astype(np.int64)
    if max(rl.max(), rc.max()) >= 1 << 11:
        return None
    l0 = np.maximum(l0, -1)  # a box centred below line -1 moved up still covers lines >= 0
    return np.unique((((l0 + 1) << 20 | c0) << 11 | rl) << 11 | rc)


def _box_pulses(
    l0: np.ndarray, c0: np.ndarray, rl: np.ndarray, rc: np.ndarray, spec: ScannerSpec
) -> np.ndarray:
    """Unique keys ``column * n_elevation + line`` of the pulses in boxes centred on
    (``l0``, ``c0``) with half-sizes (``rl``, ``rc``), wrapped or clipped to the field
    of view."""
    n = (2 * rl + 1) * (2 * rc + 1)
    b = np.repeat(np.arange(len(n)), n)
    j = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    lines = l0[b] - rl[b] + j % (2 * rl[b] + 1)
    cols = c0[b] - rc[b] + j // (2 * rl[b] + 1)
    if spec.full_turn:
        cols %= spec.n_azimuth
    else:  # columns past 360° wrap onto the start of the field of view
        steps = 360.0 / spec.horizontal_resolution_deg
        cols = np.where(cols >= spec.n_azimuth, np.rint(cols - steps).astype(np.int64), cols)
    ok = (lines >= 0) & (lines < spec.n_elevation) & (cols >= 0) & (cols < spec.n_azimuth)
    return np.unique(cols[ok] * spec.n_elevation + lines[ok])


def reachable(b: TriangleBounds, spec: ScannerSpec, *, abs_error_m: float) -> np.ndarray:
    """Which triangles (their :func:`triangle_bounds` from a station) that station,
    scanning with ``spec``, can record.

    False only where no ray can produce a point: the whole triangle lies beyond
    ``max_range_m``, or its widened angular bounds miss the field of view. Nearer than
    ``min_range_m`` is kept (a near triangle records nothing but still occludes).
    """
    m = pointing_margin_rad(spec) + abs_error_m / np.maximum(b.d_min, 1e-300)
    v0, v1 = (math.radians(a) for a in spec.vertical_fov_deg)
    ok = (b.d_min <= spec.max_range_m) & (b.el_hi + m >= v0) & (b.el_lo - m <= v1)
    if spec.full_turn:
        return ok
    h0, h1 = spec.horizontal_fov_deg
    el_abs = np.maximum(np.abs(b.el_lo), np.abs(b.el_hi)) + m
    cos_el = np.cos(np.minimum(el_abs, np.pi / 2))
    # a triangle through the station: its margin ~1e295, over a cosine: infinite
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        m_az = np.where(cos_el > 1e-3, m / cos_el, np.inf)
        a_lo = np.degrees(b.az_lo - m_az)
        span = np.degrees(b.az_hi - b.az_lo + 2 * m_az)
        rel = (a_lo - h0) % 360.0
    full = b.full_az | ~np.isfinite(span) | (span >= 360.0)
    return ok & (full | (rel <= h1 - h0) | (rel + span >= 360.0))
