"""A leaf layer from foliage points: small square leaves where a field cloud's leaves were.

:func:`leaf_layer` turns the points a wood/leaf separation called ``leaf`` into leaf quads
(two triangles each) so that a reconstructed leaf-on tree can be scanned leaf-on:

* **Density**: the points are binned in voxels of ``voxel_m`` (25 cm, within the
  0.1-0.5 m of the voxel leaf-area methods, e.g. Hosoi & Omasa 2006). The leaf area a
  voxel's points saw is their count times the area each point stands for, the square of
  the cloud's point spacing; the voxel gets ``round(area / leaf_area)`` leaves (at least
  one). Leaves hidden from every station are not counted: the layer holds the leaf area
  the scan saw, a lower bound of the tree's.
* **Size**: squares of side ``side_m`` (default 5 cm: 25 cm², a typical broadleaf leaf;
  10-50 cm² for birch to oak).
* **Position and orientation**: each leaf is centred on one of its voxel's points (drawn
  with a fixed seed) and lies in the plane fitted to that point's ``k`` nearest leaf
  points (PCA normal), turned about the normal by a uniformly drawn angle.

Deterministic for a given seed. Everything is float64 in the caller's coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ModelError

__all__ = ["LeafLayer", "leaf_layer"]


@dataclass(frozen=True)
class LeafLayer:
    """Leaf quads as triangles.

    Attributes
    ----------
    vertices : (4 m, 3) float64
    faces : (2 m, 3) int64
    n_leaves : int
    leaf_area_m2 : float
        One side of every leaf.
    """

    vertices: np.ndarray
    faces: np.ndarray
    n_leaves: int
    leaf_area_m2: float


def _empty() -> LeafLayer:
    return LeafLayer(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0, 0.0)


def leaf_layer(
    points: np.ndarray,
    *,
    spacing_m: float,
    side_m: float = 0.05,
    voxel_m: float = 0.25,
    k: int = 16,
    seed: int = 0,
) -> LeafLayer:
    """Leaf quads in the volume of ``points`` (see the module docstring).

    Parameters
    ----------
    points : (n, 3) float
        The foliage points.
    spacing_m : float
        The cloud's point spacing (m): each point stands for ``spacing_m²`` of leaf.
    side_m : float
        Side of a leaf square (m).
    voxel_m : float
        Voxel edge of the leaf density (m).
    k : int
        Neighbours of the plane fit that orients a leaf.
    seed : int

    Returns
    -------
    LeafLayer
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    for name, v in (("spacing_m", spacing_m), ("side_m", side_m), ("voxel_m", voxel_m)):
        if not np.isfinite(v) or v <= 0:
            raise ModelError(f"leaf_layer: {name} must be > 0, got {v!r}")
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ModelError(f"leaf_layer: points must have shape (n, 3), got {pts.shape}")
    if len(pts) < 3:
        return _empty()
    rng = np.random.default_rng(seed)
    keys = np.floor((pts - pts.min(axis=0)) / voxel_m).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    per_voxel = np.maximum(1, np.rint(counts * spacing_m**2 / side_m**2)).astype(np.int64)
    per_voxel = np.minimum(per_voxel, counts)
    # draw per_voxel points of each voxel: a random key per point, the lowest keys win
    order = np.lexsort((rng.random(len(pts)), inv))
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(len(pts)) - first[inv[order]]
    centres_idx = order[rank < per_voxel[inv[order]]]
    centres = pts[centres_idx]
    kk = int(min(k, len(pts)))
    _, nb = cKDTree(pts).query(centres, k=kk)
    q = pts[nb.reshape(len(centres), kk)]
    q = q - q.mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))
    normal, a = vecs[:, :, 0], vecs[:, :, 2]
    b = np.cross(normal, a)
    turn = rng.uniform(0.0, 2.0 * np.pi, len(centres))
    u = np.cos(turn)[:, None] * a + np.sin(turn)[:, None] * b
    v = np.cross(normal, u)
    h = side_m / 2.0
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * h
    verts = (
        centres[:, None, :]
        + corners[None, :, 0, None] * u[:, None, :]
        + corners[None, :, 1, None] * v[:, None, :]
    )
    m = len(centres)
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)[None] + 4 * np.arange(m)[:, None, None]
    return LeafLayer(verts.reshape(-1, 3), faces.reshape(-1, 3), m, float(m * side_m**2))
