"""Checks that a point cloud could be a tree (:func:`validate_tree_cloud`)."""

from __future__ import annotations

import numpy as np

from ..cloud import Cloud
from ..errors import EmptyInputError, InvalidGeometryError

__all__ = ["validate_tree_cloud"]

#: Smallest-to-largest principal standard deviation below which a cloud is a plane
#: (third axis against the second) or a line (second against the first). A 1 cm-radius
#: sapling stem 3.5 m tall scanned from one side still has a ratio of 0.005.
PLANE_SD_RATIO = 0.01
LINE_SD_RATIO = 0.002


def _as_points(cloud: Cloud | np.ndarray) -> np.ndarray:
    pts = cloud.points if isinstance(cloud, Cloud) else np.asarray(cloud, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidGeometryError(f"points must have shape (n, 3), got {pts.shape}")
    return np.asarray(pts, dtype=np.float64)


def validate_tree_cloud(cloud: Cloud | np.ndarray, *, min_points: int = 300) -> None:
    """Raise unless ``cloud`` could be a tree.

    Parameters
    ----------
    cloud : Cloud or (n, 3) float
    min_points : int
        Fewest points accepted.

    Raises
    ------
    EmptyInputError
        No points, or fewer than ``min_points``.
    InvalidGeometryError
        NaN or infinite coordinates (the count and the first row are named), all points
        identical, or the points lying on a plane or a line (principal standard
        deviations: third/second below ``PLANE_SD_RATIO`` or second/first below
        ``LINE_SD_RATIO``).
    """
    pts = _as_points(cloud)
    n = len(pts)
    if n == 0:
        raise EmptyInputError("the point cloud has no points; check the file and its columns")
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InvalidGeometryError(
            f"{int(bad.sum())} of {n} points have NaN or infinite coordinates (first at row "
            f"{first}: {pts[first].tolist()}); drop those rows before reconstructing"
        )
    if n < min_points:
        raise EmptyInputError(
            f"only {n} points; a tree needs at least {min_points} to reconstruct; "
            "use a denser scan or a larger clip"
        )
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if np.all(hi == lo):
        raise InvalidGeometryError(
            f"all {n} points are identical (at {lo.tolist()}): not a tree; check the "
            "export (a scanner writes zeros for missing returns)"
        )
    local = pts - 0.5 * (lo + hi)
    centred = local - local.mean(axis=0)
    cov = centred.T @ centred / n
    evals, evecs = np.linalg.eigh(cov)  # ascending
    sd = np.sqrt(np.clip(evals, 0.0, None))[::-1]  # descending
    axes = evecs[:, ::-1]

    def _span(axis: int) -> float:
        proj = centred @ axes[:, axis]
        p1, p99 = np.percentile(proj, [1.0, 99.0])
        return float(p99 - p1)

    if sd[1] <= LINE_SD_RATIO * sd[0]:
        raise InvalidGeometryError(
            f"the points lie on a line (width {1000 * _span(1):.2g} mm over "
            f"{_span(0):.3g} m): not a tree; check the file's columns and units"
        )
    if sd[2] <= PLANE_SD_RATIO * sd[1]:
        raise InvalidGeometryError(
            f"the points lie on a plane (thickness {1000 * _span(2):.2g} mm over "
            f"{_span(0):.3g} m): not a tree; check the file's columns (is z missing?) "
            "or whether this is a ground or wall scan"
        )
