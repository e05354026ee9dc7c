"""Exact geometry checks for the model tests (float64, no spatial-index dependencies)."""

from __future__ import annotations

import numpy as np


def assert_closed_and_outward(faces: np.ndarray) -> None:
    """Every edge is shared by exactly two faces, traversed once in each direction."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    base = np.int64(faces.max()) + 1
    keys = np.sort(directed[:, 0] * base + directed[:, 1])
    assert (np.diff(keys) > 0).all(), "a directed edge is used twice: inconsistent winding"
    reverse = np.sort(directed[:, 1] * base + directed[:, 0])
    assert np.array_equal(keys, reverse), "an edge has no opposite: the mesh is open"


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) areas of the triangles."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return np.linalg.norm(np.cross(b - a, c - a), axis=1) / 2.0


def assert_no_degenerate(vertices: np.ndarray, faces: np.ndarray) -> None:
    """No triangle is degenerate: area > 1e-9 of its longest edge squared (what the scanner
    drops as degenerate is 1e-12 of it), and no triangle repeats a vertex."""
    assert (faces[:, 0] != faces[:, 1]).all() and (faces[:, 1] != faces[:, 2]).all()
    assert (faces[:, 0] != faces[:, 2]).all()
    tri = vertices[faces]
    edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    area = triangle_areas(vertices, faces)
    worst = float((area / edge**2).min())
    assert worst > 1e-9, f"a sliver triangle: area / longest edge^2 = {worst:.3g}"


def point_triangle_distance(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> np.ndarray:
    """(n,) exact distances from points ``p`` to triangles ``(a, b, c)``, all (n, 3), in pairs."""
    ab, ac = b - a, c - a
    d1 = np.einsum("ij,ij->i", ab, p - a)
    d2 = np.einsum("ij,ij->i", ac, p - a)
    d3 = np.einsum("ij,ij->i", ab, p - b)
    d4 = np.einsum("ij,ij->i", ac, p - b)
    d5 = np.einsum("ij,ij->i", ab, p - c)
    d6 = np.einsum("ij,ij->i", ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    inside = (va >= 0) & (vb >= 0) & (vc >= 0) & (denom > 0)
    safe = np.where(denom > 0, denom, 1.0)
    v = np.where(inside, vb / safe, 0.0)
    w = np.where(inside, vc / safe, 0.0)
    foot = a + ab * v[:, None] + ac * w[:, None]
    best = np.where(inside, np.linalg.norm(foot - p, axis=1), np.inf)
    for s, e in ((a, b), (a, c), (b, c)):
        se = e - s
        ll = np.einsum("ij,ij->i", se, se)
        t = np.clip(np.einsum("ij,ij->i", p - s, se) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(s + se * t[:, None] - p, axis=1))
    return best


def near_distances(
    points: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    reach: float,
    cell: float = 0.1,
) -> np.ndarray:
    """Exact distance from each point to its nearest triangle, where that is <= ``reach``.

    Points farther than ``reach`` from every triangle get ``inf``. Triangles are binned
    into a grid of ``cell``-sized cubes by their bounding boxes grown by ``reach``; each
    point is compared exactly with the triangles of its cube.
    """
    tri = vertices[faces]
    origin = np.minimum(tri.reshape(-1, 3).min(axis=0), points.min(axis=0)) - 2.0 * reach
    lo = np.floor((tri.min(axis=1) - reach - origin) / cell).astype(np.int64)
    hi = np.floor((tri.max(axis=1) + reach - origin) / cell).astype(np.int64)
    dims = hi - lo + 1
    counts = dims.prod(axis=1)
    tid = np.repeat(np.arange(len(tri)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    dx, dy = dims[tid, 0], dims[tid, 1]
    big = np.int64(1 << 20)
    key = ((lo[tid, 0] + k % dx) * big + lo[tid, 1] + (k // dx) % dy) * big + (
        lo[tid, 2] + k // (dx * dy)
    )
    order = np.argsort(key, kind="stable")
    key, tid = key[order], tid[order]
    pc = np.floor((points - origin) / cell).astype(np.int64)
    pkey = (pc[:, 0] * big + pc[:, 1]) * big + pc[:, 2]
    first = np.searchsorted(key, pkey, "left")
    n = np.searchsorted(key, pkey, "right") - first
    pid = np.repeat(np.arange(len(points)), n)
    j = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + np.repeat(first, n)
    t = tid[j]
    d = point_triangle_distance(points[pid], tri[t, 0], tri[t, 1], tri[t, 2])
    out = np.full(len(points), np.inf)
    np.minimum.at(out, pid, d)
    out[out > reach] = np.inf
    return out


def winding_numbers(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) generalised winding numbers of ``points`` about a closed, outward mesh.

    1 inside, 0 outside (the solid angles of the triangles summed over 4 pi, by Van
    Oosterom & Strackee's formula); exact up to rounding for a watertight mesh.
    """
    a = vertices[faces[:, 0]][None, :, :] - points[:, None, :]
    b = vertices[faces[:, 1]][None, :, :] - points[:, None, :]
    c = vertices[faces[:, 2]][None, :, :] - points[:, None, :]
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    det = np.einsum("pfj,pfj->pf", a, np.cross(b, c))
    den = (
        la * lb * lc
        + np.einsum("pfj,pfj->pf", a, b) * lc
        + np.einsum("pfj,pfj->pf", b, c) * la
        + np.einsum("pfj,pfj->pf", c, a) * lb
    )
    return (2.0 * np.arctan2(det, den)).sum(axis=1) / (4.0 * np.pi)
