"""The ground plane under a tree (:func:`find_ground`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .normals import _local_pca

__all__ = ["find_ground"]

#: Height of the lowest band of the cloud searched for ground (m).
GROUND_BAND_M = 0.5
#: Largest tilt of a ground plane, and of the local surface of a ground candidate (deg).
GROUND_MAX_TILT_DEG = 35.0
#: A plane is ground only if its inliers cover this much area (m²) ...
GROUND_MIN_AREA_M2 = 0.25
#: ... and this share of their own bounding box (a stem's cut end is a thin ring).
GROUND_MIN_FILL = 0.25
#: RANSAC trials and seed for the ground plane.
GROUND_RANSAC_TRIALS = 300
GROUND_RANSAC_SEED = 0


def find_ground(
    points: np.ndarray,
    tolerance_m: float,
    spacing_m: float,
    *,
    tree: cKDTree | None = None,
    workers: int = 1,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Find a ground plane under a tree.

    Candidates are the points within ``GROUND_BAND_M`` of the lowest point whose local
    surface (PCA of 16 neighbours) is tilted less than ``GROUND_MAX_TILT_DEG``. A plane
    is fitted to them by RANSAC (``GROUND_RANSAC_TRIALS`` trials, seed
    ``GROUND_RANSAC_SEED``, planes tilted more than ``GROUND_MAX_TILT_DEG`` rejected) and
    refined by least squares on its inliers. It is ground only if those inliers cover at
    least ``GROUND_MIN_AREA_M2`` and ``GROUND_MIN_FILL`` of their bounding box (square
    cells of ``max(5 cm, 4 × spacing, 3 × the inliers' own median horizontal spacing)``):
    the cut end of a stem is a thin ring and fails both.

    Parameters
    ----------
    points : (n, 3) float
        Local coordinates, z up (m).
    tolerance_m : float
        Inlier distance, and the height above the plane below which points are ground.
    spacing_m : float
        Median point spacing (m).

    Returns
    -------
    ground : (n, bool)
        Points to remove (all False when no ground was found).
    info : dict
        ``detected``, ``plane`` (a, b, c, d with a x + b y + c z + d = 0, c > 0, or None),
        ``covered_area_m2``, ``fill``, ``candidates``.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    none = np.zeros(n, dtype=bool)
    info: dict[str, Any] = {
        "detected": False,
        "plane": None,
        "covered_area_m2": 0.0,
        "fill": 0.0,
        "candidates": 0,
    }
    band = np.flatnonzero(pts[:, 2] <= pts[:, 2].min() + GROUND_BAND_M)
    if len(band) < 30:
        return none, info
    tree = cKDTree(pts) if tree is None else tree
    _, nrm = _local_pca(pts, 16, tree, rows=band, workers=workers)
    cos_tilt = math.cos(math.radians(GROUND_MAX_TILT_DEG))
    cand = band[np.abs(nrm[:, 2]) >= cos_tilt]
    info["candidates"] = int(len(cand))
    if len(cand) < 30:
        return none, info
    cp = pts[cand]
    step = max(1, len(cp) // 20000)
    sample = cp[::step]
    rng = np.random.default_rng(GROUND_RANSAC_SEED)
    tri = rng.integers(0, len(sample), size=(GROUND_RANSAC_TRIALS, 3))
    a, b, c = sample[tri[:, 0]], sample[tri[:, 1]], sample[tri[:, 2]]
    nv = np.cross(b - a, c - a)
    norm = np.linalg.norm(nv, axis=1)
    ok = norm > 1e-12
    nv[ok] /= norm[ok, None]
    ok &= np.abs(nv[:, 2]) >= cos_tilt
    best, best_count = -1, 0
    for t in np.flatnonzero(ok):
        count = int((np.abs((sample - a[t]) @ nv[t]) < tolerance_m).sum())
        if count > best_count:
            best, best_count = int(t), count
    if best < 0:
        return none, info
    inl = np.abs((cp - a[best]) @ nv[best]) < tolerance_m
    q = cp[inl]
    centre = q.mean(axis=0)
    _, _, vt = np.linalg.svd(q - centre, full_matrices=False)
    normal = vt[2] if vt[2, 2] >= 0 else -vt[2]
    if normal[2] < cos_tilt:
        return none, info
    d0 = -float(normal @ centre)
    height = pts @ normal + d0
    inl = np.abs(height[cand]) < tolerance_m
    q = cp[inl]
    if len(q) < 3:
        return none, info
    d2, _ = cKDTree(q[:, :2]).query(q[:, :2], k=2)
    cell = max(0.05, 4.0 * spacing_m, 3.0 * float(np.median(d2[:, 1])))
    cells = np.unique(np.floor(q[:, :2] / cell).astype(np.int64), axis=0)
    covered = len(cells) * cell * cell
    ext = q[:, :2].max(axis=0) - q[:, :2].min(axis=0) + cell
    fill = covered / float(ext[0] * ext[1])
    info.update(
        plane=[float(normal[0]), float(normal[1]), float(normal[2]), d0],
        covered_area_m2=float(covered),
        fill=float(fill),
    )
    if covered < GROUND_MIN_AREA_M2 or fill < GROUND_MIN_FILL:
        return none, info
    info["detected"] = True
    return height < tolerance_m, info
