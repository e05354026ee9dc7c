"""The trees of a field plot cloud: stems, their DBH, and which points belong to which tree.

A TLS plot cloud with each point's height above ground (``hag``, from :mod:`treesim.plot.dtm`)
becomes a list of :class:`Stem` and a tree label per point, in the manner of
dendromatics/3DFin (Cabo et al. 2018, Laino et al. 2024), worked in a local frame (the
cloud's lowest corner subtracted; clouds may carry 5e6 m projected-CRS offsets):

1. **Stripe** (:func:`detect_stems`): the points between ``stripe_low_m`` and
   ``stripe_high_m`` above the ground (0.7-3.5 m: above most understory, below most
   crowns), thinned to one point per ``thin_m`` voxel.
2. **Verticality**: 1 - |n_z| of each point's local PCA normal (``pgeof``, radius
   ``verticality_radius_m``); a stem's bark has a horizontal normal (verticality near 1),
   ground and leaves do not. Points below ``verticality_min`` (3DFin's 0.7) are dropped.
3. **Clusters**: the vertical points in ``cluster_voxel_m`` voxels, voxels joined to their
   neighbours (vertically over gaps up to ``cluster_gap_m``, occlusion), connected
   components; a cluster is a stem candidate when it occupies ``min_cover_share`` of the
   stripe's 0.2 m height bins.
4. **Axis**: a circle per ``slab_step_m`` slab up the stripe (RANSAC of 3-point circles
   and a robust geometric least-squares refine, :func:`treesim.reconstruct.qsm.fit_circle`;
   the refine weights each point by the inverse of its 10° sector's count, so a one-sided
   arc seen from one station is not pulled by its densest part); a straight axis through
   the circle centres (lean), circles off it or of another radius (a branch, a shrub)
   dropped. Fewer than ``min_axis_circles`` consistent circles: not a stem.
5. **DBH**: a circle fitted to every stripe point within reach of the axis in the slab
   ``dbh_height_m`` ± ``dbh_half_m`` (widened up to ``dbh_max_half_m`` when sparse);
   radius outside [``min_radius_m``, ``max_radius_m``] or far from the axis circles:
   not a stem.
6. **Duplicates**: stems whose circles overlap (two clusters of one stem, a fork below
   1.3 m) are one stem: the one with more points is kept.

:func:`segment_trees` then labels every point with its tree by multi-source shortest paths
over a voxel graph from the stems' own voxels (edges that go sideways cost more, so touching
crowns split near the right place), and :func:`tree_heights` gives each tree's height.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ..errors import InputFormatError, InvalidParameterError
from ..reconstruct.qsm import CircleFit, _refine_circle, fit_circle

__all__ = [
    "SIDEWAYS_FACTOR",
    "Stem",
    "StemParams",
    "detect_stems",
    "segment_trees",
    "tree_heights",
]

#: In :func:`segment_trees` a graph edge's horizontal part counts this many times its length:
#: a path up a stem and out along a branch costs less than one across to a neighbour's crown.
SIDEWAYS_FACTOR = 2.0
#: Points lower than this above the ground (m) are left out of the tree graph (the ground,
#: litter); a stem's own foot below it is labelled by its distance to the stem's axis.
MIN_HAG_M = 0.3
#: Points lower than this above the ground (m) ...
LOW_HAG_M = 2.0
#: ... and farther than this from their stem's axis in xy (m) are understory, not the tree.
LOW_REACH_M = 1.5
#: Graph edges join voxels whose centres are at most this many voxel sizes apart.
LINK_VOXELS = 1.8
#: A part of the canopy no stem reaches through the graph (a leader or a branch tip seen
#: in pieces, with gaps wider than the links) goes to the tree whose voxels are nearest,
#: within this distance (m, horizontal parts counted ``sideways_factor`` times), when it
#: lies wholly above :data:`LOW_HAG_M`: sparse tops were left out, and the twins of a
#: generated plot stood 1-5 m short of their trees.
FRAGMENT_REACH_M = 1.0
#: Rounds of joining fragments (a fragment joined in one round can reach the next).
FRAGMENT_ROUNDS = 8
#: A tree's height is its highest point with at least this many of its points ...
TOP_SUPPORT = 3
#: ... at most this far below it (m): isolated points (a bird, noise) are not the top.
TOP_GAP_M = 0.5


@dataclass(frozen=True)
class StemParams:
    """Thresholds of :func:`detect_stems` (lengths in metres, angles in degrees).

    Attributes
    ----------
    stripe_low_m, stripe_high_m : float
        The stripe of heights above ground searched for stems (3DFin: 0.7-3.5 m).
    thin_m : float
        The stripe keeps one point per voxel this wide before its features are computed.
    verticality_radius_m : float
        Radius of the neighbourhood whose PCA normal gives a point's verticality.
    verticality_min : float
        Points less vertical than this (1 - |n_z|; 1 on bark, 0 on the ground) are dropped.
    max_neighbours : int
        At most this many neighbours enter a point's PCA.
    cluster_voxel_m : float
        Voxel size of the clustering of vertical points.
    cluster_gap_m : float
        Vertical gap (occlusion) a cluster bridges.
    min_cover_share : float
        Share of the stripe's 0.2 m height bins a cluster must occupy to be a candidate.
    min_cluster_points : int
        Smaller clusters are not candidates.
    slab_step_m, slab_half_m : float
        Axis slabs: one every ``slab_step_m`` up the stripe, ``2 * slab_half_m`` thick.
    min_axis_circles : int
        A stem needs at least this many slab circles on one straight axis.
    max_axis_offset_m : float
        A slab circle whose centre is farther off the axis than this (or half its radius,
        the larger) is not the stem's.
    max_radius_change : float
        A slab circle whose radius differs from the median of the slabs by more than this
        share (plus ``circle_band_m``) is not the stem's.
    dbh_height_m : float
        Height above ground of the diameter at breast height (1.3 m).
    dbh_half_m, dbh_max_half_m : float
        Half-thickness of the DBH slab, and how far it may widen when sparse.
    min_slab_points : int
        A slab circle needs at least this many points.
    circle_band_m : float
        Smallest inlier band of the circle fits (about 3 times the range noise).
    min_radius_m, max_radius_m : float
        Plausible stem radii at 1.3 m.
    min_arc_deg : float
        The breast-height circle must be seen on at least this arc (10° sectors): one
        station sees 150-180° of a stem; less is a branch or a stem cut by the plot edge.
    max_lean_deg : float
        Steeper axes are not stems (a leaning branch, a fallen log).
    seed : int
        Seed of the RANSAC samples (results are reproducible).

    Examples
    --------
    >>> StemParams(stripe_low_m=1.0).stripe_high_m
    3.5
    """

    stripe_low_m: float = 0.7
    stripe_high_m: float = 3.5
    thin_m: float = 0.01
    verticality_radius_m: float = 0.1
    verticality_min: float = 0.7
    max_neighbours: int = 50
    cluster_voxel_m: float = 0.05
    cluster_gap_m: float = 0.25
    min_cover_share: float = 0.5
    min_cluster_points: int = 30
    slab_step_m: float = 0.3
    slab_half_m: float = 0.1
    min_axis_circles: int = 3
    max_axis_offset_m: float = 0.05
    max_radius_change: float = 0.3
    dbh_height_m: float = 1.3
    dbh_half_m: float = 0.1
    dbh_max_half_m: float = 0.4
    min_slab_points: int = 20
    circle_band_m: float = 0.015
    min_radius_m: float = 0.025
    max_radius_m: float = 1.5
    min_arc_deg: float = 120.0
    max_lean_deg: float = 35.0
    seed: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, int | float) or not math.isfinite(v):
                raise InvalidParameterError(f"stem parameter {f.name} must be a number, got {v!r}")
            if f.name != "seed" and v <= 0:
                raise InvalidParameterError(f"stem parameter {f.name} must be positive, got {v}")
        if self.stripe_high_m <= self.stripe_low_m:
            raise InvalidParameterError(
                f"the stem stripe's top ({self.stripe_high_m} m) must be above its bottom "
                f"({self.stripe_low_m} m)"
            )
        if not self.stripe_low_m <= self.dbh_height_m <= self.stripe_high_m:
            raise InvalidParameterError(
                f"breast height {self.dbh_height_m} m must lie in the stem stripe "
                f"{self.stripe_low_m}-{self.stripe_high_m} m"
            )
        if self.min_radius_m >= self.max_radius_m:
            raise InvalidParameterError("min_radius_m must be below max_radius_m")
        if self.verticality_min >= 1.0 or self.min_cover_share > 1.0:
            raise InvalidParameterError("verticality_min and min_cover_share are shares (< 1)")


@dataclass(frozen=True)
class Stem:
    """A tree stem found in a plot cloud (input coordinates).

    Attributes
    ----------
    x_m, y_m : float
        The centre of the stem's circle at breast height.
    base_xyz_m : tuple of float
        Where the stem's axis meets the ground.
    dbh_m : float
        Diameter at breast height (of the circle fitted to the slab at 1.3 m).
    circle_rms_m : float
        RMS distance of the slab's inlier points from that circle.
    arc_deg : float
        How much of the circle the slab's points cover (10° sectors).
    n_points : int
        Points of the slab the circle was fitted to.
    lean_deg : float
        Angle of the stem's axis from the vertical.
    """

    x_m: float
    y_m: float
    base_xyz_m: tuple[float, float, float]
    dbh_m: float
    circle_rms_m: float
    arc_deg: float
    n_points: int
    lean_deg: float


#: The narrowest residual scatter a breast-height circle's band is made from (m).
MIN_SCATTER_M = 0.002


@dataclass
class _Axis:
    """A stem's axis in the local frame: centre at breast height, xy per m of height."""

    c13: np.ndarray
    slope: np.ndarray
    radius: float
    n_circles: int


