"""Point-to-triangle geometry, exact in float64.

* :func:`closest_points_on_triangles`: Ericson's region test (Real-Time Collision
  Detection, 5.1.5), vectorised over point-triangle pairs;
* :func:`well_conditioned`: triangles re-ordered so that Open3D's float32 closest-point
  routine does not cancel on slivers;
* :func:`point_to_mesh_distances`: distances from points to a mesh, the closest triangle
  picked by Open3D's ``RaycastingScene`` (float32) and the distance recomputed exactly in
  float64, with the triangles around an edge or corner checked where a float32 near-tie
  can have picked the neighbour of the right one;
* :func:`vertex_triangles`, :func:`triangles_around`: the triangles around vertices (a
  CSR incidence), where a float32 pick's neighbours are looked for (here and in the
  scanner's float64 re-test).

Coordinates are metres, preferably in a :class:`~treesim.frame.LocalFrame`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InvalidGeometryError

__all__ = [
    "closest_points_on_triangles",
    "point_to_mesh_distances",
    "triangles_around",
    "vertex_triangles",
    "well_conditioned",
]

_CHUNK = 1 << 18  # points per refinement batch (bounds the temporaries to ~100 MB)
#: Open3D's float32 closest-triangle choice can tie between triangles whose float64
#: distances differ by up to ~1e-7 of the coordinates' magnitude: a point whose exact
#: distance to the picked triangle is above float64 noise (2**-40 of that magnitude) but
#: within this reach (2**-18 of it) may lie on a neighbour, which is checked.
_TIE_FLOOR = 2.0**-40
_TIE_REACH = 2.0**-18
_O3D_CHUNK = 1 << 21  # points per Open3D query
#: Triangles :func:`vertex_triangles` sorts the corners of at once (its temporaries,
#: ~100 B a triangle, stay a few MiB whatever the mesh).
INCIDENCE_CHUNK = 1 << 15


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products (n,) of two (n, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


def closest_points_on_triangles(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> np.ndarray:
    """Closest point on triangle ``(a[i], b[i], c[i])`` to ``p[i]``, exactly, in float64.

    Ericson's region test (Real-Time Collision Detection, 5.1.5), vectorised.

    Parameters
    ----------
    p, a, b, c : (n, 3) float64
        Query points and triangle corners (non-degenerate triangles).

    Returns
    -------
    (n, 3) float64
        The closest points.
    """
    s, t, _ = _closest_params(p, a, b, c)
    return a + s[:, None] * (b - a) + t[:, None] * (c - a)


#: Feature of a triangle a closest point lies on (``_closest_params``' region codes).
_INTERIOR, _A, _B, _C, _AB, _AC, _BC = range(7)


def _closest_params(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ericson's test as parameters: the closest point is ``a + s (b - a) + t (c - a)``.

    Returns
    -------
    s, t : (n,) float64
    region : (n,) int8
        ``_INTERIOR``, a corner (``_A``, ``_B``, ``_C``) or an edge (``_AB``, ``_AC``,
        ``_BC``).
    """
    ab = b - a
    ac = c - a
    ap = p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    abab, abac, acac = _dot(ab, ab), _dot(ab, ac), _dot(ac, ac)
    d3, d4 = d1 - abab, d2 - abac  # ab·(p - b), ac·(p - b)
    d5, d6 = d1 - abac, d2 - acac  # ab·(p - c), ac·(p - c)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    zero, one = np.zeros_like(d1), np.ones_like(d1)
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        s, t = vb / denom, vc / denom
        region = np.zeros(len(p), dtype=np.int8)
        # regions in reverse order of Ericson's tests, so that earlier tests win
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        s, t, region = np.where(m, 1 - w, s), np.where(m, w, t), np.where(m, _BC, region)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        w = d2 / (d2 - d6)
        s, t, region = np.where(m, zero, s), np.where(m, w, t), np.where(m, _AC, region)
        m = (d6 >= 0) & (d5 <= d6)
        s, t, region = np.where(m, zero, s), np.where(m, one, t), np.where(m, _C, region)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        w = d1 / (d1 - d3)
        s, t, region = np.where(m, w, s), np.where(m, zero, t), np.where(m, _AB, region)
        m = (d3 >= 0) & (d4 <= d3)
        s, t, region = np.where(m, one, s), np.where(m, zero, t), np.where(m, _B, region)
        m = (d1 <= 0) & (d2 <= 0)
        s, t, region = np.where(m, zero, s), np.where(m, zero, t), np.where(m, _A, region)
    return s, t, region.astype(np.int8)


