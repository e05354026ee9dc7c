"""Local PCA of k-neighbourhoods and outward normals for tree surfaces
(:func:`estimate_normals`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import EmptyInputError, InvalidParameterError
from ..geometry import point_spacing
from .neighbours import _CHUNK
from .thin import voxel_downsample

__all__ = ["estimate_normals"]

#: Linearity ``(λ1 - λ2) / λ1`` of a k-neighbourhood above which :func:`estimate_normals`
#: treats it as a thin branch (normal: from the local axis to the point).
LINE_NEIGHBOURHOOD = 0.6


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
    (from :func:`~treesim.reconstruct.neighbours.nearest_neighbors`, at least ``k``
    columns) saves the search.

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