def _check_inputs(points, hag) -> tuple[np.ndarray, np.ndarray]:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputFormatError(f"the points must be an (n, 3) array of x, y, z; got {pts.shape}")
    h = np.asarray(hag, dtype=np.float64)
    if h.shape != (len(pts),):
        raise InputFormatError(
            f"one height above ground per point is needed: {len(pts)} points, {h.size} heights"
        )
    if not (np.isfinite(pts).all() and np.isfinite(h).all()):
        raise InputFormatError("the cloud or its heights above ground hold NaN or infinite values")
    return pts, h


def _thin(local: np.ndarray, cell_m: float) -> np.ndarray:
    """Indices of one point per ``cell_m`` voxel (the first in input order)."""
    key = np.floor(local / cell_m).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return np.sort(first)


def _verticality(local: np.ndarray, radius_m: float, max_nn: int) -> np.ndarray:
    """1 - |n_z| of each point's PCA normal over its ``radius_m`` neighbourhood."""
    import pgeof

    xyz = np.ascontiguousarray(local - local.mean(axis=0), dtype=np.float64)
    f = pgeof.compute_features_selected(
        xyz, float(radius_m), int(max_nn), [pgeof.EFeatureID.Verticality]
    )
    v = np.asarray(f, dtype=np.float64).reshape(len(xyz), -1)[:, 0]
    return np.nan_to_num(v, nan=0.0)


