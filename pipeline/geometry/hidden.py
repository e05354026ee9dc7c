"""Hidden surface: mesh area that lies inside another closed part of the same mesh.

A mesh made of overlapping closed pieces (a tree of tubes whose branches start inside
their parents, separate cylinders whose end caps are buried in the next cylinder) has
triangles that no scanner outside the tree can see: they are inside the solid. Surface
samples on them measure nothing but the mesh's construction, so completeness leaves them
out.

* :func:`mesh_parts`: the mesh's connected pieces (vertices merged by exact position), and
  which of them are closed (every edge shared by an even number of triangles, so that
  "inside" is defined by ray parity);
* :func:`inside_other_parts`: for points on the mesh (each with the part it lies on),
  whether it lies strictly inside another closed part.

The inside test is ray parity per part, along a line through each point: Open3D's
``RaycastingScene.list_intersections`` (float32, in the caller's local frame) lists every
crossing of the half-line ahead of the point, and, for the points with an odd count of
some part there, of the half-line behind it; both counts must be odd for the point to be
inside that part (a closed surface is crossed an even number of times along a whole
line). Float32 can pass a ray through a shared edge twice or not at all (DESIGN:
0.02-0.12 % of rays through shared vertices); crossings of one part closer than ``eps``
along a line are merged into one, and a point whose two counts for some part disagree (a
crossing was missed) is cast again in other directions until one is consistent (else
the majority of the directions decides). A point within ``eps`` of another part's
surface is on that surface, not inside it (coincident surfaces are kept). Points whose
line ahead crosses every other part an even number of times are outside them all (only
the second half-line could show a missed crossing there, and only for an inside point
whose line lost its single crossing: a float32 accident on a measure-zero set).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidGeometryError

__all__ = ["MeshParts", "inside_other_parts", "mesh_parts"]

#: Lines cast at a time (list_intersections returns every crossing, ~25 bytes each, and a
#: line through a large crown crosses a hundred triangles or more).
_CHUNK = 1 << 15
#: Directions tried for a point whose first line is inconsistent, besides the first.
_RETRIES = 4
#: Crossings closer than this fraction of the mesh's bounding-box diagonal along a line
#: count once (float32 resolution in a local frame is ~6e-8 of the coordinates).
_EPS_REL = 1e-6


@dataclass(frozen=True, eq=False)
class MeshParts:
    """A mesh's connected pieces (triangles joined through shared edges).

    Attributes
    ----------
    part_of_face : (f,) int64
        Piece of each triangle, ``0 .. n_parts - 1``.
    closed : (n_parts,) bool
        Whether each piece is closed: every edge (after merging vertices at the same
        position) is shared by an even number of its triangles.
    """

    part_of_face: np.ndarray
    closed: np.ndarray

    @property
    def n_parts(self) -> int:
        return int(self.closed.shape[0])

    @property
    def n_closed(self) -> int:
        return int(self.closed.sum())


def mesh_parts(vertices: np.ndarray, faces: np.ndarray) -> MeshParts:
    """The connected pieces of a triangle mesh and which are closed.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int

    Returns
    -------
    MeshParts
        Pieces of triangles connected through shared edges, where vertices at exactly
        the same position count as one (a mesh stored as a triangle soup still has
        pieces; two closed pieces touching at a single point stay two).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
        raise InvalidGeometryError(f"faces must be (f, 3) indices into vertices, got {f.shape}")
    if len(f) == 0:
        return MeshParts(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))
    used = np.unique(f)
    _, first = np.unique(v[used], axis=0, return_inverse=True)
    merged = np.full(len(v), -1, dtype=np.int64)
    merged[used] = first.reshape(-1)
    fm = merged[f]
    nv = int(fm.max()) + 1
    nf = len(fm)
    edges = np.concatenate([fm[:, [0, 1]], fm[:, [1, 2]], fm[:, [2, 0]]])
    edges.sort(axis=1)
    key = edges[:, 0] * nv + edges[:, 1]
    face = np.tile(np.arange(nf, dtype=np.int64), 3)
    order = np.argsort(key, kind="stable")
    key, face = key[order], face[order]
    # triangles sharing an edge are linked (consecutive ones in each run of one edge)
    same = key[1:] == key[:-1]
    graph = coo_matrix(
        (np.ones(int(same.sum()), dtype=np.int8), (face[:-1][same], face[1:][same])),
        shape=(nf, nf),
    )
    n_parts, label = connected_components(graph, directed=False)
    part_of_face = label.astype(np.int64)
    starts = np.flatnonzero(np.concatenate([[True], ~same]))
    count = np.diff(np.concatenate([starts, [len(key)]]))
    closed = np.ones(n_parts, dtype=bool)
    closed[part_of_face[face[starts[count % 2 == 1]]]] = False
    return MeshParts(part_of_face, closed)