def _distances(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Exact distances (n,) float64 from ``p[i]`` to triangle i, and the closest feature
    (n,) int8 (``_closest_params``' region codes)."""
    s, t, region = _closest_params(p, a, b, c)
    diff = (p - a) - s[:, None] * (b - a) - t[:, None] * (c - a)
    return np.sqrt(_dot(diff, diff)), region


def well_conditioned(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` with each triangle's corners rotated so the first is opposite its longest
    edge (orientation kept).

    Open3D's float32 point-to-triangle routine (Ericson's, with the first corner as the
    base) cancels catastrophically on sliver triangles whose first corner is the sharp
    apex: on a 0.15 m x 2 m cylinder with 256 facets it put 47 % of the points lying on
    the surface up to 1.5 mm off, picking the neighbouring triangle. With the first corner
    opposite the longest edge, the two base edges are the short ones and the error is
    gone (measured: 0 of 3000 points off by more than 1e-9 m, on that cylinder and on
    the coffee tree's QSM mesh).

    Parameters
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int

    Returns
    -------
    (f, 3) int64
    """
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = (vertices[f[:, i]] for i in range(3))
    opposite = np.stack(
        [
            np.einsum("ij,ij->i", b - c, b - c),
            np.einsum("ij,ij->i", c - a, c - a),
            np.einsum("ij,ij->i", a - b, a - b),
        ],
        axis=1,
    ).argmax(axis=1)
    return np.take_along_axis(f, (opposite[:, None] + np.arange(3)) % 3, axis=1)


def vertex_triangles(
    faces: Any, n_vertices: int, index: Any = np.int64, chunk: int = INCIDENCE_CHUNK
) -> tuple[np.ndarray, np.ndarray]:
    """The triangles around each vertex, as a CSR incidence ``(ptr, idx)``: those around
    vertex ``i`` are ``idx[ptr[i]:ptr[i + 1]]``, in increasing order (``idx`` in the
    dtype ``index``; ``ptr`` int64).

    ``faces`` is an (f, 3) array or anything whose slices are one (a caster's loaded
    rows). ``idx`` is what a stable argsort of the corners gives (``order // 3``), built
    ``chunk`` triangles at a time straight into the arrays returned: each chunk's corners
    sorted by the int64 keys ``vertex << b | triangle`` (equal keys are equal entries, so
    no order among ties is needed; numpy sorts int64 several times faster than it
    stable-argsorts int32) and placed after those of the chunks before (lower
    triangles). Its temporaries are a chunk's, not 36 B a triangle (issue 25).

    Examples
    --------
    >>> ptr, idx = vertex_triangles(np.array([[0, 1, 2], [2, 1, 3]]), 4)
    >>> ptr.tolist(), idx.tolist()
    ([0, 1, 3, 5, 6], [0, 0, 1, 0, 1, 1])
    """
    n, chunk = len(faces), max(1, int(chunk))
    fill = np.zeros(n_vertices, dtype=np.int64)  # the counts, then the next free slots
    for a in range(0, n, chunk):
        f = np.asarray(faces[a : a + chunk]).reshape(-1)
        if len(f):
            lo = int(f.min())  # a chunk's vertices are near each other in most meshes
            fill[lo : int(f.max()) + 1] += np.bincount(f - lo)
    ptr = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(fill, out=ptr[1:])
    fill[:] = ptr[:-1]  # where each vertex's next triangle goes
    inc = np.empty(int(ptr[-1]), dtype=index)
    bits = (chunk - 1).bit_length()
    for a in range(0, n, chunk):
        key = np.array(faces[a : a + chunk], dtype=np.int64, order="C")
        key <<= bits
        key += np.arange(len(key), dtype=np.int64)[:, None]
        key = key.reshape(-1)
        key.sort()
        vert = key >> bits
        first = np.flatnonzero(np.concatenate([[True], vert[1:] != vert[:-1]]))
        run = np.diff(np.append(first, len(key)))
        # each corner's place: its vertex's next free slot plus its rank in its run
        place = np.repeat(fill[vert[first]] - first, run)
        place += np.arange(len(key))
        key &= (1 << bits) - 1
        key += a
        inc[place] = key
        fill[vert[first]] += run
    return ptr, inc


def triangles_around(
    ptr: np.ndarray, idx: np.ndarray, vertices: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle around each of ``vertices`` (k,), from a :func:`vertex_triangles`
    incidence: ``(owner, triangle)``, ``owner`` the position in ``vertices`` each
    triangle was found around (non-decreasing)."""
    counts = ptr[vertices + 1] - ptr[vertices]
    owner = np.repeat(np.arange(len(vertices)), counts)
    within = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    return owner, idx[np.repeat(ptr[vertices], counts) + within]


def _feature_minimum(
    q: np.ndarray,
    tri: np.ndarray,
    region: np.ndarray,
    verts: np.ndarray,
    faces: np.ndarray,
    ptr: np.ndarray,
    idx: np.ndarray,
) -> np.ndarray:
    """Exact distance (k,) from each ``q[i]`` to the triangles that share the feature
    (corner or edge, ``region[i]``) of triangle ``tri[i]`` its closest point lies on."""
    # the feature's corners: u (always) and w (edges only, else -1)
    first = np.choose(np.clip(region - 1, 0, 5), [0, 1, 2, 0, 0, 1])
    second = np.choose(np.clip(region - 1, 0, 5), [0, 0, 0, 1, 2, 2])
    rows = np.arange(len(tri))
    u = tri[rows, first]
    w = np.where(region >= _AB, tri[rows, second], -1)
    point, cand = triangles_around(ptr, idx, u)
    ww = w[point]
    keep = (ww < 0) | (faces[cand] == ww[:, None]).any(axis=1)  # triangles on the edge
    return _least_distance(q, point[keep], cand[keep], verts, faces)


def _corners_minimum(
    q: np.ndarray,
    tri: np.ndarray,
    verts: np.ndarray,
    faces: np.ndarray,
    ptr: np.ndarray,
    idx: np.ndarray,
) -> np.ndarray:
    """Exact distance (k,) from each ``q[i]`` to the triangles around triangle
    ``tri[i]``'s corners (its edge and vertex neighbours, and itself)."""
    corner, cand = triangles_around(ptr, idx, tri.ravel())
    return _least_distance(q, corner // 3, cand, verts, faces)


def _least_distance(
    q: np.ndarray, point: np.ndarray, cand: np.ndarray, verts: np.ndarray, faces: np.ndarray
) -> np.ndarray:
    """Exact distance (k,) from each ``q[i]`` to the nearest of the triangles ``cand``
    paired with it (``point == i``); inf where none is."""
    f = faces[cand]
    d, _ = _distances(q[point], verts[f[:, 0]], verts[f[:, 1]], verts[f[:, 2]])
    best = np.full(len(q), np.inf)
    np.minimum.at(best, point, d)
    return best


def point_to_mesh_distances(
    query: np.ndarray, verts: np.ndarray, faces: np.ndarray, nthreads: int
) -> np.ndarray:
    """Exact distances from points to a triangle mesh, in float64.

    Open3D (float32) picks a closest triangle (corners rotated by
    :func:`well_conditioned`); the distance to it is recomputed exactly in float64.
    Where that closest point lies on the triangle's boundary, which is where a float32
    near-tie can have picked the neighbour of the right triangle, the triangles sharing
    that edge or corner are measured too and the smallest exact distance is kept; so are
    the triangles around its corners where the point is nearly on it (within float32's
    tie of it, above float64 noise: a point on the mesh beside a concave edge).

    Parameters
    ----------
    query : (n, 3) float64
        Query points, in the same local frame as ``verts`` (metres; keep coordinates
        small, Open3D picks in float32).
    verts : (v, 3) float64
        Mesh vertices (local frame, metres).
    faces : (f, 3) int
        Non-degenerate triangles as vertex indices.
    nthreads : int
        Open3D threads (0: all cores).

    Returns
    -------
    (n,) float64
        Distance (m) from each query point to the nearest triangle.

    Raises
    ------
    InvalidGeometryError
        If Open3D returns no closest triangle for some point.
    """
    import open3d as o3d

    faces = well_conditioned(verts, faces)
    rc = o3d.t.geometry.RaycastingScene(nthreads=int(nthreads))
    rc.add_triangles(
        o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32))
    )
    ptr, idx = vertex_triangles(faces, len(verts))
    extent = float(np.abs(verts).max()) if len(verts) else 0.0
    n = len(query)
    dist = np.empty(n, dtype=np.float64)
    for s in range(0, n, _O3D_CHUNK):
        q = query[s : s + _O3D_CHUNK]
        ans = rc.compute_closest_points(
            o3d.core.Tensor(q.astype(np.float32)), nthreads=int(nthreads)
        )
        pid = ans["primitive_ids"].numpy().astype(np.int64)
        if (pid < 0).any() or (pid >= len(faces)).any():  # never expected: guard Open3D
            raise InvalidGeometryError(
                "Open3D returned no closest triangle for some points; check the mesh"
            )
        for t in range(0, len(q), _CHUNK):
            qq = q[t : t + _CHUNK]
            tri = faces[pid[t : t + _CHUNK]]
            d, region = _distances(qq, verts[tri[:, 0]], verts[tri[:, 1]], verts[tri[:, 2]])
            edge = np.flatnonzero(region != _INTERIOR)
            if len(edge):
                d[edge] = np.minimum(
                    d[edge],
                    _feature_minimum(qq[edge], tri[edge], region[edge], verts, faces, ptr, idx),
                )
            # a point on the mesh near a concave edge projects into the neighbour of its
            # triangle: a float32 tie can pick that neighbour, at a tiny but non-zero
            # distance; the triangles around its corners hold the right one
            scale = extent + np.linalg.norm(qq, axis=1)
            tie = np.flatnonzero(
                (region == _INTERIOR) & (d > _TIE_FLOOR * scale) & (d < _TIE_REACH * scale)
            )
            if len(tie):
                d[tie] = np.minimum(
                    d[tie], _corners_minimum(qq[tie], tri[tie], verts, faces, ptr, idx)
                )
            dist[s + t : s + t + len(qq)] = d
    return dist
