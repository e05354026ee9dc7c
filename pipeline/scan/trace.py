"""Casting: stations × pulse grids → Open3D ``RaycastingScene`` → float64 hits.

Which pulses: each station's window (the angular rectangle of the scene's bounding box),
narrowed to the cells some triangle can reach (:mod:`treesim.scan.occupancy`; the same
points, bit for bit). Under ``lod="auto"`` triangles no station can record are never
loaded, and the beam model's sub-rays go only to pulses whose footprint can straddle an
edge (:class:`_AdaptiveBeam`); ``ScanResult.lod`` says what ran and why.

Precision: the scene is shifted into a :class:`~treesim.frame.LocalFrame` (float64)
before Open3D (float32) sees it; each ray starts just before the scene's bounding box
(moved forward in float64, from the float64 direction), so float32 never holds a long
range; every hit is then recomputed in float64 as the intersection of the ray with the
hit triangle's plane. Where float32 can have picked the neighbour of the triangle the
float64 ray meets (within its error of an edge), the float64 hit is checked against the
triangle's edges and, outside them, the triangles around it are tested in float64
(:meth:`_Caster.refine`): every point lies on a triangle of the mesh to float64 rounding
(measured ≤ 1e-12 m at 2 km; the README promises 1e-9 m). Whether a ray that passes
within float32's error of an edge (about 1e-6 of the scene's size, plus of the station's
distance when it is within 50 m) meets the surface there remains float32's choice.
Points leave in the input's coordinates as float64. A pulse's float32 ray is gathered
from per-station tables, so it is the same bits whichever pulses are cast beside it.

Warnings: a scan that runs but may not be what was meant says so in
``ScanResult.warnings`` (and the summary's ``warnings``): a station on a surface or
enclosed by a mesh whose normals face it, and triangles lost to precision (zero area in
float64 as given, or distorted in float32 around the local frame, which Open3D casts in).

Memory: pulses are cast in chunks of at most ``chunk_rays`` rays (about 200 bytes per
ray in flight), and with a ``sink`` each chunk's points leave as they are made, so peak
memory does not grow with the resolution or the number of points.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._system import cpu_count
from ..cloud import LABEL_CODES, LABEL_NAMES, Cloud
from ..errors import InvalidParameterError, ResourceLimitError, ScanError
from ..frame import LocalFrame
from ..geometry import triangles_around, vertex_triangles
from ..params import LODS, ScannerSpec
from ..scene import Scene
from . import beam as beam_model
from .estimate import (
    OVERHEAD,
    SAMPLE_PULSES,
    SECONDS_PER_POINT,
    ScanEstimate,
    human_time,
)
from .occupancy import occupancy_grid, reachable, thin_mask, triangle_bounds
from .rays import (
    PulseGrid,
    box_window,
    column_azimuth_rad,
    directions,
    full_grid,
    hashed_normal,
    line_elevation_rad,
    pulse_angles,
    windowed_grid,
)
from .stations import Station

Progress = Callable[[float, str], None]
#: Receives each chunk of a scan: points (n, 3) float64 and per-point fields.
Sink = Callable[[np.ndarray, dict[str, np.ndarray]], None]

#: Rays Open3D casts per second per core on this kind of machine (measured, hits and
#: misses mixed); used only for the estimate printed when a scan is refused.
_EST_RAYS_PER_S = 2.0e6
#: Bytes per ray in flight (Open3D's ≈57 B plus treesim's float64 bookkeeping).
BYTES_PER_RAY = 200
#: Share of a scene's triangles lost to precision (zero area in float64, or distorted in
#: float32) from which a scan warns: a few degenerate triangles are common and harmless.
DEGENERATE_WARN_FRACTION = 0.01
#: A triangle is distorted in float32 when rounding its vertices to float32 moves one by
#: more than this share of its shortest edge.
DISTORTED_SHARE = 0.1
#: Share of the 26 directions around a station that must cross the geometry an odd
#: number of times for it to count as enclosed (a few rays through shared edges or
#: vertices can miscount).
ENCLOSED_FRACTION = 0.9


@dataclass
class StationStats:
    """What one station cast and recorded."""

    index: int
    position_m: tuple[float, float, float]
    pulses_full_fov: int
    pulses_window: int
    pulses_cast: int
    rays_cast: int
    points: int
    azimuth_window_deg: tuple[float, float] | None
    elevation_window_deg: tuple[float, float]
    time_s: float
    #: pulses given sub-rays (beam model), and why (adaptive sampling)
    pulses_subrays: int = 0
    subray_reasons: dict[str, int] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "position_m": list(self.position_m),
            "pulses_full_fov": self.pulses_full_fov,
            "pulses_window": self.pulses_window,
            "pulses_cast": self.pulses_cast,
            "rays_cast": self.rays_cast,
            "points": self.points,
            "azimuth_window_deg": list(self.azimuth_window_deg)
            if self.azimuth_window_deg
            else None,
            "elevation_window_deg": list(self.elevation_window_deg),
            "time_s": self.time_s,
            "pulses_subrays": self.pulses_subrays,
            **({"subray_reasons": dict(self.subray_reasons)} if self.subray_reasons else {}),
        }


@dataclass
class ScanResult:
    """A simulated cloud and how it was made.

    ``cloud.fields`` holds, per point: ``station`` (uint16), ``range_m`` (float64),
    ``incidence_deg`` (float32), ``label`` (uint8, see ``cloud.metadata['label_names']``),
    ``return_number``, ``number_of_returns`` (uint8), ``intensity`` (uint16),
    ``scan_line`` (elevation step index, int32) and ``scan_column`` (azimuth step index,
    int32); and ``tree_id`` (uint32) when the scene's parts carry tree ids (a plot).
    """

    cloud: Cloud
    spec: ScannerSpec
    stations: list[Station]
    station_stats: list[StationStats]
    frame: LocalFrame
    bvh_build_s: float
    total_s: float
    window: bool
    cull: bool = False
    points_written: int = 0
    lod: dict[str, Any] = field(default_factory=dict)
    models: list[str] = field(default_factory=list)
    #: one-line sentences: the scan ran, but maybe not as meant (see the module's notes)
    warnings: list[str] = field(default_factory=list)

    @property
    def n_points(self) -> int:
        """Points made: in ``cloud``, or handed to the sink."""
        return len(self.cloud) + self.points_written

    @property
    def rays_cast(self) -> int:
        return sum(s.rays_cast for s in self.station_stats)

    @property
    def rays_full_fov(self) -> int:
        return sum(s.pulses_full_fov for s in self.station_stats) * self.spec.rays_per_pulse

    def summary(self) -> dict[str, Any]:
        return {
            "points": self.n_points,
            "rays_cast": self.rays_cast,
            "rays_full_fov": self.rays_full_fov,
            "pulses_window": sum(s.pulses_window for s in self.station_stats),
            "pulses_cast": sum(s.pulses_cast for s in self.station_stats),
            "window": self.window,
            "cull": self.cull,
            "lod": self.lod,
            "bvh_build_s": self.bvh_build_s,
            "total_s": self.total_s,
            "models_active": self.models,
            "warnings": list(self.warnings),
            "frame_origin_m": list(self.frame.origin),
            "scanner": self.spec.to_dict(),
            "stations": [s.to_dict() for s in self.station_stats],
        }


def _grid_for(
    verts_local: np.ndarray, o: np.ndarray, rot: np.ndarray, spec: ScannerSpec, window: bool
) -> tuple[PulseGrid, Any]:
    rel = (verts_local - o) @ rot  # scanner frame
    win = box_window(rel.min(axis=0), rel.max(axis=0))
    grid = windowed_grid(spec, win) if window else full_grid(spec)
    return grid, win


class _Caster:
    """The Open3D scene plus float64 triangle data for refinement."""

    def __init__(
        self, scene: Scene, frame: LocalFrame, nthreads: int, keep: np.ndarray | None = None
    ) -> None:
        import open3d as o3d

        self.o3d = o3d
        self.nthreads = int(nthreads)
        v = frame.to_local(scene.vertices)
        f = scene.faces if keep is None else scene.faces[keep]
        self.v, self.faces = v, f
        self._thickness: np.ndarray | None = None
        self.v0 = v[f[:, 0]]
        self.normal = np.empty((len(f), 3))
        # each triangle's smallest height (twice its area over its longest edge: how far
        # its interior reaches from an edge) and its shortest edge squared (the
        # distortion check's), a chunk at a time (the same figures, row by row)
        self.h_min32 = np.empty(len(f), dtype=np.float32)
        short2 = np.empty(len(f))
        for a in range(0, len(f), _BOUNDS_CHUNK):
            b = min(len(f), a + _BOUNDS_CHUNK)
            p0 = self.v0[a:b]
            v1, v2 = v[f[a:b, 1]], v[f[a:b, 2]]
            n = np.cross(v1 - p0, v2 - p0)
            twice_area = np.linalg.norm(n, axis=1)
            self.normal[a:b] = n / twice_area[:, None]
            sq_edge = np.stack([_sq_len(v1 - p0), _sq_len(v2 - v1), _sq_len(v2 - p0)])
            self.h_min32[a:b] = (twice_area / np.sqrt(sq_edge.max(axis=0))).astype(np.float32)
            short2[a:b] = sq_edge.min(axis=0)
            del p0, v1, v2, n, twice_area, sq_edge
        self.label = scene.face_label if keep is None else scene.face_label[keep]
        ft = scene.face_tree
        self.tree = None if ft is None else (ft if keep is None else ft[keep])
        self.lo, self.hi = frame.to_local(scene.bounds)
        self.pad = 1e-3 + 1e-5 * float(np.linalg.norm(self.hi - self.lo))
        self.radius = float(np.linalg.norm(np.maximum(np.abs(self.lo), np.abs(self.hi))))
        self._fan: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        v32 = v.astype(np.float32)
        self.distorted, self.moved_m = _distorted(v, v32, f, short2)
        del short2
        self.rc = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        self.rc.add_triangles(o3d.core.Tensor(v32), o3d.core.Tensor(f.astype(np.uint32)))
        t0 = time.perf_counter()
        # Open3D builds its BVH lazily on the first query: build it now, timed apart.
        self.cast(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
        self.build_s = time.perf_counter() - t0

    def thickness_m(self) -> np.ndarray:
        """Local thickness of the geometry behind each triangle (m): the distance from
        its centroid, inwards along its normal, to the next surface (a branch's
        diameter on a tube); inf where nothing is behind it (a leaf, an open sheet)."""
        if self._thickness is None:
            f = self.faces
            centroid = (self.v[f[:, 0]] + self.v[f[:, 1]] + self.v[f[:, 2]]) / 3.0
            inset = 1e-5 + 1e-7 * np.linalg.norm(centroid, axis=1)
            rays = np.empty((len(f), 6), dtype=np.float32)
            rays[:, :3] = centroid - (inset[:, None] * self.normal)
            rays[:, 3:] = -self.normal
            t, _, _ = self.cast_f32(rays)
            self._thickness = np.where(np.isfinite(t), t.astype(np.float64) + inset, np.inf)
        return self._thickness

    #: Stations nearer the scene's bounds than this cast from their own position;
    #: farther ones start every ray this close to the bounds (float32 keeps ~1e-7 of
    #: the ray's length, so 50 m costs at most ~3 µm before the float64 refinement).
    NEAR_M = 50.0

    def entry_distance(self, o: np.ndarray) -> float:
        """How far every ray from ``o`` can start without skipping any surface: the
        distance from ``o`` to the scene's (padded) bounding box, minus the pad, or 0
        when that is under ``NEAR_M``."""
        gap = np.maximum(np.maximum(self.lo - self.pad - o, o - self.hi - self.pad), 0.0)
        t0 = float(np.linalg.norm(gap)) - self.pad
        return t0 if t0 > self.NEAR_M else 0.0

    def cast_f32(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cast (n, 6) float32 rays (origin, unit direction); returns Open3D's
        ``t_hit`` (float32, inf on a miss), primitive ids (uint32) and barycentric
        ``(u, v)`` of the hits (float32, the weights of the triangle's second and third
        corners)."""
        o3c = self.o3d.core
        ans = self.rc.cast_rays(o3c.Tensor.from_numpy(rays), nthreads=self.nthreads)
        return ans["t_hit"].numpy(), ans["primitive_ids"].numpy(), ans["primitive_uvs"].numpy()

    #: Float32 units in the last place (2**-23, relative) of the largest coordinate a
    #: cast depends on that Open3D's hit may lie from the float64 hit, measured in the
    #: barycentric coordinates of the hit triangle times its smallest height and the
    #: cosine of incidence: at most 0.47 measured (aspen, coffee tree, a faceted
    #: height field; 15 m to 2 km; beams): 4 is the bound used (:meth:`ray_error_m`).
    F32_ULPS = 4.0
    #: A refined hit counts as on its triangle when it lies outside the triangle's edges
    #: (in its plane) by at most this many float64 ulps (2**-52, relative) of the largest
    #: coordinate involved: the float64 rounding of the hit (:meth:`edge_tol_m`).
    EDGE_ULPS = 8.0
    #: Unresolved hits (the float64 ray passes beside every triangle around the float32
    #: hit: a silhouette or a mesh border) are cast again from just behind it this many
    #: times at most; after that they are dropped (a float64 miss).
    RECASTS = 2

    def ray_error_m(self, o: np.ndarray, moved: bool, travelled: Any) -> Any:
        """Bound (m) of how far Open3D's float32 hit lies from the float64 hit of a ray
        from station ``o`` (local frame) that travelled ``travelled`` (m) from its float32
        origin (the station, or, ``moved``, a point on or in the scene's bounds), as seen
        from the hit triangle's edges once multiplied by the cosine of incidence:
        ``F32_ULPS`` float32 ulps of the origin's coordinates, of the distance travelled
        and of the scene's radius (the vertices' coordinates)."""
        start = self.radius + self.pad if moved else float(np.linalg.norm(o))
        return self.F32_ULPS * 2.0**-23 * (start + np.abs(travelled) + self.radius)

    def edge_tol_m(self, o: np.ndarray) -> float:
        """How far (m) a float64 hit may lie outside its triangle's edges and count as
        on it: ``EDGE_ULPS`` float64 ulps of the station's distance plus the scene's
        radius (``o`` + t ``d`` rounds by a few ulps of them). A ray through an edge can
        find both triangles' intersections just outside them when the hit's rounding
        along the ray (larger by 1 / cos of the incidence) moves them apart; then the
        least outside is taken if within this tolerance / cos (:meth:`_retest`)."""
        return self.EDGE_ULPS * 2.0**-52 * (float(np.linalg.norm(o)) + self.radius)

    def _fans(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Triangles around each vertex position (welded: equal coordinates are one
        vertex, so triangle soups such as STL files have neighbours too). Returns the
        welded corners (f, 3) and a CSR incidence: the triangles around welded vertex
        ``i`` are ``inc[ptr[i]:ptr[i + 1]]``. Built once, on first need."""
        if self._fan is None:
            key = np.ascontiguousarray(self.v + 0.0)  # + 0.0: -0.0 becomes 0.0
            _, weld = np.unique(key.view(np.dtype((np.void, 24))).ravel(), return_inverse=True)
            corners = weld.reshape(-1)[self.faces]
            self._fan = (corners, *vertex_triangles(corners, int(weld.max()) + 1))
        return self._fan

    def _outside_m(self, tri: np.ndarray, p: np.ndarray) -> np.ndarray:
        """How far (m) each point ``p`` (on triangle ``tri``'s plane) lies outside that
        triangle: the largest signed distance beyond its three edge lines (<= 0 inside)."""
        f = self.faces[tri]
        a, b, c = self.v[f[:, 0]], self.v[f[:, 1]], self.v[f[:, 2]]
        nrm = self.normal[tri]
        out = np.full(len(tri), -np.inf)
        for p0, p1 in ((a, b), (b, c), (c, a)):
            e = p1 - p0
            inside = np.einsum("ij,ij->i", np.cross(nrm, e), p - p0) / np.linalg.norm(e, axis=1)
            out = np.maximum(out, -inside)
        return out

    def _plane_t(self, o: np.ndarray, d: np.ndarray, tri: np.ndarray) -> np.ndarray:
        """Float64 distance along each ray (``o`` + t ``d``) to triangle ``tri``'s plane."""
        nrm = self.normal[tri]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.einsum("ij,ij->i", self.v0[tri] - o, nrm) / np.einsum("ij,ij->i", d, nrm)

    def _retest(
        self, o: np.ndarray, d: np.ndarray, tri: np.ndarray, tol: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """For rays whose float64 hit lies outside the triangle float32 picked: the
        nearest triangle around that one's corners (its edge and vertex neighbours, and
        itself) that the float64 ray meets within ``tol``, and the range to it; where
        none does, the one it passes nearest if within ``tol`` / cos of the incidence
        (the hit's rounding along the ray, seen in the plane); else inf / -1."""
        corners, ptr, inc = self._fans()
        k = len(tri)
        corner, cand = triangles_around(ptr, inc, corners[tri].ravel())
        owner = corner // 3
        dd = d[owner]
        t = self._plane_t(o, dd, cand)
        cos = np.abs(np.einsum("ij,ij->i", dd, self.normal[cand]))
        with np.errstate(invalid="ignore", divide="ignore"):
            p = o + t[:, None] * dd
            out = np.where(np.isfinite(t) & (t > 0), self._outside_m(cand, p), np.inf)
            loose = tol / np.maximum(cos, 1e-6)
            out = np.where(out <= tol, -np.inf, np.where(out <= loose, out, np.inf))
        # by owner: the nearest of those within tol, else the least outside within tol/cos
        key = np.where(out == -np.inf, t, np.inf)
        order = np.lexsort((out, key, owner))
        first = order[np.searchsorted(owner[order], np.arange(k))]
        found = out[first] < np.inf
        return np.where(found, t[first], np.inf), np.where(found, cand[first], -1)

    def refine(
        self,
        o: np.ndarray,
        d: np.ndarray,
        t_coarse: np.ndarray,
        pid: np.ndarray,
        uv: np.ndarray,
        t_from: float | np.ndarray,
        depth: int = 0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Float64 hits: (range, triangle) of each ray (``o`` + t ``d``, float64) that
        float32 found hitting triangle ``pid`` at about ``t_coarse`` (barycentric
        ``uv``), cast from its point at ``t_from`` (0: the station; more where the
        origin was moved forward).

        The range is the float64 intersection with the plane of the hit triangle. Near
        an edge float32 can have picked a neighbour of the triangle the float64 ray
        meets; that plane's intersection would then lie just outside the picked
        triangle (up to 0.14 mm at 2 km before this test). So where the float32 hit was
        within :meth:`ray_error_m` of an edge (or the ray grazes the plane), the float64
        hit is tested against the triangle's edges, and where it lies outside them by
        more than :meth:`edge_tol_m`, the triangles around the picked one's corners are
        tested in float64 and the nearest one the ray meets is taken. Where the float64
        ray meets none of them (it passes a silhouette or a border within float32's
        error), and where the hit lies at the ray's origin (a station standing on a
        surface: the ray leaves it), the ray is cast again from just behind the float32
        hit (``RECASTS`` times at most) and otherwise counted as a miss: every hit
        returned lies on a triangle within :meth:`edge_tol_m` (over the cosine of its
        incidence where a ray crosses an edge).

        Returns
        -------
        t : (n,) float64
            Ranges; inf where the ray turned out to miss.
        primitive : (n,) int64
            The triangle hit; -1 where it missed.
        """
        nrm = self.normal[pid]
        cos = np.einsum("ij,ij->i", d, nrm)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.einsum("ij,ij->i", self.v0[pid] - o, nrm) / cos
        np.abs(cos, out=cos)
        moved = bool(np.any(np.asarray(t_from) > 0))
        travelled = t_coarse - t_from
        # the float32 hit lies at least w * h_min from every edge (w: its smallest
        # barycentric coordinate); the float64 hit lies within ray_error_m / cos of it,
        # as seen from the edges. Tested in float32 (it only sorts out the sure ones).
        u, v = uv[:, 0], uv[:, 1]
        w = np.minimum(np.minimum(u, v), 1.0 - u - v)
        w *= self.h_min32[pid]
        w *= cos.astype(np.float32)
        far = float(travelled.max()) if len(travelled) else 0.0
        eps = float(self.ray_error_m(o, moved, far)) * 1.001 + 1e-30
        idx = np.flatnonzero(~(w > eps))  # NaN (a ray along the plane) included
        # a hit at the ray's own origin: the surface the station stands on
        at_origin = np.flatnonzero(travelled <= 8.0 * self.ray_error_m(o, moved, 0.0))
        if not len(idx) and not len(at_origin):
            return t, pid
        pid = pid.astype(np.int64, copy=True)
        tol = self.edge_tol_m(o)
        with np.errstate(invalid="ignore"):
            p = o + t[idx, None] * d[idx]
            bad = idx[~(self._outside_m(pid[idx], p) <= tol)]
        lost = at_origin
        if len(bad):
            t[bad], pid[bad] = self._retest(o, d[bad], pid[bad], tol)
            lost = np.union1d(bad[pid[bad] < 0], at_origin)
        if len(lost):
            t[lost], pid[lost] = np.inf, -1
            if depth < self.RECASTS:
                # start again just behind the float32 hit (past its float32 error)
                err = self.ray_error_m(o, moved, travelled[lost])
                start = t_coarse[lost] + 8.0 * err / np.maximum(cos[lost], 1e-2)
                rays = np.empty((len(lost), 6), dtype=np.float32)
                rays[:, :3] = o + start[:, None] * d[lost]
                rays[:, 3:] = d[lost]
                th, pr, uv2 = self.cast_f32(rays)
                h = np.flatnonzero(np.isfinite(th))
                if len(h):
                    sub = lost[h]
                    t[sub], pid[sub] = self.refine(
                        o,
                        d[sub],
                        start[h] + th[h].astype(np.float64),
                        pr[h].astype(np.int64),
                        uv2[h],
                        start[h],
                        depth + 1,
                    )
        return t, pid

    def cast(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cast rays from the point ``o`` (3,) along unit ``d`` (n, 3), float64 in and
        out: returns (t, primitive) with t = inf and primitive = -1 on a miss."""
        n = len(d)
        t0 = self.entry_distance(o)
        rays = np.empty((n, 6), dtype=np.float32)
        rays[:, :3] = o + t0 * d
        rays[:, 3:] = d
        th, pr, uv = self.cast_f32(rays)
        t_out = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        hidx = np.flatnonzero(np.isfinite(th))
        if len(hidx):
            t_coarse = t0 + th[hidx].astype(np.float64)
            t_out[hidx], prim[hidx] = self.refine(
                o, d[hidx], t_coarse, pr[hidx].astype(np.int64), uv[hidx], t0
            )
        return t_out, prim


def _sq_len(e: np.ndarray) -> np.ndarray:
    """Squared lengths (n,) of vectors ``e`` (n, 3)."""
    return np.square(e).sum(axis=1)


def _distorted(
    v: np.ndarray, v32: np.ndarray, f: np.ndarray, short2: np.ndarray
) -> tuple[int, float]:
    """How many triangles float32 (what Open3D holds) distorts, moving a vertex by more
    than :data:`DISTORTED_SHARE` of the triangle's shortest edge (``short2``: its squared
    length), and the largest move of a vertex of those triangles (m)."""
    moved = np.sqrt(_sq_len(v32.astype(np.float64) - v))
    worst = float(moved.max()) if len(f) else 0.0
    if worst == 0.0:
        return 0, 0.0
    maybe = np.flatnonzero(short2 < (worst / DISTORTED_SHARE) ** 2)  # the others cannot be
    move = moved[f[maybe]].max(axis=1)
    far = move**2 > DISTORTED_SHARE**2 * short2[maybe]
    return int(far.sum()), float(move[far].max()) if far.any() else 0.0


#: 26 unit directions: to the faces, edges and corners of a cube around a station.
_AROUND = np.array(
    [
        [x, y, z]
        for x in (-1, 0, 1)
        for y in (-1, 0, 1)
        for z in (-1, 0, 1)
        if (x, y, z) != (0, 0, 0)
    ],
    dtype=np.float64,
)
_AROUND /= np.linalg.norm(_AROUND, axis=1, keepdims=True)


def _where(k: int, st: Station) -> str:
    return f"station {k} at {tuple(round(c, 3) for c in st.position_m)}"


def _check_inside(caster: _Caster, o: np.ndarray, k: int, st: Station) -> None:
    g = _AROUND
    t, prim = caster.cast(o, g)
    hit = prim >= 0
    if hit.sum() < 0.9 * len(g):
        return
    back = np.einsum("ij,ij->i", g[hit], caster.normal[prim[hit]]) > 0
    if back.mean() >= 0.9:
        label = LABEL_NAMES[int(np.bincount(caster.label[prim[hit]]).argmax())]
        raise ScanError(
            f"{_where(k, st)} is inside the {label} geometry (nearest surface "
            f"{t[hit].min():.3f} m away in every direction); move it outside the mesh"
        )


def _station_warnings(caster: _Caster, o: np.ndarray, k: int, st: Station) -> list[str]:
    """What is wrong with a station that :func:`_check_inside` lets through: it stands
    on a surface (within a few float32 steps at its position, at least 1 µm), where
    rays leave from both sides of it; or it is enclosed by geometry whose surfaces face
    it (inverted normals), by the parity of crossings in 26 directions."""
    o3c = caster.o3d.core
    q = o3c.Tensor(o[None, :].astype(np.float32))
    near = caster.rc.compute_closest_points(q, nthreads=caster.nthreads)
    d = float(np.linalg.norm(near["points"].numpy()[0].astype(np.float64) - o))
    tol_m = max(4.0 * float(np.spacing(np.float32(np.abs(o).max()))), 1e-6)
    label = LABEL_NAMES[int(caster.label[int(near["primitive_ids"].numpy()[0])])]
    if d <= tol_m:
        return [
            f"{_where(k, st)} is on a {label} surface ({d * 1e3:.2g} mm from it, within "
            f"float32 precision {tol_m * 1e3:.2g} mm): rays that start on a surface see "
            "both of its sides and may record the inside of the mesh; move the station "
            "off the surface"
        ]
    rays = np.empty((len(_AROUND), 6), dtype=np.float32)
    rays[:, :3] = o
    rays[:, 3:] = _AROUND
    crossings = caster.rc.count_intersections(o3c.Tensor(rays), nthreads=caster.nthreads)
    odd = int((crossings.numpy() % 2 == 1).sum())
    if odd >= ENCLOSED_FRACTION * len(_AROUND):
        return [
            f"{_where(k, st)} looks enclosed by the {label} geometry: {odd} of "
            f"{len(_AROUND)} rays from it cross the mesh an odd number of times, though the "
            "surfaces around it face it (are the mesh's normals inverted?); the scan "
            "records the inside of the mesh"
        ]
    return []


def _precision_warnings(scene: Scene, caster: _Caster | None, radius_m: float) -> list[str]:
    """Triangles lost to precision: zero area in float64 as given (dropped by the
    scene), or in float32 around the local frame (kept, but rays miss them)."""
    out = []
    total = scene.n_triangles + scene.dropped_degenerate
    if scene.dropped_degenerate >= DEGENERATE_WARN_FRACTION * total:
        big = float(np.abs(scene.used_vertices).max())
        out.append(
            f"{scene.dropped_degenerate:,} of {total:,} triangles "
            f"({scene.dropped_degenerate / total:.1%}) have no area in float64 and were "
            f"dropped: coordinates reach {big:.3g} m, where float64 steps are "
            f"{float(np.spacing(big)):.2g} m; move the mesh near the origin before export"
        )
    if caster is not None and caster.distorted >= DEGENERATE_WARN_FRACTION * len(caster.faces):
        n = len(caster.faces)
        out.append(
            f"{caster.distorted:,} of {n:,} triangles ({caster.distorted / n:.1%}) are "
            f"distorted in float32, the precision rays are cast in (vertices move by up to "
            f"{caster.moved_m:.2g} m, more than {DISTORTED_SHARE:g} of those triangles' "
            f"shortest edge): the scene reaches {radius_m:.3g} m from its centre; rays may "
            "miss or hit the wrong triangles, so scan distant parts of the scene separately"
        )
    return out


def _float32_error_m(radius_m: float, o: np.ndarray) -> float:
    """Bound of the absolute error (m) of float32 vertices and ray origins for a scene
    within ``radius_m`` of the local frame's origin seen from ``o``: ~80 float32 ulps of
    the largest coordinate a ray meets (a ray starts at most ``|o| + radius_m`` out)."""
    return 2e-5 * (radius_m + float(np.linalg.norm(o))) + 1e-7


#: Triangles bounded at once when choosing those to load (bounds the temporaries).
_BOUNDS_CHUNK = 1 << 18


def _reachable_triangles(
    scene: Scene,
    frame: LocalFrame,
    stations: Sequence[Station],
    spec: ScannerSpec,
    lod: str,
    radius_m: float,
) -> tuple[np.ndarray | None, dict[str, Any]]:
    """The triangles to load (None: all) and what was left out, and why."""
    n = scene.n_triangles
    info: dict[str, Any] = {"triangles": n, "loaded": n, "beyond_range": 0, "outside_fov": 0}
    if lod != "auto" or n == 0:
        return None, info
    v = frame.to_local(scene.vertices)
    f = scene.faces
    keep = np.zeros(n, dtype=bool)
    near = np.zeros(n, dtype=bool)
    for st in stations:
        o = frame.to_local(st.position)
        rel = (v - o) @ st.rotation
        err = _float32_error_m(radius_m, o)
        # a chunk of triangles at a time: the bounds' temporaries are ~400 B a triangle
        for a in range(0, n, _BOUNDS_CHUNK):
            bounds = triangle_bounds(rel[f[a : a + _BOUNDS_CHUNK]])
            keep[a : a + _BOUNDS_CHUNK] |= reachable(bounds, spec, abs_error_m=err)
            near[a : a + _BOUNDS_CHUNK] |= bounds.d_min <= spec.max_range_m
            del bounds
        del rel
    info.update(
        loaded=int(keep.sum()),
        beyond_range=int((~near).sum()),
        outside_fov=int((near & ~keep).sum()),
    )
    return (None if keep.all() else keep), info


def _lod_summary(
    lod: str,
    spec: ScannerSpec,
    stats: list[StationStats],
    geometry: dict[str, Any],
    culled: bool,
    adaptive: bool,
) -> dict[str, Any]:
    """JSON-ready account of which models ran, where, and why."""
    window = sum(s.pulses_window for s in stats)
    cast = sum(s.pulses_cast for s in stats)
    out: dict[str, Any] = {"mode": lod}
    why = (
        f"cast only the cells of each station's window that some triangle can reach: "
        f"{cast:,} of {window:,} pulses"
        if culled
        else "cast the whole window rectangle"
    )
    if sum(s.points for s in stats) == 0:  # an empty scan: say why in plain words
        if geometry["loaded"] == 0:
            why = "nothing cast: no station can record any triangle (see geometry)"
        elif window == 0:
            why = "nothing cast: the scene is outside every station's field of view"
        elif cast == 0:
            why = (
                f"none of the {window:,} pulses of the stations' windows can reach a "
                f"triangle at {spec.horizontal_resolution_deg:g}°×"
                f"{spec.vertical_resolution_deg:g}° steps: the scene lies between the "
                "pulses; use a finer resolution"
            )
        else:
            why += (
                f"; none recorded an echo between {spec.min_range_m:g} and {spec.max_range_m:g} m"
            )
    out["rays"] = {"pulses_window": window, "pulses_cast": cast, "why": why}
    left = geometry["triangles"] - geometry["loaded"]
    out["geometry"] = {
        **geometry,
        "why": (
            f"{left:,} of {geometry['triangles']:,} triangles not loaded: "
            f"{geometry['beyond_range']:,} beyond {spec.max_range_m:g} m from every station, "
            f"{geometry['outside_fov']:,} outside every field of view"
            if left
            else "every triangle can be recorded by some station: all loaded"
        ),
    }
    if spec.beam_model:
        pulses = cast
        sub = sum(s.pulses_subrays for s in stats)
        reasons: dict[str, int] = {}
        for s in stats:
            for key, value in (s.subray_reasons or {}).items():
                reasons[key] = reasons.get(key, 0) + value
        step = math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
        ratio = spec.beam_divergence_mrad * 1e-3 / step
        out["beam"] = {
            "sampling": "adaptive" if adaptive else "full",
            "pulses_cast": pulses,
            "pulses_subrays": sub,
            "reasons": reasons,
            "footprint_over_spacing": ratio,
            "why": (
                f"{spec.subrays} sub-rays for {sub:,} of {pulses:,} pulses whose footprint "
                f"can straddle an edge, another surface or geometry thinner than the point "
                f"spacing (the footprint is {ratio:.2f}× the spacing at any range); the "
                "others keep their central ray"
                if adaptive
                else f"{spec.subrays} sub-rays for every pulse"
                + (" (lod full)" if lod == "full" else " (beam_sampling full)")
            ),
        }
    return out


def _grid_plan(
    caster: _Caster,
    grid: PulseGrid,
    o: np.ndarray,
    rot: np.ndarray,
    spec: ScannerSpec,
    culled: bool,
    adaptive: bool,
    radius_m: float,
) -> tuple[Any, np.ndarray | None]:
    """The pulses one station casts from its ``grid`` (the whole field of view or the
    scene's window): with ``culled``, the window's cells some triangle can reach. Returns
    them and, with ``adaptive`` beam sampling, the thin-geometry mask (else None)."""
    if grid.n_pulses == 0 or not (culled or adaptive):
        return grid, None
    rel = (caster.v - o) @ rot  # the vertices in the scanner frame
    abs_err = _float32_error_m(radius_m, o)
    cast = grid
    if culled:
        h0, hres = spec.horizontal_fov_deg[0], spec.horizontal_resolution_deg
        ang = np.sort((h0 + grid.columns * hres) % 360.0)
        gaps = np.diff(np.concatenate([ang, [ang[0] + 360.0]]))
        g = int(np.argmax(gaps))
        cast = occupancy_grid(
            rel, caster.faces, spec, grid, ang[g] + 0.5 * gaps[g], abs_error_m=abs_err
        )
    thin = None
    if adaptive:
        # the thin-geometry mask takes the triangles all at once (72 bytes each), made
        # after the occupancy grid, which gathers them a chunk at a time
        thin = thin_mask(
            rel[caster.faces],
            spec,
            cast,
            abs_error_m=abs_err,
            thickness_m=caster.thickness_m(),
            max_pulses=2 * cast.n_pulses,
        )
    return cast, thin


class _RayTables:
    """Per-station float32 cosines and sines of every column's azimuth and every line's
    elevation: a pulse's direction is gathered from them, so the rays of a pulse are the
    same bits whichever other pulses are cast with it. The tables hold the station's
    heading when it is level; otherwise its rotation turns the gathered directions."""

    def __init__(self, spec: ScannerSpec, station: Station) -> None:
        self.rot = station.rotation
        self.level = station.pitch_deg == 0 and station.roll_deg == 0
        heading = station.heading_deg if self.level else 0.0
        az = column_azimuth_rad(spec, np.arange(spec.n_azimuth), heading)
        el = line_elevation_rad(spec, np.arange(spec.n_elevation))
        self.cz64, self.sz64 = np.cos(az), np.sin(az)
        self.ce64, self.se64 = np.cos(el), np.sin(el)
        self.cz, self.sz = self.cz64.astype(np.float32), self.sz64.astype(np.float32)
        self.ce, self.se = self.ce64.astype(np.float32), self.se64.astype(np.float32)

    def directions(self, lines: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Float64 unit directions (n, 3) of grid pulses in the scene's frame: the values
        :func:`~treesim.scan.rays.directions` computes, gathered (and turned)."""
        ce = self.ce64[lines]
        d = np.stack([ce * self.cz64[cols], ce * self.sz64[cols], self.se64[lines]], axis=1)
        return d if self.level else d @ self.rot.T

    def directions32(self, lines: np.ndarray, cols: np.ndarray, out: np.ndarray) -> None:
        """The same directions built in float32, into ``out`` (n, 3)."""
        ce = self.ce[lines]
        np.multiply(self.cz[cols], ce, out=out[:, 0])
        np.multiply(self.sz[cols], ce, out=out[:, 1])
        out[:, 2] = self.se[lines]
        if not self.level:
            out[:] = out @ self.rot.T.astype(np.float32)


def _cast_central(
    caster: _Caster,
    tables: _RayTables,
    lines: np.ndarray,
    cols: np.ndarray,
    o: np.ndarray,
    t0: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cast and refine the grid rays of pulses (``lines``, ``cols``) from ``o``, without
    per-pulse randomness.

    Directions are built in float32 from the station's tables; only hits get float64
    directions and refined ranges (:meth:`_Caster.refine`). A ray moved ``t0`` forward
    starts at its float64 point there (rounded once): a float32 direction's rounding
    (~1e-7) times ``t0`` would move it sideways (0.1 mm at 1 km). Returns the hits'
    index into the pulses, their float64 ranges and triangles (inf / -1 where the
    refinement found a miss) and their float64 directions.
    """
    rays = np.empty((len(lines), 6), dtype=np.float32)
    tables.directions32(lines, cols, out=rays[:, 3:])
    d = None
    if t0 > 0:
        d = tables.directions(lines, cols)
        rays[:, :3] = o + t0 * d
    else:
        rays[:, :3] = o.astype(np.float32)
    th, pr, uv = caster.cast_f32(rays)
    hidx = np.flatnonzero(np.isfinite(th))
    d = tables.directions(lines[hidx], cols[hidx]) if d is None else d[hidx]
    t_coarse = t0 + th[hidx].astype(np.float64)
    t, prim = caster.refine(o, d, t_coarse, pr[hidx].astype(np.int64), uv[hidx], t0)
    return hidx, t, prim, d


@dataclass
class _StationPlan:
    """One station, planned: where it stands and the pulses it casts."""

    station: Station
    #: its position in the local frame
    o: np.ndarray
    #: the pulses to cast (the window, or its cells some triangle can reach)
    grid: Any
    #: the window's angles (:func:`~treesim.scan.rays.box_window`) and its pulses
    window: Any
    n_window: int
    #: adaptive beam sampling's thin-geometry keys (None: thin everywhere, or no mask)
    thin: np.ndarray | None
    #: how far forward its rays start (:meth:`_Caster.entry_distance`)
    t0: float


@dataclass
class _Plan:
    """A scan, planned: what :func:`scan` casts, station by station."""

    spec: ScannerSpec
    stations: list[Station]
    frame: LocalFrame
    caster: _Caster | None
    plans: list[_StationPlan]
    geometry: dict[str, Any]
    adaptive: bool
    plan_s: float
    #: what ran but may not be what was meant (stations on surfaces, lost precision)
    warnings: list[str]

    @property
    def pulses_cast(self) -> int:
        return sum(p.grid.n_pulses for p in self.plans)


def _plan_scan(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec | None,
    *,
    window: bool,
    cull: bool,
    lod: str,
    nthreads: int,
    max_rays: int | None,
    check_inside: bool,
    frame: LocalFrame | None = None,
    station_offset: int = 0,
) -> _Plan:
    """Each station's window and the pulses of it to cast, the triangles to load and the
    ray-casting scene: everything :func:`scan` and :func:`estimate_scan` do before they
    cast (``spec`` None: ``ScannerSpec()``). ``max_rays`` None: no limit (an estimate
    reports it instead). ``frame`` None: one around the scene's vertices;
    ``station_offset`` is added to the station indices in messages."""
    spec = spec or ScannerSpec()
    stations = list(stations)
    if not stations:
        raise InvalidParameterError("give at least one station")
    t_all = time.perf_counter()
    frame = frame or LocalFrame.around(scene.used_vertices)
    verts_used = frame.to_local(scene.used_vertices)
    s = spec.rays_per_pulse
    if lod not in LODS:
        raise InvalidParameterError(f"lod must be one of {', '.join(LODS)}, got {lod!r}")
    adaptive = s > 1 and spec.beam_sampling == "adaptive" and lod == "auto"
    origins = [frame.to_local(st.position) for st in stations]
    windows = [
        _grid_for(verts_used, o, st.rotation, spec, window)
        for o, st in zip(origins, stations, strict=True)
    ]
    # the limit is checked on the window with every sub-ray (an upper bound: culling
    # and adaptive sampling cast fewer), before any triangle is read
    upper = sum(grid.n_pulses for grid, _ in windows) * s
    if max_rays is not None and upper > max_rays:
        secs = upper / (_EST_RAYS_PER_S * max(1, nthreads or cpu_count()))
        raise ResourceLimitError(
            f"this scan needs {upper:.3g} rays at most ({len(stations)} station"
            f"{'s' if len(stations) > 1 else ''} at "
            f"{spec.horizontal_resolution_deg}°×{spec.vertical_resolution_deg}°"
            f"{f', {s} sub-rays per pulse' if s > 1 else ''}), about "
            f"{human_time(secs)} here, over the limit of {max_rays:.3g}; coarsen the "
            "resolution or raise max_rays (--max-rays); memory stays bounded either way"
        )
    radius = float(np.linalg.norm(verts_used, axis=1).max()) if len(verts_used) else 0.0
    keep, geometry = _reachable_triangles(scene, frame, stations, spec, lod, radius)
    caster = _Caster(scene, frame, nthreads, keep) if geometry["loaded"] else None
    plans = []
    for o, st, (window_grid, win) in zip(origins, stations, windows, strict=True):
        if caster is None:  # nothing any station can record: a valid empty scan
            grid, thin = PulseGrid(np.empty(0, np.int64), np.empty(0, np.int64)), None
        else:
            grid, thin = _grid_plan(
                caster, window_grid, o, st.rotation, spec, window and cull, adaptive, radius
            )
        t0 = caster.entry_distance(o) if caster is not None else 0.0
        plans.append(_StationPlan(st, o, grid, win, window_grid.n_pulses, thin, t0))
    warnings = _precision_warnings(scene, caster, radius)
    if caster is not None:
        for k, sp in enumerate(plans, start=station_offset):
            if check_inside:
                _check_inside(caster, sp.o, k, sp.station)
            warnings += _station_warnings(caster, sp.o, k, sp.station)
    plan_s = time.perf_counter() - t_all
    return _Plan(spec, stations, frame, caster, plans, geometry, adaptive, plan_s, warnings)


def _estimate(plan: _Plan, suffix: str, max_rays: int | None) -> ScanEstimate:
    """The scan's size and time from a sample of its planned pulses, cast and refined
    here (:mod:`treesim.scan.estimate`)."""
    spec, stations = plan.spec, plan.stations
    s = spec.rays_per_pulse
    total = plan.pulses_cast
    hits = sampled = 0
    secs = 0.0
    caster = plan.caster
    # at most 1/32 of the scan (cast twice: a few % of a small scan's time)
    budget = min(SAMPLE_PULSES, max(1024, total // 32))
    for sp in plan.plans:
        grid = sp.grid
        m = min(grid.n_pulses, round(budget * grid.n_pulses / max(total, 1)))
        if caster is None or m == 0:
            continue
        n_blocks = max(1, m // 256)
        size = m // n_blocks
        starts = np.arange(n_blocks) * (grid.n_pulses - size) // max(n_blocks - 1, 1)
        picked = [grid.indices(int(a), int(a) + size) for a in starts]
        lines = np.concatenate([p[0] for p in picked])
        cols = np.concatenate([p[1] for p in picked])
        tables = _RayTables(spec, sp.station)
        if not sampled:  # warm up (threads, the neighbour table): the scan pays it once
            _cast_central(caster, tables, lines, cols, sp.o, sp.t0)
        t_start = time.perf_counter()
        _, t, prim, _ = _cast_central(caster, tables, lines, cols, sp.o, sp.t0)
        secs += time.perf_counter() - t_start
        hits += int((_in_range(spec, t) & (prim >= 0)).sum())
        sampled += len(lines)
    rate = sampled / secs if secs > 0 else 0.0
    fraction = hits / sampled if sampled else 0.0
    points = int(round(fraction * total))
    rays = total * s
    seconds = plan.plan_s + (rays * OVERHEAD / rate if rate > 0 else 0.0)
    seconds += points * SECONDS_PER_POINT
    per_station = []
    for k, sp in enumerate(plan.plans):
        win = sp.window
        per_station.append(
            {
                "index": k,
                "position_m": list(sp.station.position_m),
                "azimuth_window_deg": list(win.azimuth_deg) if win.azimuth_deg else None,
                "elevation_window_deg": list(win.elevation_deg),
                "pulses_window": sp.n_window,
                "pulses_cast": sp.grid.n_pulses,
            }
        )
    notes = []
    if s > 1:
        notes.append(
            f"{s} sub-rays per pulse counted for every pulse"
            + (": adaptive sampling casts fewer" if plan.adaptive else "")
        )
    return ScanEstimate(
        stations=per_station,
        pulses_full_fov=spec.n_azimuth * spec.n_elevation * len(stations),
        pulses_window=sum(p.n_window for p in plan.plans),
        pulses_cast=total,
        rays=rays,
        rays_exact=not plan.adaptive,
        points=points,
        hit_fraction=fraction,
        sample_pulses=sampled,
        rate_rays_per_s=rate,
        plan_s=plan.plan_s,
        seconds=seconds,
        suffix=suffix,
        max_rays=max_rays,
        notes=notes,
    )


def estimate_scan(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec | None = None,
    *,
    window: bool = True,
    cull: bool = True,
    lod: str = "auto",
    nthreads: int = 0,
    max_rays: int | None = 1_000_000_000,
    suffix: str = ".laz",
) -> ScanEstimate:
    """What :func:`scan` with these settings would cast, record, write and take, without
    scanning: the scan is planned as it would run and a sample of its pulses is cast here
    (see :mod:`treesim.scan.estimate`). Nothing is written.

    Parameters
    ----------
    scene, stations, spec, window, cull, lod, nthreads
        As for :func:`scan`.
    max_rays : int, optional
        The limit :func:`scan` would apply; the estimate says whether it is exceeded
        (``over_limit``) instead of refusing.
    suffix : str
        The output's format, for the file size (``.laz``, ``.las``, ``.ply``, ``.xyz``).

    Returns
    -------
    ScanEstimate
    """
    plan = _plan_scan(
        scene,
        stations,
        spec,
        window=window,
        cull=cull,
        lod=lod,
        nthreads=nthreads,
        max_rays=None,
        check_inside=False,
    )
    return _estimate(plan, suffix.lower(), max_rays)


def scan(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec | None = None,
    *,
    window: bool = True,
    cull: bool = True,
    chunk_rays: int = 1 << 19,
    max_rays: int = 1_000_000_000,
    nthreads: int = 0,
    check_inside: bool = True,
    progress: Progress | None = None,
    sink: Sink | None = None,
    lod: str = "auto",
    estimate: Callable[[ScanEstimate], None] | None = None,
    frame: LocalFrame | None = None,
    station_offset: int = 0,
) -> ScanResult:
    """Scan a scene from one or more stations.

    Parameters
    ----------
    scene : Scene
        The labelled meshes (any coordinates; georeferenced is fine).
    stations : sequence of Station
        Scanner positions; the output's ``station`` field is the index into this list.
    spec : ScannerSpec
        Scanner settings (default ``ScannerSpec()``).
    window : bool
        Cast only the pulses whose direction can reach the scene's bounds (default), or
        the whole field of view (``False``; same points, many more rays).
    cull : bool
        Within the window, cast only the cells some triangle can reach
        (:mod:`treesim.scan.occupancy`; default). Conservative: the same points, bit for
        bit, as casting the whole window.
    chunk_rays : int
        Rays cast per batch; bounds peak memory to about ``chunk_rays × 200`` bytes.
    max_rays : int
        Refuse (``ResourceLimitError``, with an estimate) a scan that needs more rays.
    nthreads : int
        Open3D threads (0: all cores).
    check_inside : bool
        Refuse stations enclosed by the geometry.
    progress : callable(fraction, message), optional
        Called after each chunk.
    sink : callable(points, fields), optional
        Receives each chunk's points (float64, the scene's coordinates) and fields as
        they are made (e.g. a :func:`treesim.io.open_cloud_writer`'s ``write``); the
        result's cloud then holds no points, so memory does not grow with the output.
    lod : {"auto", "full"}
        Level of detail. ``"auto"`` (default) models only what the scene requires:
        triangles that no station can record (beyond ``max_range_m`` or outside every
        field of view) are never loaded into the ray-casting scene, and the beam model
        follows ``spec.beam_sampling``. ``"full"`` loads everything and gives every
        pulse its sub-rays. ``result.lod`` says what ran and why.
    estimate : callable(ScanEstimate), optional
        Called once, after planning and before casting, with the scan's estimated rays,
        points, file size (as LAZ) and time, from a sample cast on this machine
        (:mod:`treesim.scan.estimate`); :func:`estimate_scan` gives it alone.
    frame : LocalFrame, optional
        The float64 origin the scene is cast around (default: the centre of its
        vertices' bounds). Scans of parts of one scene that share a frame share their
        float32 geometry: a plot scanned station by station, with only the trees each
        station can record (:func:`treesim.plot.scan.scan_plot`), gives the points of
        the whole plot's scan.
    station_offset : int
        Index of ``stations[0]`` in a longer list (a plot scanned station by station):
        the ``station`` field, the station figures and the per-station random draws
        (range noise, jitter, beam) use ``station_offset + k``, so one station scanned
        alone gives what it gives among the others.

    Returns
    -------
    ScanResult
        ``result.cloud`` in the scene's coordinates (float64), with per-point fields.
    """
    if int(chunk_rays) < 1:
        raise InvalidParameterError(f"chunk_rays must be >= 1, got {chunk_rays}")
    # checked before planning (which names stations by it and builds the BVH)
    if isinstance(station_offset, bool) or int(station_offset) < 0:
        raise InvalidParameterError(f"station_offset must be >= 0, got {station_offset!r}")
    station_offset = int(station_offset)
    t_all = time.perf_counter()
    plan = _plan_scan(
        scene,
        stations,
        spec,
        window=window,
        cull=cull,
        lod=lod,
        nthreads=nthreads,
        max_rays=max_rays,
        check_inside=check_inside,
        frame=frame,
        station_offset=station_offset,
    )
    spec, stations, frame, caster = plan.spec, plan.stations, plan.frame, plan.caster
    geometry, adaptive = plan.geometry, plan.adaptive
    s = spec.rays_per_pulse
    if estimate is not None:
        estimate(_estimate(plan, ".laz", max_rays))
    offsets, weights = (
        beam_model.subray_pattern(s, spec.beam_divergence_mrad) if s > 1 else (None, None)
    )
    reflect = np.zeros(len(LABEL_CODES))
    for name, code in LABEL_CODES.items():
        reflect[code] = spec.reflectance.get(name, spec.reflectance.get("other", 0.5))
    fields_out = scan_fields(scene)
    with_trees = "tree_id" in fields_out
    out: dict[str, list[np.ndarray]] = {k: [] for k in fields_out}
    pts: list[np.ndarray] = []
    stats: list[StationStats] = []
    total_pulses = max(1, plan.pulses_cast)
    done_pulses = 0
    n_written = 0
    for k, sp in enumerate(plan.plans, start=station_offset):
        t_st = time.perf_counter()
        n_points = 0
        rays_cast = 0
        o, grid, t0 = sp.o, sp.grid, sp.t0
        tables = _RayTables(spec, sp.station)
        fast = s == 1 and spec.angular_jitter_sd_deg == 0
        # thin geometry nearly everywhere: every pulse needs its sub-rays anyway
        station_adaptive = adaptive and sp.thin is not None
        per_chunk = max(1, int(chunk_rays) // (1 if station_adaptive else s))
        if station_adaptive:
            chunks = _AdaptiveBeam(caster, spec, sp, tables, k)
            blocks = chunks.blocks(per_chunk, offsets, weights)
        else:
            blocks = (
                (a, min(grid.n_pulses, a + per_chunk)) for a in range(0, grid.n_pulses, per_chunk)
            )
        for block in blocks:
            if station_adaptive:
                rec, lines_r, cols_r, d_r, n_pulses, n_rays = block
            else:
                a, b = block
                lines, cols = grid.indices(a, b)
                n_pulses, n_rays = b - a, (b - a) * s
                if fast:
                    hidx, t, prim, d_r = _cast_central(caster, tables, lines, cols, o, t0)
                    lines_r, cols_r = lines[hidx], cols[hidx]
                    rec = _single_returns(spec, t, prim)
                else:
                    az, el = pulse_angles(spec, k, lines, cols)
                    d = directions(az, el) @ tables.rot.T
                    if s == 1:
                        t, prim = caster.cast(o, d)
                        rec = _single_returns(spec, t, prim)
                    else:
                        sd = beam_model.subray_directions(d, offsets).reshape(-1, 3)
                        t, prim = caster.cast(o, sd)
                        rec = _beam_returns(
                            spec, t.reshape(-1, s), prim.reshape(-1, s), sd, weights
                        )
                    lines_r, cols_r, d_r = lines, cols, d
            n_rec = len(rec["pulse"])
            if n_rec:
                pi = rec["pulse"]
                rng = rec["range_m"]
                if spec.range_noise_sd_m > 0:
                    # independent draws per pulse and per return
                    rng = rng + spec.range_noise_sd_m * hashed_normal(
                        spec.seed, 1, k, lines_r[pi], cols_r[pi], sub=rec["return_number"]
                    )
                rd = rec["direction"]
                ray_d = d_r[pi] if rd is None else np.where(np.isnan(rd[:, :1]), d_r[pi], rd)
                p_local = o + rng[:, None] * d_r[pi]
                prim = rec["primitive"]
                lab = caster.label[prim]
                cosi = np.abs(np.einsum("ij,ij->i", ray_d, caster.normal[prim]))
                inc = np.degrees(np.arccos(np.clip(cosi, 0.0, 1.0)))
                ref10 = np.minimum(1.0, (10.0 / np.maximum(rng, 1e-9)) ** 2)
                inten = np.clip(reflect[lab] * cosi * rec["energy"] * ref10, 0.0, 1.0)
                chunk_fields = {
                    "station": np.full(n_rec, k, dtype=np.uint16),
                    "range_m": rng.astype(np.float64),
                    "incidence_deg": inc.astype(np.float32),
                    "label": lab.astype(np.uint8),
                    "return_number": rec["return_number"].astype(np.uint8),
                    "number_of_returns": rec["number_of_returns"].astype(np.uint8),
                    "intensity": np.round(inten * 65535).astype(np.uint16),
                    "scan_line": lines_r[pi].astype(np.int32),
                    "scan_column": cols_r[pi].astype(np.int32),
                }
                if with_trees:
                    chunk_fields["tree_id"] = caster.tree[prim].astype(np.uint32)
                if sink is not None:
                    sink(frame.to_global(p_local), chunk_fields)
                    n_written += n_rec
                else:
                    pts.append(p_local)
                    for name, values in chunk_fields.items():
                        out[name].append(values)
                n_points += n_rec
            rays_cast += n_rays
            done_pulses += n_pulses
            if progress is not None:
                of = f"/{len(stations)}" if not station_offset else ""
                progress(done_pulses / total_pulses, f"station {k + 1}{of}")
        full = spec.n_azimuth * spec.n_elevation
        stats.append(
            StationStats(
                index=k,
                position_m=sp.station.position_m,
                pulses_full_fov=full,
                pulses_window=sp.n_window,
                pulses_cast=grid.n_pulses,
                rays_cast=rays_cast,
                points=n_points,
                azimuth_window_deg=sp.window.azimuth_deg,
                elevation_window_deg=sp.window.elevation_deg,
                time_s=time.perf_counter() - t_st,
                pulses_subrays=(
                    sum(chunks.reasons.values())
                    if station_adaptive
                    else (grid.n_pulses if s > 1 else 0)
                ),
                subray_reasons=(
                    dict(chunks.reasons)
                    if station_adaptive
                    else ({"thin geometry everywhere": grid.n_pulses} if adaptive else None)
                ),
            )
        )
    if pts:
        points = frame.to_global(np.concatenate(pts))
        fields = {k: np.concatenate(v) for k, v in out.items()}
    else:
        points = np.empty((0, 3))
        fields = {k: np.empty(0, dtype=v) for k, v in fields_out.items()}
    cloud = Cloud(points, fields, scan_metadata(stations))
    return ScanResult(
        cloud=cloud,
        spec=spec,
        stations=stations,
        station_stats=stats,
        frame=frame,
        bvh_build_s=caster.build_s if caster is not None else 0.0,
        total_s=time.perf_counter() - t_all,
        window=window,
        cull=window and cull,
        points_written=n_written,
        lod=_lod_summary(lod, spec, stats, geometry, window and cull, adaptive),
        models=spec.active_models(),
        warnings=plan.warnings,
    )


def scan_metadata(stations: Sequence[Station]) -> dict[str, Any]:
    """The metadata of a simulated cloud (what a writer records before the points)."""
    return {
        "label_names": dict(LABEL_NAMES),
        "source": "treesim scan",
        "stations": [st.to_dict() for st in stations],
    }


_FIELDS: dict[str, Any] = {
    "station": np.uint16,
    "range_m": np.float64,
    "incidence_deg": np.float32,
    "label": np.uint8,
    "return_number": np.uint8,
    "number_of_returns": np.uint8,
    "intensity": np.uint16,
    "scan_line": np.int32,
    "scan_column": np.int32,
}
#: The fields of a simulated cloud and their types (what a streaming writer declares);
#: a scene whose parts carry tree ids adds ``tree_id`` (see :func:`scan_fields`).
SCAN_FIELDS: dict[str, np.dtype] = {k: np.dtype(v) for k, v in _FIELDS.items()}


#: The field a scan of a plot adds (see :func:`scan_fields`).
TREE_ID_FIELD: dict[str, np.dtype] = {"tree_id": np.dtype(np.uint32)}


def scan_fields(scene: Scene) -> dict[str, np.dtype]:
    """The per-point fields a scan of ``scene`` makes: :data:`SCAN_FIELDS`, plus
    ``tree_id`` (uint32; 0 where the hit part belongs to no tree) when any part of the
    scene carries a tree id (a plot)."""
    if scene.face_tree is None:
        return dict(SCAN_FIELDS)
    return {**SCAN_FIELDS, **TREE_ID_FIELD}


#: A neighbour's hit farther than this from the plane of a pulse's hit triangle means a
#: different surface may lie inside the pulse's footprint (adaptive beam sampling).
ADAPTIVE_PLANE_TOL_M = 1e-3
#: Largest dense neighbour table (cells) adaptive sampling builds per block of columns.
_DENSE_NEIGHBOUR_CELLS = 1 << 23
#: Hits within this fraction of a range limit get sub-rays (the beam may straddle it).
_RANGE_LIMIT_FRACTION = 0.02


class _AdaptiveBeam:
    """Beam divergence at the price of one ray where one ray is enough.

    Every pulse's central ray is cast first. A pulse gets its sub-rays (the same
    sub-rays, cast the same way, as ``beam_sampling="full"``) only where its footprint
    can straddle an edge: a neighbour within ``k`` steps (``k`` from the beam's
    half-angle over the angular step) missed while it hit, or hit while it missed, or hit
    another part label, or hit a point farther than :data:`ADAPTIVE_PLANE_TOL_M` from the
    plane of this pulse's triangle (another surface in front or behind); or its range is
    near a range limit. Elsewhere every sub-ray would hit the same plane: the pulse keeps
    its central hit as one return of full energy, which differs from the full model's
    energy-weighted range by the beam's first moment on that plane (microns; the README
    states the measured agreement).

    Work goes column by column so that neighbours are known: each block of columns is
    cast with a halo of ``k`` columns on each side (cast again by the next block).
    """

    def __init__(
        self,
        caster: _Caster,
        spec: ScannerSpec,
        plan: _StationPlan,
        tables: _RayTables,
        station_index: int,
    ) -> None:
        self.caster, self.spec, self.tables = caster, spec, tables
        self.grid, self.thin, self.o, self.t0 = plan.grid, plan.thin, plan.o, plan.t0
        self.k_station = station_index
        half = 0.5 * spec.beam_divergence_mrad * 1e-3
        step = math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
        self.k = int(min(3, max(1, math.ceil(1.01 * half / step))))
        self.n_lines = spec.n_elevation
        self.n_az = spec.n_azimuth
        self.full_turn = spec.full_turn
        self.col_offsets = self.grid.offsets
        #: pulses given sub-rays, by the first reason that applied
        self.reasons = {"edge": 0, "surface": 0, "thin": 0, "range_limit": 0}

    def _pulses_of_columns(self, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lines, columns) the grid casts in the given columns (any, present or not)."""
        gc = self.grid.columns
        pos = np.searchsorted(gc, columns)
        ok = pos < len(gc)
        ok[ok] = gc[pos[ok]] == columns[ok]
        parts_l, parts_c = [], []
        for p in pos[ok]:
            ln, cl = self.grid.indices(int(self.col_offsets[p]), int(self.col_offsets[p + 1]))
            parts_l.append(ln)
            parts_c.append(cl)
        if not parts_l:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        return np.concatenate(parts_l), np.concatenate(parts_c)

    def _directions(self, lines: np.ndarray, cols: np.ndarray) -> np.ndarray:
        spec = self.spec
        if spec.angular_jitter_sd_deg > 0:
            az, el = pulse_angles(spec, self.k_station, lines, cols)
            return directions(az, el) @ self.tables.rot.T
        return self.tables.directions(lines, cols)

    def _central(self, lines: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Central ray of each pulse: (t, primitive), inf / -1 on a miss."""
        if self.spec.angular_jitter_sd_deg > 0:
            return self.caster.cast(self.o, self._directions(lines, cols))
        t = np.full(len(lines), np.inf)
        prim = np.full(len(lines), -1, dtype=np.int64)
        hidx, th, pr, _ = _cast_central(self.caster, self.tables, lines, cols, self.o, self.t0)
        t[hidx], prim[hidx] = th, pr
        return t, prim

    def _neighbour_finder(self, lines: np.ndarray, cols: np.ndarray, key: np.ndarray):
        """A function (columns, lines, ok) -> index of that pulse among ``lines``/``cols``
        or -1: a dense table over the block's columns and lines where it is small, a
        search in the sorted keys otherwise."""
        ucols = np.unique(cols)
        lmin = int(lines.min())
        height = int(lines.max()) - lmin + 1
        if len(ucols) * height <= _DENSE_NEIGHBOUR_CELLS:
            colpos = np.full(self.n_az, -1, dtype=np.int64)
            colpos[ucols] = np.arange(len(ucols))
            table = np.full((len(ucols), height), -1, dtype=np.int32)
            table[colpos[cols], lines - lmin] = np.arange(len(lines), dtype=np.int32)

            def dense(qc: np.ndarray, ql: np.ndarray, ok: np.ndarray) -> np.ndarray:
                pc = colpos[qc]
                row = ql - lmin
                ok = ok & (pc >= 0) & (row >= 0) & (row < height)
                out = table[np.where(ok, pc, 0), np.where(ok, row, 0)].astype(np.int64)
                return np.where(ok, out, -1)

            return dense
        order = np.argsort(key, kind="stable")
        skey = key[order]

        def search(qc: np.ndarray, ql: np.ndarray, ok: np.ndarray) -> np.ndarray:
            qkey = qc * self.n_lines + ql
            pos = np.minimum(np.searchsorted(skey, qkey), len(skey) - 1)
            return np.where(ok & (skey[pos] == qkey), order[pos], -1)

        return search

    def _flags(
        self,
        lines: np.ndarray,
        cols: np.ndarray,
        t: np.ndarray,
        prim: np.ndarray,
        n_core: int,
    ) -> np.ndarray:
        """Which of the first ``n_core`` pulses need sub-rays (see the class notes)."""
        spec, caster = self.spec, self.caster
        key = cols * self.n_lines + lines
        find = self._neighbour_finder(lines, cols, key)
        hit = np.isfinite(t)
        d_hit = np.zeros((len(t), 3))
        d_hit[hit] = self._directions(lines[hit], cols[hit])
        x = self.o + np.where(hit, t, 0.0)[:, None] * d_hit
        cl, cc = lines[:n_core], cols[:n_core]
        hit_p = hit[:n_core]
        pp = np.where(hit_p, prim[:n_core], 0)
        n_p = caster.normal[pp]
        v0_p = caster.v0[pp]
        lab_p = caster.label[pp]
        flag = np.zeros(n_core, dtype=bool)
        surface = np.zeros(n_core, dtype=bool)
        k = self.k
        for dc in range(-k, k + 1):
            qc = cc + dc
            if self.full_turn:
                qc = qc % self.n_az
                col_ok = np.ones(n_core, dtype=bool)
            else:
                col_ok = (qc >= 0) & (qc < self.n_az)
            for dl in range(-k, k + 1):
                if dc == 0 and dl == 0:
                    continue
                ql = cl + dl
                ok = col_ok & (ql >= 0) & (ql < self.n_lines)
                q = find(np.where(ok, qc, 0), ql, ok)
                found = q >= 0
                q = np.maximum(q, 0)
                q_hit = found & hit[q]
                # a hit beside a miss, or a miss beside a hit
                flag |= hit_p != q_hit
                both = hit_p & q_hit
                if both.any():
                    qb = q[both]
                    other = caster.label[prim[qb]] != lab_p[both]
                    dev = np.abs(np.einsum("ij,ij->i", x[qb] - v0_p[both], n_p[both]))
                    surface[both] |= other | (dev > ADAPTIVE_PLANE_TOL_M)
        tc = t[:n_core]
        near_limit = hit_p & (
            (np.abs(tc - spec.max_range_m) < _RANGE_LIMIT_FRACTION * spec.max_range_m)
            | (np.abs(tc - spec.min_range_m) < _RANGE_LIMIT_FRACTION * max(spec.min_range_m, 1.0))
        )
        thin = np.zeros(n_core, dtype=bool)
        if self.thin is None:  # no mask (the whole window, or too large): all are near
            thin[:] = True
        elif len(self.thin):
            ck = key[:n_core]
            pos = np.minimum(np.searchsorted(self.thin, ck), len(self.thin) - 1)
            thin = self.thin[pos] == ck
        st = self.reasons
        st["edge"] += int(flag.sum())
        st["surface"] += int((surface & ~flag).sum())
        st["thin"] += int((thin & ~flag & ~surface).sum())
        st["range_limit"] += int((near_limit & ~flag & ~surface & ~thin).sum())
        return flag | surface | thin | near_limit

    def _plane_range(
        self, d: np.ndarray, prim: np.ndarray, offsets: np.ndarray, weights: np.ndarray
    ) -> np.ndarray:
        """The full model's range of pulses (directions ``d``) whose every sub-ray meets
        the plane of triangle ``prim``: the weighted mean of the sub-rays' ranges to it
        (the sunflower pattern is not symmetric, so this differs from the central range
        by the pattern's first moment times the incidence's tangent)."""
        caster = self.caster
        n = caster.normal[prim]
        num = np.einsum("ij,ij->i", caster.v0[prim] - self.o, n)
        # n · (sub-ray direction), without building the sub-rays: they are
        # (d + tan(u) e1 + tan(v) e2) / sqrt(1 + tan²u + tan²v) on the beam's orthonormal
        # basis (:func:`~treesim.scan.beam.subray_directions`)
        e1, e2 = beam_model.beam_basis(d)
        tu, tv = np.tan(offsets[:, 0]), np.tan(offsets[:, 1])
        norm = np.sqrt(1.0 + tu * tu + tv * tv)
        nd = np.einsum("ij,ij->i", n, d)[:, None]
        n1 = np.einsum("ij,ij->i", n, e1)[:, None]
        n2 = np.einsum("ij,ij->i", n, e2)[:, None]
        den = (nd + tu[None, :] * n1 + tv[None, :] * n2) / norm[None, :]
        return (num[:, None] / den) @ weights / weights.sum()

    def blocks(self, per_chunk: int, offsets: np.ndarray, weights: np.ndarray):
        """Yield (records, lines, cols, directions, pulses, rays) per block of columns."""
        spec, grid, caster = self.spec, self.grid, self.caster
        s = spec.rays_per_pulse
        off = self.col_offsets
        n_cols = len(grid.columns)
        ca = 0
        while ca < n_cols:
            cb = int(np.searchsorted(off, off[ca] + per_chunk, side="right")) - 1
            cb = max(ca + 1, min(cb, n_cols))
            lines, cols = grid.indices(int(off[ca]), int(off[cb]))
            core_cols = grid.columns[ca:cb]
            near = (core_cols[:, None] + np.arange(-self.k, self.k + 1)[None, :]).reshape(-1)
            if self.full_turn:
                near = near % self.n_az
            halo = np.setdiff1d(near, core_cols)
            hl, hc = self._pulses_of_columns(halo)
            n_core = len(lines)
            all_l = np.concatenate([lines, hl])
            all_c = np.concatenate([cols, hc])
            t, prim = self._central(all_l, all_c)
            n_rays = len(all_l)
            flag = self._flags(all_l, all_c, t, prim, n_core)
            t, prim = t[:n_core], prim[:n_core]
            # pulses whose footprint lies on one plane: one return of full energy, at
            # the range the full model gives there (its sub-rays' weighted mean range)
            single = np.flatnonzero(~flag & _in_range(spec, t) & (prim >= 0))
            cand = np.flatnonzero(flag)
            step = max(1, per_chunk // s)
            r_single = np.empty(len(single))
            for a in range(0, len(single), step):
                sp = single[a : a + step]
                r_single[a : a + step] = self._plane_range(
                    self._directions(lines[sp], cols[sp]), prim[sp], offsets, weights
                )
            parts = [
                {
                    "pulse": single,
                    "range_m": r_single,
                    "primitive": prim[single],
                    "direction": None,
                    "energy": np.ones(len(single)),
                    "return_number": np.ones(len(single), np.int64),
                    "number_of_returns": np.ones(len(single), np.int64),
                }
            ]
            for a in range(0, len(cand), step):
                cp = cand[a : a + step]
                d = self._directions(lines[cp], cols[cp])
                sd = beam_model.subray_directions(d, offsets).reshape(-1, 3)
                ts, ps = caster.cast(self.o, sd)
                n_rays += len(sd)
                rec = _beam_returns(spec, ts.reshape(-1, s), ps.reshape(-1, s), sd, weights)
                rec["pulse"] = cp[rec["pulse"]]
                parts.append(rec)
            rec = _merge_records(parts)
            # pulses with returns, renumbered (records are ordered by pulse)
            fresh = np.ones(len(rec["pulse"]), dtype=bool)
            fresh[1:] = rec["pulse"][1:] != rec["pulse"][:-1]
            used = rec["pulse"][fresh]
            rec["pulse"] = np.cumsum(fresh) - 1
            d_used = self._directions(lines[used], cols[used])
            yield rec, lines[used], cols[used], d_used, n_core, n_rays
            ca = cb


def _merge_records(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Concatenate return records and order them by pulse, then return number."""
    out: dict[str, Any] = {}
    n = sum(len(p["pulse"]) for p in parts)
    for name in ("pulse", "range_m", "primitive", "energy", "return_number", "number_of_returns"):
        out[name] = np.concatenate([p[name] for p in parts]) if n else np.empty(0)
    dirs = [p["direction"] for p in parts]
    if any(d is not None for d in dirs):
        out["direction"] = np.concatenate(
            [
                d if d is not None else np.full((len(p["pulse"]), 3), np.nan)
                for p, d in zip(parts, dirs, strict=True)
            ]
        )
    else:
        out["direction"] = None
    order = np.lexsort((out["return_number"], out["pulse"]))
    for name, v in out.items():
        if v is not None:
            out[name] = v[order]
    out["pulse"] = out["pulse"].astype(np.int64)
    out["primitive"] = out["primitive"].astype(np.int64)
    return out


def _in_range(spec: ScannerSpec, t: np.ndarray) -> np.ndarray:
    return np.isfinite(t) & (t >= spec.min_range_m) & (t <= spec.max_range_m)


def _single_returns(spec: ScannerSpec, t: np.ndarray, prim: np.ndarray) -> dict[str, Any]:
    keep = _in_range(spec, t) & (prim >= 0)
    idx = np.flatnonzero(keep)
    one = np.ones(len(idx), dtype=np.int64)
    return {
        "pulse": idx,
        "range_m": t[idx],
        "primitive": prim[idx],
        "direction": None,  # the pulse direction
        "energy": np.ones(len(idx)),
        "return_number": one,
        "number_of_returns": one,
    }


def _beam_returns(
    spec: ScannerSpec, t: np.ndarray, prim: np.ndarray, sd: np.ndarray, weights: np.ndarray
) -> dict[str, Any]:
    p, s = t.shape
    t = np.where(_in_range(spec, t) & (prim >= 0), t, np.inf)
    g = beam_model.group_returns(t, weights, spec.range_resolution_m)
    keep = beam_model.select_returns(g, spec.return_mode)
    pulse = g["pulse"][keep]
    sub = g["subray"][keep]
    flat = pulse * s + sub
    return {
        "pulse": pulse,
        "range_m": g["range_m"][keep],
        "primitive": prim.reshape(-1)[flat],
        "direction": sd[flat],
        "energy": g["energy"][keep],
        "return_number": g["return_number"][keep],
        "number_of_returns": g["number_of_returns"][keep],
    }


__all__ = [
    "BYTES_PER_RAY",
    "SCAN_FIELDS",
    "scan_fields",
    "ScanResult",
    "StationStats",
    "estimate_scan",
    "scan",
    "scan_metadata",
]