def _crossings(
    scene: object,
    points: np.ndarray,
    point_part: np.ndarray,
    closed_part_of_face: np.ndarray,
    n_parts: int,
    direction: np.ndarray,
    eps: float,
    nthreads: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crossings of other closed parts along the half-lines from ``points`` along
    ``direction``: per (point, part) met, its key ``point * n_parts + part`` (sorted),
    whether the count beyond ``eps`` is odd, and whether a crossing lies within ``eps``
    of the point (the point is on that part's surface)."""
    import open3d as o3d

    keys, odd, on = [], [], []
    for lo in range(0, len(points), _CHUNK):
        p = points[lo : lo + _CHUNK]
        rays = np.empty((len(p), 6), dtype=np.float32)
        rays[:, :3] = p
        rays[:, 3:] = direction
        hits = scene.list_intersections(  # type: ignore[attr-defined]
            o3d.core.Tensor(rays), nthreads=int(nthreads)
        )
        ray = hits["ray_ids"].numpy().astype(np.int64) + lo
        if ray.size == 0:
            continue
        t = hits["t_hit"].numpy().astype(np.float64)
        part = closed_part_of_face[hits["primitive_ids"].numpy().astype(np.int64)]
        keep = part != point_part[ray]
        group, t = ray[keep] * n_parts + part[keep], t[keep]
        order = np.lexsort((t, group))
        group, t = group[order], t[order]
        # crossings of one part closer than eps along the line count once (a shared edge)
        dup = np.zeros(len(t), dtype=bool)
        dup[1:] = (group[1:] == group[:-1]) & (t[1:] - t[:-1] < eps)
        group, t = group[~dup], t[~dup]
        k, idx = np.unique(group, return_inverse=True)
        idx = idx.reshape(-1)
        keys.append(k)
        odd.append(np.bincount(idx, weights=t > eps, minlength=len(k)) % 2 == 1)
        on.append(np.bincount(idx, weights=t <= eps, minlength=len(k)) > 0)
    if not keys:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty.astype(bool), empty.astype(bool)
    return np.concatenate(keys), np.concatenate(odd), np.concatenate(on)


def _line_verdicts(
    scene: object,
    points: np.ndarray,
    point_part: np.ndarray,
    closed_part_of_face: np.ndarray,
    n_parts: int,
    direction: np.ndarray,
    eps: float,
    nthreads: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Per point: (inside another closed part, the line's counts were consistent).

    The half-line ahead of every point first; the one behind only for the points that
    have an odd count ahead for some part (the others are outside every part, or a
    crossing was missed, which the line behind could only show for the former)."""
    n = len(points)
    inside = np.zeros(n, dtype=bool)
    consistent = np.ones(n, dtype=bool)
    args = (closed_part_of_face, n_parts)
    k_ahead, odd_ahead, on_ahead = _crossings(
        scene, points, point_part, *args, direction, eps, nthreads
    )
    maybe = odd_ahead & ~on_ahead
    cand = np.unique(k_ahead[maybe] // n_parts)
    if cand.size == 0:
        return inside, consistent
    k_behind, odd_behind, on_behind = _crossings(
        scene, points[cand], point_part[cand], *args, -direction, eps, nthreads
    )
    k_behind = cand[k_behind // n_parts] * n_parts + k_behind % n_parts
    # per (point, part) met on either side: odd ahead, odd behind, on the surface
    sel = np.isin(k_ahead // n_parts, cand)
    keys = np.concatenate([k_ahead[sel], k_behind])
    uniq, idx = np.unique(keys, return_inverse=True)
    idx = idx.reshape(-1)
    m = int(sel.sum())
    ahead = np.zeros(len(uniq), dtype=bool)
    behind = np.zeros(len(uniq), dtype=bool)
    on = np.zeros(len(uniq), dtype=bool)
    ahead[idx[:m]] = odd_ahead[sel]
    behind[idx[m:]] = odd_behind
    on[idx[:m]] |= on_ahead[sel]
    on[idx[m:]] |= on_behind
    point = uniq // n_parts
    inside[point[~on & ahead & behind]] = True
    consistent[point[~on & (ahead ^ behind)]] = False
    return inside, consistent


def inside_other_parts(
    points: np.ndarray,
    point_face: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    parts: MeshParts | None = None,
    *,
    seed: int = 0,
    nthreads: int = 0,
) -> np.ndarray:
    """Whether each point on a mesh lies strictly inside another closed part of it.

    Parameters
    ----------
    points : (n, 3) float64
        Points on the mesh (e.g. surface samples), in a local frame (near the origin:
        the lines are cast in float32).
    point_face : (n,) int
        Triangle each point lies on; its part is never tested against the point.
    vertices : (v, 3) float64
        Mesh vertices, same frame.
    faces : (f, 3) int
    parts : MeshParts, optional
        :func:`mesh_parts` of the mesh, when already known.
    seed : int
        Seed of the line directions.
    nthreads : int
        Open3D threads (0: all cores).

    Returns
    -------
    (n,) bool
        True where the point is inside a closed part other than its own (farther than
        ``1e-6`` of the mesh's bounding-box diagonal from that part's surface).
    """
    p = np.asarray(points, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    pf = np.asarray(point_face, dtype=np.int64)
    if p.ndim != 2 or p.shape[1] != 3 or pf.shape != (len(p),):
        raise InvalidGeometryError(
            f"points must be (n, 3) with one face each, got {p.shape} and {pf.shape}"
        )
    parts = parts if parts is not None else mesh_parts(v, f)
    out = np.zeros(len(p), dtype=bool)
    if len(p) == 0 or parts.n_closed == 0 or parts.n_parts < 2:
        return out
    import open3d as o3d

    closed_faces = np.flatnonzero(parts.closed[parts.part_of_face])
    scene = o3d.t.geometry.RaycastingScene(nthreads=int(nthreads))
    scene.add_triangles(
        o3d.core.Tensor(v.astype(np.float32)),
        o3d.core.Tensor(f[closed_faces].astype(np.uint32)),
    )
    closed_part_of_face = parts.part_of_face[closed_faces]
    point_part = parts.part_of_face[pf]
    used = v[np.unique(f)]
    lo, hi = used.min(axis=0), used.max(axis=0)
    eps = _EPS_REL * max(float(np.linalg.norm(hi - lo)), 1e-3)
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(1 + _RETRIES, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)

    todo = np.arange(len(p))
    votes = np.zeros(len(p), dtype=np.int64)
    tries = np.zeros(len(p), dtype=np.int64)
    for d in directions:
        inside, consistent = _line_verdicts(
            scene,
            p[todo],
            point_part[todo],
            closed_part_of_face,
            parts.n_parts,
            d,
            eps,
            nthreads,
        )
        done = consistent
        out[todo[done]] = inside[done]
        votes[todo] += inside
        tries[todo] += 1
        todo = todo[~done]
        if todo.size == 0:
            break
    if todo.size:  # never consistent: the majority of the directions decides
        out[todo] = 2 * votes[todo] > tries[todo]
    return out
