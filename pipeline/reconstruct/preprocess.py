"""Preparing a field point cloud for reconstruction: checks, thinning, cleaning, normals.

:func:`prepare` turns a :class:`~treesim.cloud.Cloud` (any coordinates, georeferenced
or not) into a :class:`PreparedCloud` in a float64 local frame, in this order:

1. **Checks** (:func:`validate_tree_cloud`): enough points, no NaN/inf rows, not all
   identical, not a plane or a line; each failure names the problem.
2. **Voxel downsampling** (``voxel_size_m``, default 5 mm): one point per occupied voxel,
   the centroid of the points in it, computed in float64; ``weights`` count the input
   points each output point stands for. Duplicate points always collapse (with the voxel
   grid off, exact duplicates are merged instead): duplicates break PCA normals and change
   Poisson and ball-pivoting output.
3. **Statistical outlier removal** (``sor_neighbors``, ``sor_std_ratio``): a point whose
   mean distance to its ``k`` nearest neighbours exceeds the mean of that figure over the
   cloud by more than ``sor_std_ratio`` standard deviations (PCL's and Open3D's rule) and
   is also more than three times its neighbours' median is dropped: sparse but consistent
   regions (a treetop far from the scanner) stay.
4. **Ground removal** (``remove_ground``, on by default): see :func:`find_ground`. A
   horizontal or gently sloping plane is fitted (RANSAC with a fixed seed) to the points
   of the lowest 0.5 m whose local surface is near horizontal; it is taken for ground only when its
   inliers cover a wide, filled area (at least 0.25 m² and a quarter of their bounding
   box), so the cut end of a stem with no ground under it is never removed. Then every
   point less than ``ground_tolerance_m`` above the plane (or below it) is dropped. Then
   the stem's foot and the understory (``remove_understory``): see
   :mod:`treesim.reconstruct.foot`.
5. **Spacing**: the median nearest-neighbour distance of what is left.
6. **Normals** (:func:`estimate_normals`): PCA of the ``normals_neighbors`` nearest
   neighbours, oriented outward (away from the local centroid at the smallest telling
   scale, see there).
7. **Leaves** (:func:`leaf_measure`): the share of points whose ~10 cm neighbourhood has
   normals pointing every way (foliage), as opposed to normals perpendicular to one axis
   (stems, branches, even twigs whose PCA normals are noisy).

Every step records how many points it removed in :attr:`PreparedCloud.steps`.
Everything is deterministic and vectorised (``scipy.spatial.cKDTree``; no O(n²) step).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..cloud import Cloud
from ..errors import EmptyInputError, InvalidGeometryError, InvalidParameterError
from ..frame import LocalFrame
from ..geometry import point_spacing
from ..params import PrepareParams
from .foot import StemFoot, find_foot, understory

__all__ = [
    "PrepareParams",
    "PreparedCloud",
    "estimate_normals",
    "find_ground",
    "leaf_measure",
    "nearest_neighbors",
    "prepare",
    "validate_tree_cloud",
    "voxel_downsample",
]

#: Smallest-to-largest principal standard deviation below which a cloud is a plane
#: (third axis against the second) or a line (second against the first). A 1 cm-radius
#: sapling stem 3.5 m tall scanned from one side still has a ratio of 0.005.
PLANE_SD_RATIO = 0.01
LINE_SD_RATIO = 0.002

#: Linearity ``(λ1 - λ2) / λ1`` of a k-neighbourhood above which :func:`estimate_normals`
#: treats it as a thin branch (normal: from the local axis to the point).
LINE_NEIGHBOURHOOD = 0.6

#: Statistical outlier removal spares a point whose mean neighbour distance is at most
#: this many times the median of its neighbours' (a sparse but consistent region).
SOR_LOCAL_RATIO = 3.0
#: ... unless its mean neighbour distance is over this many times the cloud's median
#: (a sparse scatter of outliers is consistent with itself too).
SOR_MAX_SPARSITY = 30.0

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

#: Smallest eigenvalue of the mean ``n nᵀ`` of the normals around a point above which
#: its neighbourhood counts as foliage (0: normals perpendicular to one axis, as on any
#: cylinder or plane; 1/3: normals pointing every way).
LEAF_NORMAL_SPREAD = 0.12
#: Smallest neighbourhood radius of the leaf measure (m); it grows with the spacing.
LEAF_RADIUS_M = 0.16
#: Share of leaf-like points from which a cloud is reported as leaf-on.
LEAF_PRESENT_FRACTION = 0.25

#: Points processed at a time in neighbourhood computations (bounds temporary memory).
_CHUNK = 32768

#: Neighbours per point that :func:`prepare` finds once and keeps
#: (:attr:`PreparedCloud.neighbors`): the PCA's ``normals_neighbors`` (24 by default)
#: and the QSM's graph (``neighbors + 1``) and gap bridging (24) read them instead of
#: searching the cloud again.
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


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True, kw_only=True)
class PreparedCloud:
    """A cloud ready for reconstruction, in a local frame.

    Parameters
    ----------
    frame : LocalFrame
        Add ``frame.origin`` to local coordinates to get the input's coordinates.
    points : (n, 3) float64
        Local coordinates (m).
    weights : (n,) int64
        Input points each point stands for (points merged into its voxel).
    normals : (n, 3) float64 or None
        Unit normals oriented outward, or ``None`` when not asked for.
    spacing_m : float
        Median nearest-neighbour distance of ``points`` (m).
    steps : list of dict
        One record per step: ``step``, ``points_before``, ``points_after``, ``removed``,
        ``params`` (including ``enabled``).
    leaves_present : bool
        ``leaf_fraction >= LEAF_PRESENT_FRACTION``.
    leaf_fraction : float
        Share of input points (weighted) in foliage-like neighbourhoods, see
        :func:`leaf_measure`.
    n_input : int
        Points in the input cloud.
    params : PrepareParams
        The parameters used.
    neighbors : (n, k) int32 or None
        Each point's ``k = max(KEPT_NEIGHBORS, normals_neighbors)`` nearest points (itself
        first), sorted by distance (:func:`nearest_neighbors`); the QSM builds its graph
        from them instead of searching the cloud again. ``None`` on a cloud built by
        hand.
    foot : StemFoot or None
        The terrain under the tree and the stem's foot on it
        (:func:`~treesim.reconstruct.foot.find_foot`); the QSM grows from it.
    """

    frame: LocalFrame
    points: np.ndarray
    weights: np.ndarray
    normals: np.ndarray | None
    spacing_m: float
    steps: list[dict[str, Any]]
    leaves_present: bool
    leaf_fraction: float
    n_input: int
    params: PrepareParams = field(default_factory=PrepareParams)
    neighbors: np.ndarray | None = field(default=None, repr=False, compare=False)
    foot: StemFoot | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def global_points(self) -> np.ndarray:
        """The points in the input's coordinates, (n, 3) float64."""
        return self.frame.to_global(self.points)

    def summary(self) -> dict[str, Any]:
        """A JSON-ready description: counts, spacing, leaves, steps and parameters."""
        return {
            "n_input": self.n_input,
            "n_points": len(self.points),
            "spacing_m": self.spacing_m,
            "leaves_present": self.leaves_present,
            "leaf_fraction": self.leaf_fraction,
            "frame_origin": list(self.frame.origin),
            "steps": [dict(s) for s in self.steps],
            "params": asdict(self.params),
        }


