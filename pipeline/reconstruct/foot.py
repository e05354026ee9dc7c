"""The tree's foot: the terrain under a single-tree cloud, the stem's base on it, and the
understory around it.

Single-tree clouds are usually cut from plot scans (a column around the stem): ground,
litter, shrubs and fallen wood come with them. A QSM grown from the lowest point of such
a cloud starts in the litter, runs along the ground to the stem and models that run with
the whole tree's pipe-model radius (a spruce cut from a plot: a 51 cm "stem" along the
ground holding 1.7 m³ of its 2.0 m³). So before the skeleton:

1. :func:`~treesim.reconstruct.preprocess.find_ground` fits the terrain plane (a robust
   lowest-surface fit; ground only where it covers a wide, filled area, so the cut end of
   a stem with no ground under it stays) and the points on it are removed;
2. :func:`find_foot` finds the stem in the band 0.1-1.5 m above that terrain (the
   component of the band's neighbour graph that spans the band with the most points)
   and its axis: the foot is where the axis meets the terrain;
3. :func:`understory` marks what grows from or lies on the ground but is not the stem:
   points within ``NEAR_GROUND_M`` of the terrain away from the stem's foot (litter,
   fallen wood, the feet of shrubs), then every piece no longer connected to the stem
   whose lowest point is within ``UNDERSTORY_FOOT_M`` of the terrain (a shrub, a
   sapling). A branch of the tree that the scan saw apart from the rest starts in the
   crown, not on the ground, and stays (the QSM bridges it).

The QSM then grows from the foot (its geodesic sources are the lowest points near the
foot's axis, not the cloud's lowest point) and starts its stem on the terrain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

__all__ = ["NEAR_GROUND_M", "UNDERSTORY_FOOT_M", "StemFoot", "find_foot", "understory"]

#: Height band above the terrain (m) searched for the stem: above the litter and the
#: root flare, below most first branches. Short trees use the lower 40 % of their height.
FOOT_BAND_M = (0.1, 1.5)
#: Height above the terrain (m) under which points away from the stem's foot are litter,
#: fallen wood or the feet of shrubs.
NEAR_GROUND_M = 0.3
#: A piece not connected to the stem whose lowest point is this close to the terrain (m)
#: grows from the ground: understory.
UNDERSTORY_FOOT_M = 0.5
#: Shortest link (m) that joins points into pieces when looking for understory: a shrub
#: scanned sparser than the stem still holds together as one piece.
UNDERSTORY_LINK_M = 0.05
#: Horizontal room around the stem's foot kept at any height (m), beyond 1.5 stem radii
#: (root flare, buttresses).
FOOT_MARGIN_M = 0.1
#: Thickness of the layers whose centroids give the stem's axis (m).
AXIS_LAYER_M = 0.1


def _height(
    points: np.ndarray, plane: tuple[float, float, float, float] | None, base_z_m: float
) -> np.ndarray:
    """Height of ``points`` (n, 3) above ``plane`` (vertically), or above ``base_z_m``."""
    p = np.asarray(points, dtype=np.float64)
    if plane is None:
        return p[:, 2] - base_z_m
    a, b, c, d = plane
    return p[:, 2] + (a * p[:, 0] + b * p[:, 1] + d) / c


@dataclass(frozen=True)
class StemFoot:
    """Where the stem meets the ground, in the prepared cloud's local frame.

    Attributes
    ----------
    plane : (4,) float or None
        The terrain ``a x + b y + c z + d = 0`` (unit normal, ``c > 0``); ``None`` when the
        cloud has no ground (heights are then taken above its lowest point).
    base_z_m : float
        z of the lowest point when there is no plane (the reference of heights).
    xy : (2,) float
        The axis at the terrain (the foot's centre).
    z_m : float
        Terrain height at the foot (the stem's base).
    direction : (3,) float
        Unit direction of the stem's axis near the ground (z up).
    radius_m : float
        Half the stem's width across its axis in the band (a rough size, for margins).
    """

    plane: tuple[float, float, float, float] | None
    base_z_m: float
    xy: np.ndarray
    z_m: float
    direction: np.ndarray
    radius_m: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """Height of ``points`` (n, 3) above the terrain (m), vertically."""
        return _height(points, self.plane, self.base_z_m)

    def axis_distance(self, points: np.ndarray) -> np.ndarray:
        """Horizontal distance of ``points`` from the stem's axis at their own height (m)."""
        p = np.asarray(points, dtype=np.float64)
        dz = p[:, 2] - self.z_m
        t = self.direction[:2] / max(float(self.direction[2]), 0.2)
        at = self.xy[None, :] + dz[:, None] * t[None, :]
        return np.linalg.norm(p[:, :2] - at, axis=1)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready description (local coordinates)."""
        return {
            "terrain_plane": None if self.plane is None else [float(v) for v in self.plane],
            "foot_xy_m": [float(v) for v in self.xy],
            "foot_z_m": float(self.z_m),
            "axis": [float(v) for v in self.direction],
            "stem_radius_m": float(self.radius_m),
        }


def _pieces(
    neighbors: np.ndarray, points: np.ndarray, keep: np.ndarray, link_m: float
) -> np.ndarray:
    """Each point's connected piece of the graph of neighbour pairs within ``link_m``
    whose ends are both kept (a removed point is a piece of its own)."""
    n = len(points)
    k = neighbors.shape[1]
    rows = np.repeat(np.arange(n), k - 1)
    cols = neighbors[:, 1:].ravel().astype(np.int64)
    ok = keep[rows] & keep[cols]
    rows, cols = rows[ok], cols[ok]
    near = np.linalg.norm(points[rows] - points[cols], axis=1) <= link_m
    g = sparse.coo_matrix((np.ones(int(near.sum())), (rows[near], cols[near])), shape=(n, n))
    return connected_components(g.tocsr(), directed=False)[1]


def find_foot(
    points: np.ndarray,
    neighbors: np.ndarray,
    spacing_m: float,
    *,
    plane: tuple[float, float, float, float] | None = None,
    weights: np.ndarray | None = None,
) -> StemFoot | None:
    """Find the stem's foot: its axis in the band ``FOOT_BAND_M`` above the terrain.

    Parameters
    ----------
    points : (n, 3) float
        Local coordinates, z up (m), ground removed.
    neighbors : (n, k) int
        Each point's nearest points, itself first.
    spacing_m : float
        Median point spacing (m).
    plane : (4,) float, optional
        The terrain plane (:func:`~treesim.reconstruct.preprocess.find_ground`); without
        it heights are taken above the lowest point.
    weights : (n,) float, optional
        Points each point stands for.

    Returns
    -------
    StemFoot or None
        None when the band holds too few points to tell a stem.
    """
    p = np.asarray(points, dtype=np.float64)
    w = np.ones(len(p)) if weights is None else np.asarray(weights, dtype=np.float64)
    z0 = float(p[:, 2].min())
    hag = _height(p, plane, z0)
    top = float(np.max(hag))
    lo, hi = FOOT_BAND_M
    hi = min(hi, 0.4 * top)
    lo = min(lo, 0.25 * hi) if plane is not None else 0.0
    band = (hag >= lo) & (hag <= hi)
    if band.sum() < 20:
        return None
    link = max(4.0 * spacing_m, 0.02)
    lab = _pieces(neighbors, p, band, link)
    lab_b = lab[band]
    wb, hb = w[band], hag[band]
    comps, inv = np.unique(lab_b, return_inverse=True)
    weight = np.bincount(inv, weights=wb)
    span = np.zeros(len(comps))
    np.maximum.at(span, inv, hb)
    low = np.full(len(comps), np.inf)
    np.minimum.at(low, inv, hb)
    span = np.clip(span - low, 0.0, None)
    score = weight * (span / max(hi - lo, 1e-9)) ** 2
    best = int(np.argmax(score))
    sel = np.flatnonzero(band)[inv == best]
    q, wq, hq = p[sel], w[sel], hag[sel]
    if len(q) < 10:
        return None
    layer = np.floor(hq / AXIS_LAYER_M).astype(np.int64)
    layers, li = np.unique(layer, return_inverse=True)
    lw = np.bincount(li, weights=wq)
    cen = np.stack([np.bincount(li, weights=wq * q[:, j]) / lw for j in range(3)], axis=1)
    if len(layers) >= 3:  # axis: weighted line through the layer centroids, x(z), y(z)
        zc = cen[:, 2]
        a = np.column_stack([zc - zc.mean(), np.ones(len(zc))])
        sw = np.sqrt(lw)
        coef, *_ = np.linalg.lstsq(a * sw[:, None], cen[:, :2] * sw[:, None], rcond=None)
        slope = coef[0]
        if np.hypot(*slope) > 1.0:  # more than 45° from the vertical: not a stem foot
            slope = np.zeros(2)
        direction = np.array([slope[0], slope[1], 1.0])
    else:
        direction = np.array([0.0, 0.0, 1.0])
    direction /= np.linalg.norm(direction)
    # the foot: the axis followed down to the terrain (or the lowest band height)
    c0 = cen[int(np.argmin(cen[:, 2]))]
    h0 = float(_height(c0[None, :], plane, z0)[0])
    t = direction[:2] / direction[2]
    if plane is None:
        dz = -h0
    else:  # along the axis until the height above the plane is 0
        a_, b_, c_, _ = plane
        slope_h = 1.0 + (a_ * t[0] + b_ * t[1]) / c_
        dz = -h0 / slope_h if abs(slope_h) > 1e-6 else -h0
    foot = c0 + dz * np.array([t[0], t[1], 1.0])
    rel = q[:, :2] - (foot[:2][None, :] + (q[:, 2] - foot[2])[:, None] * t[None, :])
    radius = float(np.percentile(np.linalg.norm(rel, axis=1), 90))
    return StemFoot(plane, z0, foot[:2].copy(), float(foot[2]), direction, radius)


def understory(
    points: np.ndarray,
    neighbors: np.ndarray,
    spacing_m: float,
    foot: StemFoot,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Points that grow from or lie on the ground but are not the tree.

    Parameters
    ----------
    points : (n, 3) float
        Local coordinates (m), ground removed.
    neighbors : (n, k) int
        Each point's nearest points, itself first.
    spacing_m : float
        Median point spacing (m).
    foot : StemFoot
        The stem's foot (:func:`find_foot`) with a terrain plane.

    Returns
    -------
    remove : (n,) bool
    info : dict
        ``near_ground`` and ``pieces`` (points removed by each rule), ``pieces_removed``.
    """
    p = np.asarray(points, dtype=np.float64)
    hag = foot.height(p)
    room = 1.5 * foot.radius_m + FOOT_MARGIN_M
    near = (hag < NEAR_GROUND_M) & (foot.axis_distance(p) > room)
    keep = ~near
    lab = _pieces(neighbors, p, keep, max(8.0 * spacing_m, UNDERSTORY_LINK_M))
    # the stem's piece: the one holding most of the points near the axis in the foot band
    lo, hi = FOOT_BAND_M
    at_foot = keep & (hag >= lo) & (hag <= hi) & (foot.axis_distance(p) <= room)
    if not at_foot.any():
        at_foot = keep & (foot.axis_distance(p) <= room)
    if not at_foot.any():
        return near, {"near_ground": int(near.sum()), "pieces": 0, "pieces_removed": 0}
    stem_label = int(np.argmax(np.bincount(lab[at_foot])))
    low = np.full(int(lab.max()) + 1, np.inf)
    np.minimum.at(low, lab[keep], hag[keep])
    grounded = low < UNDERSTORY_FOOT_M
    grounded[stem_label] = False
    pieces = keep & grounded[lab]
    remove = near | pieces
    info = {
        "near_ground": int(near.sum()),
        "pieces": int(pieces.sum()),
        "pieces_removed": int(len(np.unique(lab[pieces]))),
        "near_ground_m": NEAR_GROUND_M,
        "understory_foot_m": UNDERSTORY_FOOT_M,
    }
    return remove, info
