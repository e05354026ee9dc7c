"""Voxel downsampling (:func:`voxel_downsample`): one point per occupied voxel, the
weighted centroid of the points in it."""

from __future__ import annotations

import numpy as np

__all__ = ["voxel_downsample"]


def voxel_downsample(
    points: np.ndarray,
    voxel_size_m: float | None,
    weights: np.ndarray | None = None,
    *,
    anchor: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One point per occupied voxel: the (weighted) centroid of the points in it.

    Parameters
    ----------
    points : (n, 3) float
    voxel_size_m : float or None
        Voxel edge (m); ``None`` merges exact duplicates only.
    weights : (n,) float, optional
        Weight of each input point (default 1); the output weights are their sums.
    anchor : (3,) float, optional
        A corner of the voxel grid; default half a voxel below the minimum corner of
        ``points`` (as Open3D does, so the lowest points are not on a voxel boundary).

    Returns
    -------
    centroids : (m, 3) float64
        Sorted by voxel index (x, then y, then z), so the output is deterministic.
    out_weights : (m,) float64 or int64
        Summed weights (int64 counts when ``weights`` is None).
    inverse : (n,) int64
        Output row of each input point.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        return pts.reshape(0, 3), np.zeros(0, np.int64), np.zeros(0, np.int64)
    if voxel_size_m is None:
        _, inverse = np.unique(pts, axis=0, return_inverse=True)
    else:
        h = float(voxel_size_m)
        origin = pts.min(axis=0) - 0.5 * h if anchor is None else np.asarray(anchor, np.float64)
        keys = np.floor((pts - origin) / h).astype(np.int64)
        keys -= keys.min(axis=0)
        dims = keys.max(axis=0) + 1
        if float(dims[0]) * float(dims[1]) * float(dims[2]) < 2.0**62:
            code = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
            _, inverse = np.unique(code, return_inverse=True)
        else:  # a grid too large to number in int64: sort the index triples instead
            _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = np.asarray(inverse, dtype=np.int64).reshape(-1)
    m = int(inverse.max()) + 1
    if weights is None:
        w = np.ones(len(pts))
        out_w: np.ndarray = np.bincount(inverse, minlength=m).astype(np.int64)
    else:
        w = np.asarray(weights, dtype=np.float64)
        out_w = np.bincount(inverse, weights=w, minlength=m)
    wsum = np.bincount(inverse, weights=w, minlength=m)
    centroids = np.empty((m, 3), dtype=np.float64)
    for k in range(3):
        centroids[:, k] = np.bincount(inverse, weights=pts[:, k] * w, minlength=m) / wsum
    return centroids, out_w, inverse