# --------------------------------------------------------------------------- validation


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


# --------------------------------------------------------------------------- downsampling


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


def statistical_outliers(
    points: np.ndarray,
    neighbors: int,
    std_ratio: float,
    *,
    workers: int = 1,
    knn: np.ndarray | None = None,
) -> np.ndarray:
    """Boolean mask of the points statistical outlier removal keeps.

    A point is an outlier when its mean distance to its ``neighbors`` nearest neighbours
    exceeds the mean of that figure over the cloud by more than ``std_ratio`` standard
    deviations (PCL's and Open3D's rule) **and** is more than ``SOR_LOCAL_RATIO`` times
    the median of the same figure over those neighbours or ``SOR_MAX_SPARSITY`` times its
    median over the cloud. The second test keeps regions that are sparse but consistent,
    such as the top of a tall tree far from the scanner: the global rule alone cut 0.9 m
    off a 17 m simulated aspen, the combined rule 0.15 m.

    Parameters
    ----------
    points : (n, 3) float
    neighbors : int
        k nearest neighbours (the point itself excluded).
    std_ratio : float
        Threshold in standard deviations above the mean of the mean neighbour distance.
    knn : (n, >= neighbors + 1) int, optional
        Each point's nearest points, itself first (:func:`nearest_neighbors`), to use
        instead of a search.

    Returns
    -------
    keep : (n,) bool
    """
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n <= neighbors:
        return np.ones(n, dtype=bool)
    # in chunks, neighbours kept as int32: the (n, k) float64 distances and int64
    # indices of one query over the whole cloud were 0.4 GB at 1.4 M points
    reuse = knn is not None and knn.shape[1] > neighbors
    tree = None if reuse else cKDTree(pts)
    mean_d = np.empty(n)
    nb = knn[:, 1 : neighbors + 1] if reuse else np.empty((n, neighbors), _index_dtype(n))  # type: ignore[index]
    for lo in range(0, n, _CHUNK):
        if reuse:
            j = knn[lo : lo + _CHUNK, : neighbors + 1]  # type: ignore[index]
            i = np.arange(lo, lo + len(j))[:, None]
            d = _lengths(pts, i, j)
        else:
            d, j = tree.query(pts[lo : lo + _CHUNK], k=neighbors + 1, workers=workers)  # type: ignore[union-attr]
        mean_d[lo : lo + len(d)] = d[:, 1:].mean(axis=1)
        if not reuse:
            nb[lo : lo + len(d)] = j[:, 1:]
    del tree
    threshold = mean_d.mean() + std_ratio * mean_d.std()
    local = np.empty(n)
    for lo in range(0, n, _CHUNK):
        local[lo : lo + _CHUNK] = np.median(mean_d[nb[lo : lo + _CHUNK]], axis=1)
    sparse_but_consistent = (mean_d <= SOR_LOCAL_RATIO * local) & (
        mean_d <= SOR_MAX_SPARSITY * np.median(mean_d)
    )
    return (mean_d <= threshold) | sparse_but_consistent


