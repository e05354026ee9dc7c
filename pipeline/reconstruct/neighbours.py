"""Nearest-neighbour searches of a prepared cloud, in chunks (bounded temporary memory):
each point's ``k`` nearest points, the point spacing from them, and the nearest kept
points after a cleaning step removed some (without a new search of the whole cloud)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["KEPT_NEIGHBORS", "nearest_neighbors"]

#: Points processed at a time in neighbourhood computations (bounds temporary memory);
#: preparation's other steps import it from here.
_CHUNK = 32768

#: Neighbours per point that :func:`~treesim.reconstruct.preprocess.prepare` finds once
#: and keeps (:attr:`~treesim.reconstruct.preprocess.PreparedCloud.neighbors`): the
#: PCA's ``normals_neighbors`` (24 by default) and the QSM's graph (``neighbors + 1``)
#: and gap bridging (24) read them instead of searching the cloud again.
KEPT_NEIGHBORS = 24


def _index_dtype(n: int) -> type:
    """The narrowest integer type that indexes ``n`` points (int32 below 2**31)."""
    return np.int32 if n < 2**31 - 1 else np.int64


def nearest_neighbors(
    points: np.ndarray, k: int, tree: cKDTree | None = None, *, workers: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest points of every point (itself included), searched in chunks.

    Parameters
    ----------
    points : (n, 3) float64
    k : int
        Neighbours per point, the point itself included (at most ``n`` are returned).
    tree : cKDTree, optional
        A tree already built on ``points``.

    Returns
    -------
    neighbors : (n, min(k, n)) int32 (int64 past 2**31 points)
        Row indices sorted by distance, as ``cKDTree.query`` returns them (the point
        itself first unless it has a duplicate).
    nearest_m : (n,) float64
        Distance to the nearest other row (the second column's distance): its median is
        :func:`~treesim.geometry.point_spacing` with ``distinct=False``.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    tree = cKDTree(pts) if tree is None else tree
    k = int(min(k, n))
    nb = np.empty((n, k), dtype=_index_dtype(n))
    nearest = np.zeros(n)
    for lo in range(0, n, _CHUNK):
        d, j = tree.query(pts[lo : lo + _CHUNK], k=k, workers=workers)
        d, j = d.reshape(len(d), k), j.reshape(len(d), k)
        nb[lo : lo + len(d)] = j
        if k > 1:
            nearest[lo : lo + len(d)] = d[:, 1]
    return nb, nearest


def _lengths(points: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Euclidean lengths of the pairs (i, j), computed as ``cKDTree.query`` computes its
    distances (the same float64 operations in the same order, so the same bits)."""
    diff = points[i] - points[j]
    return np.sqrt((diff * diff).sum(axis=-1))


def _spacing(points: np.ndarray, neighbors: np.ndarray, nearest: np.ndarray | None) -> float:
    """:func:`~treesim.geometry.point_spacing` with ``distinct=False`` (the same bits)
    from the :func:`nearest_neighbors` of ``points``: the median of ``nearest`` when the
    search returned it, else of the lengths to the second column."""
    if nearest is None:
        nearest = _lengths(points, np.arange(len(points)), neighbors[:, 1])
    return float(np.median(nearest))


def _neighbors_of_kept(
    points: np.ndarray,
    neighbors: np.ndarray,
    keep: np.ndarray,
    k: int,
    tree: cKDTree,
    *,
    workers: int = 1,
) -> np.ndarray:
    """The ``k`` nearest kept points of each kept point, numbered among the kept points.

    ``neighbors`` are the nearest points among all ``points`` (``tree``'s). A kept point
    whose ``k`` nearest were all kept has the same list among the kept points; the
    others (those next to a removed point) are searched again, deeper, and their first
    ``k`` kept neighbours taken: the result of a new search over the kept points, without
    building its tree or searching every point again.
    """
    n_all = len(points)
    kept = np.flatnonzero(keep)
    new = np.full(n_all, -1, dtype=neighbors.dtype)
    new[kept] = np.arange(len(kept), dtype=neighbors.dtype)
    k = int(min(k, len(kept)))
    out = np.empty((len(kept), k), dtype=neighbors.dtype)
    for lo in range(0, len(kept), _CHUNK):  # no (n, k) temporary beside the two tables
        out[lo : lo + _CHUNK] = new[neighbors[kept[lo : lo + _CHUNK], :k]]
    redo = np.flatnonzero((out < 0).any(axis=1))
    depth = k
    while len(redo):
        depth = int(min(2 * depth, n_all))
        _, j = tree.query(points[kept[redo]], k=depth, workers=workers)
        m = new[j.reshape(len(redo), depth)]
        enough = ((m >= 0).sum(axis=1) >= k) | (depth == n_all)
        first = np.argsort(m[enough] < 0, axis=1, kind="stable")[:, :k]
        out[redo[enough]] = np.take_along_axis(m[enough], first, axis=1)
        redo = redo[~enough]
    return out