def _cluster(local: np.ndarray, voxel_m: float, gap_m: float) -> np.ndarray:
    """Cluster label per point: voxels joined to their neighbours (vertically over gaps)."""
    key = np.floor(local / voxel_m).astype(np.int64)
    vox, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    # z shrunk so a vertical gap of gap_m is as near as one voxel sideways
    squeeze = max(1.0, gap_m / voxel_m)
    tree = cKDTree(vox * np.array([1.0, 1.0, 1.0 / squeeze]))
    pairs = tree.query_pairs(1.75, output_type="ndarray")
    n = len(vox)
    g = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    return lab[inv]


def _sector_weights(q: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Weights equalising the points' share per 10° sector around ``centre``; a sector
    with few points (a quarter of the median sector's, at least 3) counts as that many, so
    that a stray point or two (a branch base, a leaf) cannot weigh as much as a whole
    sector of stem."""
    ang = np.arctan2(q[:, 1] - centre[1], q[:, 0] - centre[0])
    sec = np.floor((ang + np.pi) / (2 * np.pi) * 36).astype(int) % 36
    count = np.bincount(sec, minlength=36)
    floor = max(3.0, 0.25 * float(np.median(count[count > 0])))
    return 1.0 / np.maximum(count[sec], floor)


def _circle(q: np.ndarray, p: StemParams, rng: np.random.Generator):
    """A robust circle (local-frame centre) or None: once unweighted, once sector-weighted."""
    if len(q) < p.min_slab_points:
        return None
    if len(q) > 4000:
        q = q[np.sort(rng.choice(len(q), 4000, replace=False))]
    o = q.mean(axis=0)
    # two RANSAC draws, the better kept (96 triples each: sparse slabs with outliers)
    tries = [fit_circle(q - o, np.ones(len(q)), rng, p.circle_band_m) for _ in range(2)]
    tries = [c for c in tries if c is not None]
    if not tries:
        return None
    c = max(tries, key=lambda c: (c.inlier_share, -c.rms))
    near = np.abs(np.linalg.norm(q - o - c.centre, axis=1) - c.radius) < max(
        3 * p.circle_band_m, 0.1 * c.radius
    )
    if near.sum() >= p.min_slab_points:
        qn = q[near] - o
        c2 = fit_circle(qn, _sector_weights(qn, c.centre), rng, p.circle_band_m)
        if c2 is not None and abs(c2.radius - c.radius) < max(p.circle_band_m, 0.2 * c.radius):
            c = c2
    c.centre = c.centre + o
    return c


def _axis(lp: np.ndarray, lh: np.ndarray, p: StemParams, rng: np.random.Generator):
    """A straight axis through the cluster's slab circles, or None when it is not a stem."""
    rows = []
    h = p.stripe_low_m + p.slab_half_m
    while h <= p.stripe_high_m - p.slab_half_m + 1e-9:
        s = np.abs(lh - h) <= p.slab_half_m
        c = _circle(lp[s, :2], p, rng)
        if c is not None and p.min_radius_m <= c.radius <= p.max_radius_m:
            rows.append((float(lh[s].mean()), c.centre[0], c.centre[1], c.radius))
        h += p.slab_step_m
    a = np.array(rows).reshape(-1, 4)
    if len(a) < p.min_axis_circles:
        return None
    coef = _theil_sen(a[:, 0] - p.dbh_height_m, a[:, 1:3])
    keep = np.zeros(len(a), bool)
    for _ in range(4):
        pred = coef[0] + np.outer(a[:, 0] - p.dbh_height_m, coef[1])
        off = np.linalg.norm(a[:, 1:3] - pred, axis=1)
        r_med = float(np.median(a[keep, 3] if keep.sum() else a[:, 3]))
        new = (off <= max(p.max_axis_offset_m, 0.5 * r_med)) & (
            np.abs(a[:, 3] - r_med) <= p.max_radius_change * r_med + p.circle_band_m
        )
        if new.sum() < p.min_axis_circles:
            return None
        if (new == keep).all():
            break
        keep = new
        design = np.column_stack([np.ones(keep.sum()), a[keep, 0] - p.dbh_height_m])
        coef, *_ = np.linalg.lstsq(design, a[keep, 1:3], rcond=None)
    return _Axis(coef[0], coef[1], float(np.median(a[keep, 3])), int(keep.sum()))


def _theil_sen(h: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """A robust straight line xy = c + s * h: the median of pairwise slopes, then of
    intercepts (rows: c, s)."""
    i, j = np.triu_indices(len(h), 1)
    dh = h[j] - h[i]
    ok = np.abs(dh) > 1e-6
    slope = np.median((xy[j][ok] - xy[i][ok]) / dh[ok, None], axis=0) if ok.any() else np.zeros(2)
    return np.vstack([np.median(xy - np.outer(h, slope), axis=0), slope])


def _circle_from_prior(q: np.ndarray, centre: np.ndarray, radius: float, p: StemParams):
    """The circle near a prior one (the axis'): points within a shrinking band of it,
    weighted per 10° sector, fitted geometrically; None when too few points or no fit."""
    x = np.array([centre[0], centre[1], radius], dtype=np.float64)
    band = p.circle_band_m
    inl = np.zeros(len(q), bool)
    scatter = band
    # a wide band first (the prior may be off), then bands from the residuals' own scatter
    # (a fixed band of a few cm takes in the branch bases around a thin conifer stem and
    # pulls its circle outwards)
    for share, times in ((0.3, 3.0), (0.1, 2.5), (0.0, 2.5), (0.0, 2.5)):
        tol = max(share * x[2], times * scatter)
        inl = np.abs(np.linalg.norm(q - x[:2], axis=1) - x[2]) < tol
        if inl.sum() < p.min_slab_points:
            return None
        o = q[inl].mean(axis=0)
        qi = q[inl] - o
        x0 = np.array([x[0] - o[0], x[1] - o[1], x[2]])
        xi = _refine_circle(qi, _sector_weights(qi, x0[:2]), x0, band)
        if not np.isfinite(xi).all() or xi[2] <= 0:
            return None
        x = np.array([xi[0] + o[0], xi[1] + o[1], xi[2]])
        res = np.linalg.norm(q[inl] - x[:2], axis=1) - x[2]
        scatter = min(band, max(MIN_SCATTER_M, 1.4826 * float(np.median(np.abs(res)))))
    d = np.abs(np.linalg.norm(q - x[:2], axis=1) - x[2])
    inl = d < 2.5 * scatter
    if inl.sum() < p.min_slab_points:
        return None
    ang = np.arctan2(q[inl, 1] - x[1], q[inl, 0] - x[0])
    sectors = np.unique(np.floor((ang + np.pi) / (2 * np.pi) * 36).astype(int) % 36)
    return CircleFit(
        centre=x[:2].copy(),
        radius=float(x[2]),
        rms=float(np.sqrt(np.mean(d[inl] ** 2))),
        coverage_deg=10.0 * len(sectors),
        inlier_share=float(inl.mean()),
        scatter=float(1.4826 * np.median(np.abs(d - np.median(d)))),
    )


def _dbh(
    ax: _Axis,
    stripe: np.ndarray,
    stripe_h: np.ndarray,
    kd: cKDTree,
    p: StemParams,
    rng: np.random.Generator,
):
    """The circle of the slab at breast height around the axis, its points; or None."""
    reach = ax.radius + max(0.1, 0.5 * ax.radius)
    idx = np.asarray(kd.query_ball_point(ax.c13, reach), dtype=np.int64)
    if len(idx) == 0:
        return None
    half = p.dbh_half_m
    # z of the axis at breast height: the ground under the axis (a plane through the
    # ground under the points near it) + 1.3 m; a point's height along the axis is its z
    # above that (its own hag differs by the ground's slope across the stem)
    z13 = _ground_at(stripe[idx], stripe_h[idx], ax.c13) + p.dbh_height_m
    while True:
        s = idx[np.abs(stripe_h[idx] - p.dbh_height_m) <= half]
        # each point moved to breast height along the axis (a leaning stem's slab)
        q = stripe[s, :2] - np.outer(stripe[s, 2] - z13, ax.slope)
        if len(s) >= 3 * p.min_slab_points or half >= p.dbh_max_half_m:
            break
        half = min(p.dbh_max_half_m, half * 2)
    c = _circle_from_prior(q, ax.c13, ax.radius, p)
    if c is None:
        c = _circle(q, p, rng)
    if c is None or not p.min_radius_m <= c.radius <= p.max_radius_m:
        return None
    if c.coverage_deg < p.min_arc_deg:
        return None
    if np.linalg.norm(c.centre - ax.c13) > max(p.max_axis_offset_m, 0.5 * ax.radius):
        return None
    if abs(c.radius - ax.radius) > p.max_radius_change * ax.radius + p.circle_band_m:
        return None
    return c, s


def _ground_at(g: np.ndarray, h: np.ndarray, xy: np.ndarray) -> float:
    """The ground's z at ``xy``: a plane through the ground under points ``g`` (z - hag)."""
    gz = g[:, 2] - h
    design = np.column_stack([np.ones(len(g)), g[:, 0] - xy[0], g[:, 1] - xy[1]])
    coef, *_ = np.linalg.lstsq(design, gz, rcond=None)
    if not np.isfinite(coef).all() or np.abs(coef[1:]).max() > 2.0:  # not a ground (> 63°)
        return float(np.median(gz))
    return float(coef[0])


def _stem(ax: _Axis, c, s, stripe: np.ndarray, stripe_h: np.ndarray, origin, p: StemParams):
    """The :class:`Stem` of an axis and its breast-height circle (input coordinates)."""
    base_xy = c.centre - ax.slope * p.dbh_height_m
    base_z = _ground_at(stripe[s], stripe_h[s], base_xy)
    lean = math.degrees(math.atan(float(np.linalg.norm(ax.slope))))
    return Stem(
        x_m=float(c.centre[0] + origin[0]),
        y_m=float(c.centre[1] + origin[1]),
        base_xyz_m=(
            float(base_xy[0] + origin[0]),
            float(base_xy[1] + origin[1]),
            float(base_z + origin[2]),
        ),
        dbh_m=2.0 * float(c.radius),
        circle_rms_m=float(c.rms),
        arc_deg=float(c.coverage_deg),
        n_points=len(s),
        lean_deg=lean,
    )


def _merge(stems: list[Stem]) -> list[Stem]:
    """One stem per set of overlapping circles (the one with most points kept)."""
    kept: list[Stem] = []
    for st in sorted(stems, key=lambda s: (-s.n_points, s.x_m, s.y_m)):
        if all(
            math.hypot(st.x_m - k.x_m, st.y_m - k.y_m) >= 0.5 * (st.dbh_m + k.dbh_m) for k in kept
        ):
            kept.append(st)
    return kept


def _candidates(local: np.ndarray, h: np.ndarray, p: StemParams) -> list[np.ndarray]:
    """Indices (into ``local``) of each cluster of vertical points that covers the stripe."""
    sub = _thin(local, p.thin_m)
    if len(sub) < p.min_cluster_points:
        return []
    vert = _verticality(local[sub], p.verticality_radius_m, p.max_neighbours)
    cand = sub[vert >= p.verticality_min]
    if len(cand) < p.min_cluster_points:
        return []
    lab = _cluster(local[cand], p.cluster_voxel_m, p.cluster_gap_m)
    order = np.argsort(lab, kind="stable")
    bounds = np.flatnonzero(np.diff(lab[order])) + 1
    n_bins = max(1, int(round((p.stripe_high_m - p.stripe_low_m) / 0.2)))
    out = []
    for grp in np.split(order, bounds):
        if len(grp) < p.min_cluster_points:
            continue
        gi = cand[grp]
        b = np.clip(((h[gi] - p.stripe_low_m) / 0.2).astype(int), 0, n_bins - 1)
        if len(np.unique(b)) >= p.min_cover_share * n_bins:
            out.append(gi)
    return out


def detect_stems(points, hag, *, params: StemParams | None = None) -> tuple[list[Stem], list[str]]:
    """Find the tree stems of a plot cloud and measure their DBH.

    Parameters
    ----------
    points : (N, 3) array_like of float
        The plot cloud in input coordinates (any offset).
    hag : (N,) array_like of float
        Each point's height above the ground (m).
    params : StemParams, optional
        Thresholds; the defaults suit TLS plots in metres.

    Returns
    -------
    stems : list of Stem
        Sorted by x, then y.
    warnings : list of str
        Doubts: no stem found, stems seen on a short arc, strongly leaning stems.

    Raises
    ------
    InputFormatError
        ``points`` is not (N, 3), ``hag`` not one per point, or either holds NaN.

    Examples
    --------
    >>> stems, warnings = detect_stems(cloud.points, hag)  # doctest: +SKIP
    >>> [round(s.dbh_m, 2) for s in stems]  # doctest: +SKIP
    [0.23, 0.31]
    """
    p = params if params is not None else StemParams()
    pts, h = _check_inputs(points, hag)
    in_stripe = (h >= p.stripe_low_m) & (h <= p.stripe_high_m)
    if not in_stripe.any():
        return [], [
            f"no points {p.stripe_low_m}-{p.stripe_high_m} m above the ground: no stems can be "
            "found (are the heights above ground right?)"
        ]
    origin = pts[in_stripe].min(axis=0)
    stripe = pts[in_stripe] - origin
    stripe_h = h[in_stripe]
    rng = np.random.default_rng(p.seed)
    kd = cKDTree(stripe[:, :2])
    stems = []
    for gi in _candidates(stripe, stripe_h, p):
        ax = _axis(stripe[gi], stripe_h[gi], p, rng)
        if ax is None or math.degrees(math.atan(np.linalg.norm(ax.slope))) > p.max_lean_deg:
            continue
        got = _dbh(ax, stripe, stripe_h, kd, p, rng)
        if got is not None:
            stems.append(_stem(ax, got[0], got[1], stripe, stripe_h, origin, p))
    stems = sorted(_merge(stems), key=lambda s: (s.x_m, s.y_m))
    return stems, _warnings(stems, p)


def _warnings(stems: list[Stem], p: StemParams) -> list[str]:
    if not stems:
        return [
            f"no tree stems found: no vertical, round structure {p.stripe_low_m}-"
            f"{p.stripe_high_m} m above the ground"
        ]
    out = []
    short = [s for s in stems if s.arc_deg < 90.0]
    if short:
        out.append(
            f"{len(short)} of {len(stems)} stems are seen on less than 90° of their "
            "circumference at 1.3 m: their DBH is uncertain"
        )
    lean = [s for s in stems if s.lean_deg > 15.0]
    if lean:
        out.append(f"{len(lean)} stems lean more than 15°: check they are stems")
    return out


def _axes_local(stems: list[Stem], origin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each stem's base xy, xy per m of height above ground (local frame) and radius."""
    base = np.array([[s.base_xyz_m[0], s.base_xyz_m[1]] for s in stems]) - origin[:2]
    at13 = np.array([[s.x_m, s.y_m] for s in stems]) - origin[:2]
    return base, (at13 - base) / 1.3, np.array([0.5 * s.dbh_m for s in stems])


def _axis_distance(xy: np.ndarray, h: np.ndarray, k: np.ndarray, base, slope) -> np.ndarray:
    """xy distance of each point from stem k's axis at the point's height above ground."""
    return np.linalg.norm(xy - base[k] - slope[k] * h[:, None], axis=1)


def _voxel_graph(vox: np.ndarray, voxel_m: float, sideways: float) -> sparse.csr_matrix:
    """Voxels joined within :data:`LINK_VOXELS`, horizontal parts of edges ``sideways`` times."""
    pairs = cKDTree(vox).query_pairs(LINK_VOXELS, output_type="ndarray")
    d = (vox[pairs[:, 0]] - vox[pairs[:, 1]]).astype(np.float64)
    w = np.sqrt(sideways**2 * (d[:, 0] ** 2 + d[:, 1] ** 2) + d[:, 2] ** 2) * voxel_m
    n = len(vox)
    return sparse.coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()


def segment_trees(
    points,
    hag,
    stems: list[Stem],
    *,
    voxel_m: float = 0.1,
    ground=None,
    sideways_factor: float = SIDEWAYS_FACTOR,
) -> np.ndarray:
    """Label every point with its tree: 0 for none, k for ``stems[k - 1]``'s.

    The points higher than :data:`MIN_HAG_M` above the ground (and not ``ground``) are
    voxelised; voxels within :data:`LINK_VOXELS` voxel sizes are joined by edges whose
    horizontal part counts ``sideways_factor`` times; each voxel goes to the stem whose own
    voxels (those on its axis, up to 3 m) reach it by the shortest path. Voxels no stem
    reaches stay 0, and so do points lower than :data:`LOW_HAG_M` farther than
    :data:`LOW_REACH_M` from their stem's axis (understory beside a tree). A stem's foot
    below :data:`MIN_HAG_M` is labelled by its distance to the axis.

    Parameters
    ----------
    points : (N, 3) array_like of float
        The plot cloud in input coordinates.
    hag : (N,) array_like of float
        Heights above ground (m).
    stems : list of Stem
        From :func:`detect_stems`.
    voxel_m : float
        Voxel size of the graph (m).
    ground : (N,) array_like of bool, optional
        Ground points (never labelled).
    sideways_factor : float
        Cost of a horizontal step relative to a vertical one (>= 1).

    Returns
    -------
    (N,) int32 array
        Tree labels.

    Examples
    --------
    >>> labels = segment_trees(cloud.points, hag, stems, ground=ground)  # doctest: +SKIP
    >>> np.bincount(labels)[1:]  # points per tree  # doctest: +SKIP
    array([20816, 31450])
    """
    pts, h = _check_inputs(points, hag)
    if not voxel_m > 0 or not sideways_factor >= 1:
        raise InvalidParameterError(
            f"voxel_m must be positive and sideways_factor at least 1 (got {voxel_m}, "
            f"{sideways_factor})"
        )
    gmask = np.zeros(len(pts), bool) if ground is None else np.asarray(ground, dtype=bool)
    if gmask.shape != (len(pts),):
        raise InputFormatError(f"the ground mask has {gmask.size} values for {len(pts)} points")
    labels = np.zeros(len(pts), np.int32)
    use = np.flatnonzero(~gmask & (h >= MIN_HAG_M))
    if not stems or len(use) == 0:
        return labels
    origin = pts[use].min(axis=0)
    local = pts[use] - origin
    base, slope, radius = _axes_local(stems, origin)
    key = np.floor(local / voxel_m).astype(np.int64)
    vox, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    centre = (vox + 0.5) * voxel_m
    vh = np.bincount(inv, weights=h[use], minlength=len(vox)) / np.bincount(inv)
    seed_of = _seed_voxels(centre[:, :2], vh, base, slope, radius, voxel_m)
    seeds = np.flatnonzero(seed_of >= 0)
    if len(seeds) == 0:
        return labels
    graph = _voxel_graph(vox, voxel_m, float(sideways_factor))
    _, _, src = dijkstra(
        graph, directed=False, indices=seeds, min_only=True, return_predecessors=True
    )
    vlab = np.where(src >= 0, seed_of[np.maximum(src, 0)] + 1, 0).astype(np.int32)
    _join_fragments(vlab, graph, centre, vh, float(sideways_factor))
    lab = vlab[inv]
    low = (lab > 0) & (h[use] < LOW_HAG_M)
    li = np.flatnonzero(low)
    far = _axis_distance(local[li, :2], h[use][li], lab[li] - 1, base, slope) > LOW_REACH_M
    lab[li[far]] = 0
    labels[use] = lab
    _label_feet(labels, pts - origin, h, gmask, base, slope, radius)
    return labels


def _join_fragments(
    vlab: np.ndarray, graph: sparse.csr_matrix, centre: np.ndarray, vh: np.ndarray, sideways: float
) -> None:
    """Give the canopy's unreached components (in ``vlab``, in place) to the nearest
    tree (see :data:`FRAGMENT_REACH_M`), nearest first, over several rounds."""
    free = np.flatnonzero(vlab == 0)
    if len(free) == 0 or not (vlab > 0).any():
        return
    sub = graph[free][:, free]
    n_comp, comp = connected_components(sub, directed=False)
    low = np.full(n_comp, np.inf)
    np.minimum.at(low, comp, vh[free])
    keep = low[comp] >= LOW_HAG_M
    free, comp = free[keep], comp[keep]
    scale = np.array([sideways, sideways, 1.0])
    for _ in range(FRAGMENT_ROUNDS):
        if len(free) == 0:
            return
        owned = np.flatnonzero(vlab > 0)
        d, j = cKDTree(centre[owned] * scale).query(
            centre[free] * scale, distance_upper_bound=FRAGMENT_REACH_M
        )
        hit = np.isfinite(d)
        if not hit.any():
            return
        # each component takes the label of its voxel nearest to a tree
        best = np.full(comp.max() + 1, np.inf)
        np.minimum.at(best, comp[hit], d[hit])
        first = hit & (d == best[comp])
        label_of = np.zeros(comp.max() + 1, np.int32)
        label_of[comp[first]] = vlab[owned[j[first]]]
        joined = label_of[comp] > 0
        vlab[free[joined]] = label_of[comp[joined]]
        free, comp = free[~joined], comp[~joined]


def _nearest_axis(xy, h, base, slope, radius) -> tuple[np.ndarray, np.ndarray]:
    """The nearest stem (0-based) of each point by its axis at the point's height, and the
    xy distance from that stem's surface (of the few stems whose bases are nearest)."""
    k = min(4, len(base))
    _, near = cKDTree(base).query(xy, k=k)
    near = near.reshape(len(xy), k)
    axis_xy = base[near] + slope[near] * h[:, None, None]
    d = np.linalg.norm(xy[:, None, :] - axis_xy, axis=2) - radius[near]
    j = np.argmin(d, axis=1)
    rows = np.arange(len(xy))
    return near[rows, j], d[rows, j]


def _seed_voxels(cxy, vh, base, slope, radius, voxel_m) -> np.ndarray:
    """The stem (0-based) whose axis a voxel up to 3 m lies on, or -1."""
    seed_of = np.full(len(cxy), -1, np.int64)
    low = np.flatnonzero(vh <= 3.0)
    if len(low) == 0:
        return seed_of
    k, d = _nearest_axis(cxy[low], vh[low], base, slope, radius)
    ok = d <= voxel_m
    seed_of[low[ok]] = k[ok]
    return seed_of


def _label_feet(labels, local, h, gmask, base, slope, radius) -> None:
    """Points below :data:`MIN_HAG_M` on a stem's surface: that stem's."""
    foot = np.flatnonzero(~gmask & (h < MIN_HAG_M) & (h > -0.1))
    if len(foot) == 0:
        return
    k, d = _nearest_axis(local[foot, :2], h[foot], base, slope, radius)
    on = d <= 0.1 * radius[k] + 0.03
    labels[foot[on]] = k[on] + 1


def tree_heights(hag, labels, n: int) -> np.ndarray:
    """Each tree's height: its highest point above ground that is not isolated.

    The top is the highest point of the tree with at least :data:`TOP_SUPPORT` of the
    tree's points within :data:`TOP_GAP_M` below it (a stray point above the crown is not
    the top); a tree with fewer points takes its highest point.

    Parameters
    ----------
    hag : (N,) array_like of float
        Heights above ground (m).
    labels : (N,) array_like of int
        Tree labels from :func:`segment_trees` (0: no tree).
    n : int
        Number of trees (labels 1..n).

    Returns
    -------
    (n,) float64 array
        Heights (m); NaN for a tree without points.

    Examples
    --------
    >>> tree_heights([1.0, 10.0, 9.8, 9.7, 9.6, 30.0], [1, 1, 1, 1, 1, 1], 1).round(1)
    array([10.])
    """
    h = np.asarray(hag, dtype=np.float64).ravel()
    lab = np.asarray(labels).ravel()
    if lab.shape != h.shape:
        raise InputFormatError(f"{lab.size} labels for {h.size} heights")
    out = np.full(int(n), np.nan)
    sel = (lab >= 1) & (lab <= n)
    lab, h = lab[sel], h[sel]
    order = np.lexsort((-h, lab))
    lab, h = lab[order], h[order]
    starts = np.searchsorted(lab, np.arange(1, n + 1), side="left")
    ends = np.searchsorted(lab, np.arange(1, n + 1), side="right")
    for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
        if b == a:
            continue
        hs = h[a:b]  # descending
        if len(hs) <= TOP_SUPPORT:
            out[k] = hs[0]
            continue
        ok = hs[:-TOP_SUPPORT] - hs[TOP_SUPPORT:] <= TOP_GAP_M
        out[k] = hs[int(np.argmax(ok))] if ok.any() else hs[0]
    return out