# --------------------------------------------------------------------------- local PCA


def _local_frames(
    points: np.ndarray,
    k: int,
    tree: cKDTree | None = None,
    rows: np.ndarray | None = None,
    *,
    workers: int = 1,
    neighbors: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """PCA of the k-neighbourhoods of the points ``rows`` (default all); ``neighbors``
    (from :func:`nearest_neighbors`, at least ``k`` columns) saves the search.

    Returns
    -------
    evals : (m, 3) float64
        Eigenvalues of the neighbourhood covariance, ascending.
    normals : (m, 3) float64
        Unit eigenvectors of the smallest eigenvalue (unoriented).
    centroids : (m, 3) float64
        Neighbourhood centroids.
    major : (m, 3) float64
        Unit eigenvectors of the largest eigenvalue (the local line direction).
    """
    pts = np.asarray(points, dtype=np.float64)
    k = int(min(k, len(pts)))
    reuse = neighbors is not None and neighbors.shape[1] >= k
    tree = cKDTree(pts) if tree is None and not reuse else tree
    rows = np.arange(len(pts)) if rows is None else np.asarray(rows)
    m = len(rows)
    evals, normals = np.empty((m, 3)), np.empty((m, 3))
    centroids, major = np.empty((m, 3)), np.empty((m, 3))
    for lo in range(0, m, _CHUNK):
        r = rows[lo : lo + _CHUNK]
        if reuse:
            idx = neighbors[r, :k]  # type: ignore[index]
        else:
            _, idx = tree.query(pts[r], k=k, workers=workers)
        nb = pts[idx.reshape(len(r), k)]
        c = nb.mean(axis=1)
        nb = nb - c[:, None, :]
        cov = np.einsum("nki,nkj->nij", nb, nb) / k
        w, v = np.linalg.eigh(cov)
        sl = slice(lo, lo + len(r))
        evals[sl], normals[sl], centroids[sl], major[sl] = w, v[:, :, 0], c, v[:, :, 2]
    return evals, normals, centroids, major


def _local_pca(
    points: np.ndarray,
    k: int,
    tree: cKDTree | None = None,
    rows: np.ndarray | None = None,
    *,
    workers: int = 1,
    neighbors: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and unit smallest-eigenvalue vectors of k-neighbourhoods."""
    evals, normals, _, _ = _local_frames(
        points, k, tree, rows, workers=workers, neighbors=neighbors
    )
    return evals, normals


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(norm > 0, norm, 1.0)


# --------------------------------------------------------------------------- normals


def _centroid_offsets(
    points: np.ndarray,
    normals: np.ndarray,
    radius_m: float,
    rows: np.ndarray,
    *,
    workers: int = 1,
) -> np.ndarray:
    """Offset along the normal of the centroid of the points within ``radius_m``, per row.

    The centroid is taken over a support grid of voxels ``radius_m / 3`` (weighted by
    their counts, at most the 32 nearest within the radius), so the cost stays linear
    whatever the radius. Returns the offsets (m) of the points ``rows``.
    """
    sup, cnt, _ = voxel_downsample(points, radius_m / 3.0)
    tree = cKDTree(sup)
    k = int(min(32, len(sup)))
    off = np.empty(len(rows))
    cnt_f = np.append(cnt.astype(np.float64), 0.0)
    sup_x = np.vstack([sup, np.zeros((1, 3))])
    for lo in range(0, len(rows), _CHUNK):
        r = rows[lo : lo + _CHUNK]
        p = points[r]
        _, j = tree.query(p, k=k, distance_upper_bound=radius_m, workers=workers)
        j = j.reshape(len(p), k)
        w = cnt_f[j]  # the index len(sup) marks "none" and has weight 0
        c = np.einsum("nk,nkd->nd", w, sup_x[j]) / w.sum(axis=1, keepdims=True)
        off[lo : lo + len(p)] = np.einsum("nd,nd->n", c - p, normals[r])
    return off


def estimate_normals(
    points: np.ndarray,
    k: int = 24,
    *,
    axis_points: np.ndarray | None = None,
    spacing_m: float | None = None,
    workers: int = 1,
) -> np.ndarray:
    """PCA normals oriented outward, for tree surfaces.

    The direction is the smallest principal axis of the ``k`` nearest neighbours, except
    on thin branches: where the neighbourhood is a line (linearity at least
    ``LINE_NEIGHBOURHOOD``) that axis points anywhere around the branch, and the normal is
    instead the direction from the neighbourhood's axis (its centroid and major axis) to
    the point, which is outward by construction. The sign elsewhere:

    * with ``axis_points`` (points on the skeleton, e.g. a QSM's cylinder axes): away from
      the nearest axis point, which is exact wherever the skeleton is right;
    * otherwise away from the centroid of a larger neighbourhood, which lies on the
      concave (inner) side of a surface: inside a branch near its axis. Four radii are
      tried, ``R = max(2 cm, 6 × spacing)``, ``3R``, ``9R`` and ``27R``; each point takes
      the smallest whose centroid offset along the normal is at least 10 % of the radius
      (a clear answer), or else the radius with the clearest answer. Points whose
      answer stays ambiguous (offset under 2 % of the radius: flat patches) then take the
      sign their confident neighbours agree on, a few sweeps over the k-neighbour graph.

    Parameters
    ----------
    points : (n, 3) float
        Local coordinates (m).
    k : int
        Neighbours for the PCA.
    axis_points : (m, 3) float, optional
        Skeleton points in the same coordinates.
    spacing_m : float, optional
        Median point spacing; computed when not given.
    workers : int
        Threads for the neighbour searches.

    Returns
    -------
    normals : (n, 3) float64
        Unit vectors.
    """
    normals, _, _ = _estimate_normals(
        points, k, axis_points=axis_points, spacing_m=spacing_m, workers=workers
    )
    return normals


def _estimate_normals(
    points: np.ndarray,
    k: int = 24,
    *,
    axis_points: np.ndarray | None = None,
    spacing_m: float | None = None,
    workers: int = 1,
    tree: cKDTree | None = None,
    neighbors: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`estimate_normals`, also returning the k-neighbourhood eigenvalues (ascending)
    and the plain (unoriented) PCA normals; ``tree`` and ``neighbors`` (built on
    ``points``) save searches."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 3:
        raise EmptyInputError(f"normals need at least 3 points, got {len(pts)}")
    if int(k) != k or k < 3:
        raise InvalidParameterError(f"k must be an integer >= 3, got {k}")
    tree = cKDTree(pts) if tree is None else tree
    evals, normals, centroids, major = _local_frames(
        pts, int(k), tree, workers=workers, neighbors=neighbors
    )
    pca_normals = normals.copy()
    if axis_points is not None:
        axis = np.asarray(axis_points, dtype=np.float64).reshape(-1, 3)
        if len(axis) == 0 or not np.isfinite(axis).all():
            raise InvalidParameterError("axis_points must be a non-empty finite (m, 3) array")
        _, j = cKDTree(axis).query(pts, workers=workers)
        s = np.einsum("nd,nd->n", pts - axis[j], normals)
        return normals * np.where(s < 0, -1.0, 1.0)[:, None], evals, normals

    spacing = (
        point_spacing(pts, distinct=False, tree=tree, workers=workers)
        if spacing_m is None
        else float(spacing_m)
    )
    base = max(0.02, 6.0 * spacing)
    score = np.full(len(pts), -1.0)
    sign = np.ones(len(pts))
    settled = np.zeros(len(pts), dtype=bool)

    # Thin branches: the neighbourhood is a line and its PCA normal points anywhere
    # around it. The direction from the neighbourhood's axis (through its centroid, along
    # its major axis) to the point is the outward normal, sign included.
    radial = pts - centroids
    radial -= np.einsum("nd,nd->n", radial, major)[:, None] * major
    r_len = np.linalg.norm(radial, axis=1)
    l1 = np.maximum(evals[:, 2], 1e-300)
    linear = ((evals[:, 2] - evals[:, 1]) / l1 >= LINE_NEIGHBOURHOOD) & (
        r_len > 0.3 * np.sqrt(np.maximum(evals[:, 1], 0.0))
    )
    normals[linear] = radial[linear] / r_len[linear, None]
    score[linear] = 1.0
    settled |= linear
    for radius in (base, 3.0 * base, 9.0 * base, 27.0 * base):
        rows = np.flatnonzero(~settled)
        if len(rows) == 0:
            break
        off = _centroid_offsets(pts, normals, radius, rows, workers=workers)
        s = np.abs(off) / radius
        take = s > score[rows]
        score[rows[take]] = s[take]
        sign[rows[take]] = np.where(off[take] > 0, -1.0, 1.0)
        settled[rows] = s >= 0.10
    normals = normals * sign[:, None]

    # Ambiguous points follow their confident neighbours.
    unsure = score < 0.02
    if unsure.any() and (~unsure).any():
        kk = int(min(k, len(pts)))
        rows = np.flatnonzero(unsure)
        if neighbors is not None and neighbors.shape[1] >= kk:
            nb = neighbors[rows, :kk]
        else:
            _, nb = tree.query(pts[rows], k=kk, workers=workers)
            nb = nb.reshape(len(rows), kk)
        conf = np.where(unsure, 0.0, score)
        for _ in range(8):
            agree = np.einsum("nkd,nd->nk", normals[nb], normals[rows])
            vote = (conf[nb] * agree).sum(axis=1)
            flip = vote < 0
            normals[rows[flip]] *= -1.0
            # A point that now agrees with a confident neighbourhood passes its sign on.
            conf[rows] = np.maximum(conf[rows], 0.5 * np.abs(vote) / kk)
            if not flip.any():
                break
    return normals, evals, pca_normals


# --------------------------------------------------------------------------- ground


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


# --------------------------------------------------------------------------- leaves


def leaf_measure(
    points: np.ndarray,
    normals: np.ndarray,
    spacing_m: float,
    weights: np.ndarray | None = None,
    *,
    evals: np.ndarray | None = None,
    workers: int = 1,
) -> tuple[float, np.ndarray]:
    """Share of points in foliage-like neighbourhoods.

    Wood is made of cylinders: within ~10 cm of any point of a stem, a branch, or a twig
    the (unoriented) normals are all nearly perpendicular to one axis, even where PCA
    normals are noisy, so the mean of ``n nᵀ`` over the neighbourhood has a smallest
    eigenvalue near 0 (plane: 0, 0, 1; cylinder: 0, ½, ½). Leaves and needles point every
    way: the smallest eigenvalue approaches 1/3. A point is leaf-like where it exceeds
    ``LEAF_NORMAL_SPREAD``. Neighbourhoods have radius ``max(8 cm, 8 × spacing)``,
    computed on a grid of a third of that (linear cost); those with fewer than 10 points
    count as wood. With ``evals`` (the k-neighbourhood eigenvalues, ascending) each normal
    is weighted by ``1 - 3 λ3 / (λ1 + λ2 + λ3)``, so scanner noise (neighbourhoods that
    are balls, not surfaces) does not pass for foliage. Junctions of branches add a few
    per cent on leaf-off trees.

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float
        Unit normals, sign irrelevant.
    spacing_m : float
    weights : (n,) float, optional
        Input points each point stands for.

    Returns
    -------
    leaf_fraction : float
        Weighted share of leaf-like points.
    leaf_like : (n,) bool
    """
    pts = np.asarray(points, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, dtype=np.float64)
    if len(pts) == 0:
        return 0.0, np.zeros(0, dtype=bool)
    radius = max(LEAF_RADIUS_M, 8.0 * spacing_m)
    cent, cnt, inv = voxel_downsample(pts, radius / 3.0)
    m = len(cent)
    if evals is None:
        trust = np.ones(len(pts))
    else:  # 1 on a clean surface or line, 0 where the neighbourhood is a ball of noise
        ev = np.clip(np.asarray(evals, dtype=np.float64), 0.0, None)
        trust = np.clip(1.0 - 3.0 * ev[:, 0] / np.maximum(ev.sum(axis=1), 1e-300), 0.0, 1.0)
    # per cell, the sum of trust-weighted n nᵀ: six distinct entries, each one bincount
    # over (n,) temporaries (the (n, 3, 3) products took 0.5 GB at 1.4 M points)
    sums = np.empty((m, 9))
    for a in range(3):
        for b in range(a, 3):
            col = np.bincount(inv, weights=nrm[:, a] * nrm[:, b] * trust, minlength=m)
            sums[:, 3 * a + b] = sums[:, 3 * b + a] = col
    counts = np.bincount(inv, weights=trust, minlength=m)
    sums = np.vstack([sums, np.zeros((1, 9))])
    counts = np.append(counts, 0.0)
    k = int(min(64, m))
    _, j = cKDTree(cent).query(cent, k=k, distance_upper_bound=radius, workers=workers)
    j = j.reshape(m, k)
    total, num = np.empty((m, 9)), np.empty(m)
    for lo in range(0, m, _CHUNK // 8):  # (cells, k, 9) gathers, a chunk at a time
        jj = j[lo : lo + _CHUNK // 8]
        total[lo : lo + len(jj)] = sums[jj].sum(axis=1)
        num[lo : lo + len(jj)] = counts[jj].sum(axis=1)
    mat = (total / np.maximum(num, 1.0)[:, None]).reshape(m, 3, 3)
    spread = np.linalg.eigvalsh(mat)[:, 0]
    leafy_cell = (spread > LEAF_NORMAL_SPREAD) & (num >= 10)
    leaf_like = leafy_cell[inv]
    frac = float(w[leaf_like].sum() / w.sum()) if w.sum() > 0 else 0.0
    return frac, leaf_like


# --------------------------------------------------------------------------- prepare


def _kept(
    pts: np.ndarray,
    weights: np.ndarray,
    neighbors: np.ndarray,
    keep: np.ndarray,
    k: int,
    tree: cKDTree | None,
    workers: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points, weights and ``k`` nearest kept neighbours (:func:`_neighbors_of_kept`)
    of the points ``keep`` marks; ``tree`` is ``pts``'s (built here when None)."""
    tree = cKDTree(pts) if tree is None else tree
    kept_neighbors = _neighbors_of_kept(pts, neighbors, keep, k, tree, workers=workers)
    return pts[keep], weights[keep], kept_neighbors


def _step(name: str, before: int, after: int, **params: Any) -> dict[str, Any]:
    return {
        "step": name,
        "points_before": int(before),
        "points_after": int(after),
        "removed": int(before - after),
        "params": params,
    }


def prepare(
    cloud: Cloud | np.ndarray, params: PrepareParams | None = None, *, normals: bool = True
) -> PreparedCloud:
    """Check, thin and clean a tree cloud, and estimate its normals.

    Parameters
    ----------
    cloud : Cloud or (n, 3) float
        Points in the input's coordinates (georeferenced or not).
    params : PrepareParams, optional
        Defaults: 5 mm voxels, outlier removal (16 neighbours, 2.5 σ), no ground
        removal, normals from 24 neighbours.
    normals : bool
        Orient normals (``params.normals_neighbors``); ``False`` leaves
        :attr:`PreparedCloud.normals` ``None`` for a method that does not use them (the
        QSM), which saves their orientation, the dearest step on large clouds. The leaf
        measure is the same either way: it reads the unoriented PCA.

    Returns
    -------
    PreparedCloud
        See the module docstring for the steps.

    Raises
    ------
    EmptyInputError, InvalidGeometryError
        From :func:`validate_tree_cloud`, or when cleaning leaves too few points.
    """
    params = PrepareParams() if params is None else params
    w = int(params.threads)
    pts_in = _as_points(cloud)
    validate_tree_cloud(pts_in, min_points=params.min_points)
    frame = LocalFrame.around(pts_in)
    local = frame.to_local(pts_in)
    steps: list[dict[str, Any]] = []

    # 1. voxel downsampling / deduplication
    n0 = len(local)
    pts, weights, _ = voxel_downsample(local, params.voxel_size_m)
    if params.voxel_size_m is None:
        steps.append(_step("deduplicate", n0, len(pts), enabled=True, voxel_size_m=None))
    else:
        steps.append(
            _step("voxel_downsample", n0, len(pts), enabled=True, voxel_size_m=params.voxel_size_m)
        )

    # 2. statistical outlier removal; one neighbour search of the thinned cloud serves
    # it, the spacing, the PCA and the QSM's graph (see step 4)
    n1 = len(pts)
    k_pca = params.normals_neighbors or 24
    k_keep = max(KEPT_NEIGHBORS, k_pca)
    tree = cKDTree(pts)
    k_search = k_keep if params.sor_std_ratio is None else max(k_keep, params.sor_neighbors + 1)
    neighbors, nearest = nearest_neighbors(pts, k_search, tree, workers=w)
    if params.sor_std_ratio is not None:
        keep = statistical_outliers(
            pts, params.sor_neighbors, params.sor_std_ratio, workers=w, knn=neighbors
        )
        if not keep.all():
            pts, weights, neighbors = _kept(pts, weights, neighbors, keep, k_keep, tree, w)
            nearest, tree = None, None
    neighbors = neighbors[:, :k_keep]
    steps.append(
        _step(
            "outlier_removal",
            n1,
            len(pts),
            enabled=params.sor_std_ratio is not None,
            neighbors=params.sor_neighbors,
            std_ratio=params.sor_std_ratio,
        )
    )

    # 3. ground removal, the stem's foot, understory (treesim.reconstruct.foot)
    n2 = len(pts)
    ground_info: dict[str, Any] = {}
    plane = None
    if params.remove_ground:
        tree = cKDTree(pts) if tree is None else tree
        spacing = _spacing(pts, neighbors, nearest)
        ground, ground_info = find_ground(
            pts, params.ground_tolerance_m, spacing, tree=tree, workers=w
        )
        if ground_info.get("detected"):
            plane = tuple(ground_info["plane"])
        if ground.any():
            pts, weights, neighbors = _kept(pts, weights, neighbors, ~ground, k_keep, tree, w)
            nearest, tree = None, None
    steps.append(
        _step(
            "ground_removal",
            n2,
            len(pts),
            enabled=params.remove_ground,
            tolerance_m=params.ground_tolerance_m,
            **ground_info,
        )
    )
    n3 = len(pts)
    spacing = _spacing(pts, neighbors, nearest)
    foot = find_foot(pts, neighbors, spacing, plane=plane, weights=weights)
    under_info: dict[str, Any] = {}
    if params.remove_understory and foot is not None and plane is not None:
        under, under_info = understory(pts, neighbors, spacing, foot)
        if under.any() and (~under).sum() >= max(10, params.normals_neighbors or 0):
            pts, weights, neighbors = _kept(pts, weights, neighbors, ~under, k_keep, tree, w)
            nearest, tree = None, None
    steps.append(
        _step(
            "understory_removal",
            n3,
            len(pts),
            enabled=params.remove_understory and plane is not None,
            foot=None if foot is None else foot.to_dict(),
            **under_info,
        )
    )
    if len(pts) < max(10, params.normals_neighbors or 0):
        raise EmptyInputError(
            f"only {len(pts)} points are left after cleaning ({n0} in the input); "
            "use a smaller voxel_size_m, a larger sor_std_ratio, or turn ground removal off"
        )
    validate_tree_cloud(pts, min_points=min(params.min_points, len(pts)))

    # 4. spacing (median nearest-neighbour distance), normals and leaves, from the
    # neighbours found in step 2
    spacing = _spacing(pts, neighbors, nearest)
    oriented: np.ndarray | None = None
    if params.normals_neighbors is not None and normals:
        oriented, evals, unoriented = _estimate_normals(
            pts, k_pca, spacing_m=spacing, workers=w, tree=tree, neighbors=neighbors
        )
    else:
        evals, unoriented = _local_pca(pts, k_pca, tree, workers=w, neighbors=neighbors)
    del tree
    leaf_fraction, _ = leaf_measure(pts, unoriented, spacing, weights, evals=evals, workers=w)
    return PreparedCloud(
        frame=frame,
        points=pts,
        weights=weights,
        normals=oriented,
        neighbors=neighbors,
        spacing_m=spacing,
        steps=steps,
        leaves_present=leaf_fraction >= LEAF_PRESENT_FRACTION,
        leaf_fraction=leaf_fraction,
        n_input=n0,
        params=params,
        foot=foot,
    )
