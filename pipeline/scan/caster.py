"""The caster: rays over Open3D's float32 ``RaycastingScene``, hits in float64.

Precision: the scene is shifted into a :class:`~treesim.frame.LocalFrame` (float64)
before Open3D (float32) sees it; each ray starts just before the scene's bounding box
(moved forward in float64, from the float64 direction), so float32 never holds a long
range; every hit is then recomputed in float64 as the intersection of the ray with the
hit triangle's plane. Where float32 can have picked the neighbour of the triangle the
float64 ray meets (within its error of an edge), the float64 hit is checked against the
triangle's edges and, outside them, the triangles around it are tested in float64
(:meth:`Caster.refine`): every point lies on a triangle of the mesh to float64 rounding
(measured ≤ 1e-12 m at 2 km; the manual, docs/concepts.md, promises 1e-9 m). Whether a
ray that passes within float32's error of an edge (about 1e-6 of the scene's size, plus
of the station's distance when it is within 50 m) meets the surface there remains
float32's choice.
Points leave in the input's coordinates as float64. A pulse's float32 ray is gathered
from per-station tables (:class:`RayTables`), so it is the same bits whichever pulses are
cast beside it (:func:`cast_central`).

Used by :func:`treesim.scan.scan` (:mod:`treesim.scan.trace`) and its planning; nothing
here is part of the package's public names.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..frame import LocalFrame
from ..geometry import triangles_around, vertex_triangles
from ..params import ScannerSpec
from ..scene import Scene
from .rays import column_azimuth_rad, line_elevation_rad
from .stations import Station

#: Triangles bounded at once (the caster's per-triangle data, the triangles to load):
#: bounds the temporaries.
BOUNDS_CHUNK = 1 << 18
#: A triangle is distorted in float32 when rounding its vertices to float32 moves one by
#: more than this share of its shortest edge.
DISTORTED_SHARE = 0.1
#: A caster whose normals and smallest heights (28 B a triangle) fit in this many bytes
#: holds them (each hit reads them: a scan is faster); larger scenes gather them from the
#: corners when read (the same figures: memory per triangle, issue 25).
HELD_GEOMETRY_BYTES = 16 << 20
#: Vertices or triangles the edge fans (:meth:`Caster._fans`) are built from at once
#: (:func:`~treesim.geometry.vertex_triangles`' ``chunk``):
#: their temporaries (~100 B each) stay a few MiB whatever the scene (issue 25).
FAN_CHUNK = 1 << 15
#: A scene whose arrays (vertices, faces, labels, tree ids: ~30 B a triangle) take at
#: least this many bytes is spilled to a temporary file while Open3D builds its BVH
#: (:meth:`~treesim.scene.Scene.spilled`): the build's peak, a station's highest, is then
#: Open3D's alone (issue 25); smaller scenes skip the file.
SPILL_BYTES = 16 << 20


def triangle_chunks(n: int, size: int | None = None) -> Iterator[tuple[int, int]]:
    """``(start, stop)`` of consecutive chunks of ``n`` rows (triangles, or vertices),
    ``size`` at most each (default :data:`BOUNDS_CHUNK`, read when called, so a test can
    shrink it for every user at once)."""
    step = BOUNDS_CHUNK if size is None else size
    for a in range(0, n, step):
        yield a, min(n, a + step)


def float32_error_m(radius_m: float, o: np.ndarray) -> float:
    """Bound of the absolute error (m) of float32 vertices and ray origins for a scene
    within ``radius_m`` of the local frame's origin seen from ``o``: ~80 float32 ulps of
    the largest coordinate a ray meets (a ray starts at most ``|o| + radius_m`` out)."""
    return 2e-5 * (radius_m + float(np.linalg.norm(o))) + 1e-7


class Caster:
    """The Open3D scene plus the scene's float64 triangles for refinement.

    Memory (issue 25): the caster holds no per-triangle or per-vertex array of its own
    beyond Open3D's: it reads the scene's float64 vertices, faces, labels and tree ids
    (through an int32 index when only some triangles are loaded), and gathers what a
    hit needs (the local corners, the normal, the smallest height) when it needs it,
    with the figures a held array computed row by row would give. A scene whose normals
    and heights fit in :data:`HELD_GEOMETRY_BYTES` holds those two (faster hits). While
    Open3D builds its BVH (a station's highest peak with its casts), a scene of
    :data:`SPILL_BYTES` or more waits in a temporary file, the caster and the scene
    holding only its maps; the edge fans are built a chunk at a time and share the
    scene's faces where no two vertices are welded.
    """

    def __init__(
        self, scene: Scene, frame: LocalFrame, nthreads: int, keep: np.ndarray | None = None
    ) -> None:
        from ._open3d import load_open3d

        o3d = load_open3d()
        self.o3d = o3d
        self.nthreads = int(nthreads)
        self._origin = frame.origin_array
        index = None if keep is None else _small_index(np.flatnonzero(keep))
        self._bind(scene, index)
        self._thickness: np.ndarray | None = None
        # each triangle's first corner, normal and smallest height, gathered when read
        # (the normals and heights held instead when they are small)
        self.v0 = _Gathered(self, 0)
        self.normal: Any = _Gathered(self, 1)
        self.h_min32: Any = _Gathered(self, 2)
        if 28 * len(self.faces) <= HELD_GEOMETRY_BYTES:
            self.normal, self.h_min32 = self._held_geometry()
        self.lo, self.hi = frame.to_local(scene.bounds)
        self.pad = 1e-3 + 1e-5 * float(np.linalg.norm(self.hi - self.lo))
        self.radius = float(np.linalg.norm(np.maximum(np.abs(self.lo), np.abs(self.hi))))
        self._fan: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        v32, worst = self._float32_vertices()
        self.distorted, self.moved_m = self._distorted(v32, worst)
        self.rc = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        # Open3D copies both into its own buffers (from tensors sharing our arrays: no
        # third copy); ours go before its BVH is built
        f = np.asarray(self.faces)
        f32 = f.view(np.uint32) if f.dtype == np.int32 else f.astype(np.uint32)
        self.rc.add_triangles(_o3d_view(o3d, v32), _o3d_view(o3d, f32))
        del v32, f, f32
        self._build(scene, index)

    def _bind(self, scene: Any, index: np.ndarray | None) -> None:
        """Read the scene's vertices (global, moved into the local frame when gathered),
        faces, labels and tree ids (rows ``index`` of them when given)."""
        self._sv = np.asarray(scene.vertices, dtype=np.float64)
        self.faces: Any = _rows(scene.faces, index)
        self.label: Any = _rows(scene.face_label, index)
        ft = scene.face_tree
        self.tree: Any = None if ft is None else _rows(ft, index)

    def _build(self, scene: Any, index: np.ndarray | None) -> None:
        """Build Open3D's BVH (lazily built on the first query: built now, timed apart
        in ``build_s``); a scene of :data:`SPILL_BYTES` or more meanwhile spilled to a
        temporary file, the caster holding only its maps (``spill_s``: the time of the
        writing and reading back)."""
        t_all = time.perf_counter()
        spill = isinstance(scene, Scene) and scene.array_bytes >= SPILL_BYTES
        if spill:
            # the caster lets go of the scene's arrays (the file's maps come instead)
            self._sv = self.faces = self.label = self.tree = None
            with scene.spilled():
                self._bind(scene, index)
                t0 = time.perf_counter()
                self.cast(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
                self.build_s = time.perf_counter() - t0
                self._sv = self.faces = self.label = self.tree = None
            self._bind(scene, index)  # the arrays read back
        else:
            self.cast(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
            self.build_s = time.perf_counter() - t_all
        self.spill_s = time.perf_counter() - t_all - self.build_s

    @property
    def v(self) -> np.ndarray:
        """(v, 3) float64 vertices in the local frame (a new array each time: the caster
        keeps only the scene's)."""
        return self._sv - self._origin

    def corners(self, idx: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The local float64 corners (three (n, 3) arrays) of triangles ``idx``."""
        f = self.faces[idx]
        if f.ndim == 2:  # an index array or a slice
            # np.take gathers rows about twice as fast as indexing (the same values)
            out = []
            for k in range(3):
                c = np.take(self._sv, f[:, k], axis=0)
                c -= self._origin
                out.append(c)
            return out[0], out[1], out[2]
        o = self._origin
        return self._sv[f[..., 0]] - o, self._sv[f[..., 1]] - o, self._sv[f[..., 2]] - o

    def first_corners(self, idx: Any) -> np.ndarray:
        """The local float64 first corner (n, 3) of triangles ``idx`` (:meth:`corners`'
        first, without gathering the other two)."""
        f = self.faces[idx]
        if f.ndim == 2:
            c = np.take(self._sv, f[:, 0], axis=0)
            c -= self._origin
            return c
        return self._sv[f[..., 0]] - self._origin

    def geometry(self, idx: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First corner (n, 3), unit normal (n, 3) and smallest height (n,), float32 (twice
        the area over the longest edge: how far the interior reaches from an edge), of
        triangles ``idx``."""
        p0, v1, v2 = self.corners(idx)
        e1, e2 = v1 - p0, v2 - p0
        n = _cross(e1, e2)
        twice_area = np.sqrt(_sq_len(n))
        longest = np.maximum(np.maximum(_sq_len(e1), _sq_len(v2 - v1)), _sq_len(e2))
        h32 = (twice_area / np.sqrt(longest)).astype(np.float32)
        n /= twice_area[..., None]
        return p0, n, h32

    def normals(self, idx: Any) -> np.ndarray:
        """Unit normals (n, 3) float64 of triangles ``idx`` (:meth:`geometry`'s)."""
        p0, v1, v2 = self.corners(idx)
        v1 -= p0
        v2 -= p0
        n = _cross(v1, v2)
        n /= np.sqrt(_sq_len(n))[..., None]
        return n

    def _held_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """Every triangle's normal and smallest height (:meth:`geometry`'s), a chunk of
        triangles at a time."""
        normal = np.empty((len(self.faces), 3))
        h_min32 = np.empty(len(self.faces), dtype=np.float32)
        for a, b in triangle_chunks(len(self.faces)):
            _, normal[a:b], h_min32[a:b] = self.geometry(slice(a, b))
        return normal, h_min32

    def _float32_vertices(self) -> tuple[np.ndarray, float]:
        """The local vertices in float32 (what Open3D holds), a chunk at a time, and the
        largest move of a vertex by that rounding (m; 0 without triangles)."""
        v32 = np.empty(self._sv.shape, dtype=np.float32)
        worst = 0.0
        for a, b in triangle_chunks(len(self._sv)):
            local = self._sv[a:b] - self._origin
            v32[a:b] = local
            moved = np.sqrt(_sq_len(v32[a:b].astype(np.float64) - local))
            worst = max(worst, float(moved.max()))
        return v32, (worst if len(self.faces) else 0.0)

    def _distorted(self, v32: np.ndarray, worst: float) -> tuple[int, float]:
        """How many triangles float32 (what Open3D holds) distorts, moving a vertex by
        more than :data:`DISTORTED_SHARE` of the triangle's shortest edge, and the
        largest move of a vertex of those triangles (m); ``worst``: the largest move of
        any vertex. A chunk of triangles at a time."""
        if worst == 0.0:
            return 0, 0.0
        count, most = 0, 0.0
        for a, b in triangle_chunks(len(self.faces)):
            p0, v1, v2 = self.corners(slice(a, b))
            short2 = np.stack([_sq_len(v1 - p0), _sq_len(v2 - v1), _sq_len(v2 - p0)]).min(axis=0)
            del p0, v1, v2
            maybe = np.flatnonzero(short2 < (worst / DISTORTED_SHARE) ** 2)  # others cannot be
            f = self.faces[a:b][maybe].reshape(-1)
            moved = np.sqrt(_sq_len(v32[f].astype(np.float64) - (self._sv[f] - self._origin)))
            move = moved.reshape(-1, 3).max(axis=1)
            far = move**2 > DISTORTED_SHARE**2 * short2[maybe]
            count += int(far.sum())
            most = max(most, float(move[far].max()) if far.any() else 0.0)
        return count, most

    def thickness_m(self) -> np.ndarray:
        """Local thickness of the geometry behind each triangle (m): the distance from
        its centroid, inwards along its normal, to the next surface (a branch's
        diameter on a tube); inf where nothing is behind it (a leaf, an open sheet)."""
        if self._thickness is None:
            p0, v1, v2 = self.corners(slice(None))
            centroid = (p0 + v1 + v2) / 3.0
            del p0, v1, v2
            normal = self.normal[:]
            inset = 1e-5 + 1e-7 * np.linalg.norm(centroid, axis=1)
            rays = np.empty((len(centroid), 6), dtype=np.float32)
            rays[:, :3] = centroid - (inset[:, None] * normal)
            rays[:, 3:] = -normal
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
        ``i`` are ``inc[ptr[i]:ptr[i + 1]]``. Built once, on first need.

        Which number a welded vertex gets is immaterial (only which triangles share one,
        each vertex's listed in increasing order): where no two vertices share their
        coordinates, the corners are the faces themselves (:func:`_weld`)."""
        if self._fan is None:
            weld, n_welded = _weld(self._sv, self._origin)
            # held while the caster lives: int32 indices where they fit (the same values)
            small = max(n_welded, 3 * len(self.faces)) < 2**31 - 1
            index = np.int32 if small else np.int64
            corners: Any = self.faces  # every vertex its own: the faces (no copy)
            if weld is not None:
                corners = weld.astype(index)[np.asarray(self.faces)]
            del weld
            ptr, inc = vertex_triangles(corners, n_welded, index, chunk=FAN_CHUNK)
            self._fan = (corners, ptr, inc)
        return self._fan

    def _outside_m(self, tri: np.ndarray, p: np.ndarray) -> np.ndarray:
        """How far (m) each point ``p`` (on triangle ``tri``'s plane) lies outside that
        triangle: the largest signed distance beyond its three edge lines (<= 0 inside)."""
        a, b, c = self.corners(tri)
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
        if isinstance(self.normal, np.ndarray):  # held
            p0, nrm, h_min32 = self.v0[pid], self.normal[pid], self.h_min32[pid]
        else:
            p0, nrm, h_min32 = self.geometry(pid)
        cos = np.einsum("ij,ij->i", d, nrm)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.einsum("ij,ij->i", p0 - o, nrm) / cos
        del p0, nrm
        np.abs(cos, out=cos)
        moved = bool(np.any(np.asarray(t_from) > 0))
        travelled = t_coarse - t_from
        # the float32 hit lies at least w * h_min from every edge (w: its smallest
        # barycentric coordinate); the float64 hit lies within ray_error_m / cos of it,
        # as seen from the edges. Tested in float32 (it only sorts out the sure ones).
        u, v = uv[:, 0], uv[:, 1]
        w = np.minimum(np.minimum(u, v), 1.0 - u - v)
        w *= h_min32
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


def _row_hash(words: np.ndarray) -> np.ndarray:
    """A 64-bit hash (n,) uint64 of rows of three 64-bit words (n, 3) uint64 (multiply
    and xor-shift rounds: equal rows hash equal; :func:`_weld` checks the rest)."""
    h = words[:, 0] * np.uint64(0x9E3779B97F4A7C15)
    for k, mult in ((1, 0xBF58476D1CE4E5B9), (2, 0x94D049BB133111EB)):
        h ^= h >> np.uint64(31)
        h ^= words[:, k]
        h *= np.uint64(mult)
    h ^= h >> np.uint64(29)
    return h


def _local_hashes(sv: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """:func:`_row_hash` of the local vertices ``sv - origin`` (-0.0 made 0.0), made a
    chunk of :data:`FAN_CHUNK` rows at a time (no copy of every vertex)."""
    h = np.empty(len(sv), dtype=np.uint64)
    for a, b in triangle_chunks(len(sv), FAN_CHUNK):
        local = sv[a:b] - origin
        local += 0.0  # -0.0 becomes 0.0
        h[a:b] = _row_hash(local.view(np.uint64))
    return h


def _weld(sv: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray | None, int]:
    """A labelling of the local vertices ``sv - origin`` (n, 3) float64, equal where
    their coordinates are (-0.0 and 0.0 equal): ``(weld, n_welded)``, ``weld`` (n,) in
    ``range(n_welded)``, or ``(None, n)`` where every row differs (each its own label,
    its index; most meshes). Rows are told apart by a 64-bit hash of their bits
    (:func:`_local_hashes`, sorted in place: 16 B a vertex, no copy of the vertices, where
    every hash differs); where two hashes are equal, the rows are copied, those of equal
    hash compared, and where two differ (a collision) the labels are np.unique's of the
    rows' bytes. About 15 times faster than np.unique on 24-byte keys (issue 25)."""
    h = _local_hashes(sv, origin)
    h.sort()
    if not (h[1:] == h[:-1]).any():  # distinct hashes: distinct rows
        return None, len(sv)
    del h
    v = sv - origin
    v += 0.0  # -0.0 becomes 0.0
    words = v.view(np.uint64)
    h = _row_hash(words)
    order = np.argsort(h)
    h = h[order]
    first = np.empty(len(h), dtype=bool)
    first[:1] = True
    np.not_equal(h[1:], h[:-1], out=first[1:])
    del h
    # every row equal to the one before it in its run of equal hashes: no collision
    same = np.flatnonzero(~first[1:])
    before = np.take(words, order[same], axis=0)
    equal = np.array_equal(before, np.take(words, order[same + 1], axis=0))
    del same, before
    if not equal:
        _, weld = np.unique(words.view(np.dtype((np.void, 24))).ravel(), return_inverse=True)
        weld = weld.reshape(-1)
        return weld, int(weld.max()) + 1
    label = np.cumsum(first) - 1
    weld = np.empty(len(v), dtype=np.int64)
    weld[order] = label
    return weld, int(label[-1]) + 1


class _Gathered:
    """Per-triangle figures of a caster gathered when indexed (the values a held array
    computed row by row would give, without holding it): ``what`` 0, each triangle's
    first corner; 1, its unit normal; 2, its smallest height (float32)."""

    def __init__(self, caster: Caster, what: int) -> None:
        self.caster, self.what = caster, what

    def __getitem__(self, idx: Any) -> np.ndarray:
        if self.what == 0:
            return self.caster.first_corners(idx)
        if self.what == 1:
            return self.caster.normals(idx)
        return self.caster.geometry(idx)[2]

    def __len__(self) -> int:
        return len(self.caster.faces)


class _Subset:
    """Rows ``index`` of an array, gathered when indexed: a caster's faces, labels and
    tree ids when only some triangles are loaded (an int32 index, not copies)."""

    def __init__(self, a: np.ndarray, index: np.ndarray) -> None:
        self.a, self.index = a, index

    def __getitem__(self, idx: Any) -> np.ndarray:
        return self.a[self.index[idx]]

    def __len__(self) -> int:
        return len(self.index)

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        rows = self.a[self.index]
        return rows if dtype is None else rows.astype(dtype, copy=False)


def _rows(a: np.ndarray, index: np.ndarray | None) -> Any:
    """``a`` itself (index None), or its rows ``index`` gathered when read."""
    return a if index is None else _Subset(a, index)


def _small_index(index: np.ndarray) -> np.ndarray:
    """Indices as int32 where they fit (the same values, half the bytes)."""
    return index.astype(np.int32) if len(index) and index[-1] < 2**31 - 1 else index


def _o3d_view(o3d: Any, a: np.ndarray) -> Any:
    """An Open3D tensor sharing ``a``'s memory (``add_triangles`` copies it)."""
    return o3d.core.Tensor.from_numpy(np.ascontiguousarray(a))


def _sq_len(e: np.ndarray) -> np.ndarray:
    """Squared lengths (n,) of vectors ``e`` (n, 3): the sum of the squares in order, the
    figure ``np.square(e).sum(axis=1)`` and ``np.linalg.norm(e, axis=1) ** 2`` give."""
    sq = np.square(e)
    return sq[..., 0] + sq[..., 1] + sq[..., 2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of (n, 3) vectors, the same operations (each product rounded,
    then the difference), without its generic set-up."""
    n = np.empty(np.broadcast_shapes(a.shape, b.shape))
    n[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    n[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    n[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return n


class RayTables:
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


def cast_central(
    caster: Caster,
    tables: RayTables,
    lines: np.ndarray,
    cols: np.ndarray,
    o: np.ndarray,
    t0: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cast and refine the grid rays of pulses (``lines``, ``cols``) from ``o``, without
    per-pulse randomness.

    Directions are built in float32 from the station's tables; only hits get float64
    directions and refined ranges (:meth:`Caster.refine`). A ray moved ``t0`` forward
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
