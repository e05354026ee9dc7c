"""Nearest-neighbour spacing of point clouds, and the k-d tree it is measured with."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InvalidGeometryError

__all__ = ["kdtree", "point_spacing"]

#: Neighbours searched for a point whose nearest neighbour coincides with it.
_DUPLICATE_SEARCH = 32


def kdtree(points: np.ndarray) -> Any:
    """A SciPy ``cKDTree`` (float64) on ``points``, built the fast way (unbalanced, loose
    nodes): quicker to build than the default, with the same query distances.

    Parameters
    ----------
    points : (n, 3) float64

    Returns
    -------
    scipy.spatial.cKDTree
    """
    from scipy.spatial import cKDTree

    return cKDTree(points, balanced_tree=False, compact_nodes=False)


def point_spacing(
    points: np.ndarray,
    *,
    distinct: bool = True,
    subsample: int | None = None,
    seed: int = 0,
    tree: Any = None,
    workers: int = -1,
) -> float:
    """Median nearest-neighbour distance of a point cloud (m).

    What is measured: for each query point, the Euclidean distance to the nearest *other*
    point of ``points`` (another row, never the point itself); the result is the median
    of these distances over the query points. The query points are all points, or, when
    ``subsample`` is given and smaller than the cloud, that many distinct rows drawn
    with ``numpy.random.default_rng(seed).choice(n, subsample, replace=False)``.

    ``distinct`` decides what coincident points (equal coordinates) count as:

    * ``True``: the nearest other point at a *non-zero* distance, i.e. the spacing of the
      distinct locations (what a cloud with every point written twice still has). It is
      searched among the 32 nearest rows; a query point whose 32 nearest rows all
      coincide with it is left out of the median. This is the comparison's
      ``point_spacing_m``.
    * ``False``: the nearest other row, so a duplicate counts as a neighbour at distance
      0 (the spacing the points are actually stored at). A cloud of fewer than two
      points has spacing 0.0. This is what reconstruction scales its radii by.

    Parameters
    ----------
    points : (n, 3) float64
        The cloud (m), preferably in a local frame.
    distinct : bool
        Skip coincident points (see above).
    subsample : int, optional
        Measure at this many seeded random points (queried against all points); default
        all points.
    seed : int
        Seed of the subsample.
    tree : scipy.spatial.cKDTree, optional
        A tree already built on ``points`` (default: :func:`kdtree`).
    workers : int
        Query threads, as SciPy takes them (-1: all cores).

    Returns
    -------
    float
        The spacing in metres.

    Raises
    ------
    InvalidGeometryError
        With ``distinct``, if no query point has a non-coincident neighbour (all points
        coincide, or fewer than two points).
    """
    pts = np.asarray(points, dtype=np.float64)
    if not distinct and len(pts) < 2:
        return 0.0
    tree = tree if tree is not None else kdtree(pts)
    if subsample is not None and len(pts) > subsample:
        idx = np.random.default_rng(seed).choice(len(pts), size=subsample, replace=False)
        q = pts[idx]
    else:
        q = pts
    d = tree.query(q, k=2, workers=workers)[0][:, 1]
    if distinct:
        dup = np.flatnonzero(d == 0)
        if len(dup):  # duplicates: look further for the nearest *other* point
            far = tree.query(q[dup], k=min(len(pts), _DUPLICATE_SEARCH), workers=workers)[0]
            d[dup] = np.where(far > 0, far, np.inf).min(axis=1)
        d = d[np.isfinite(d)]
        if len(d) == 0:
            raise InvalidGeometryError(
                "all points of the cloud coincide, so it has no spacing to derive the "
                "tolerance from; check the input, or give tolerance_m (--tolerance-m) and, "
                "for a mesh reference, sample_spacing_m (--sample-spacing-m)"
            )
    return float(np.median(d))
