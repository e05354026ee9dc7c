"""Independent references from a single-tree cloud: ground under the stem, height, stem slabs.

Shared by ``tests/reconstruct/test_real_tree_accuracy.py`` and
``benchmarks/bench_real_trees.py``. It imports nothing from ``treesim.reconstruct`` (numpy
and scipy only, its own code), so it can judge the reconstruction without sharing its
mistakes.

The method, in four steps:

1. **The stem's axis near the foot.** Points between 0.5 m and 3 m above the cloud's low
   level are binned in 5 cm cells in plan; a stem occupies its cells at every 10 cm layer
   of that window, ground, litter, shrubs and clipped neighbours' branches at few. The
   cells occupied in at least 60 % of the layers the best cell reaches, and connected to
   it, give the axis (their centroid) and a first radius (their extent).
2. **The ground under the stem** is the lowest dense level near the axis (the first 2 cm
   bin holding a fifth of the median bin's count, so isolated points below the ground are
   skipped). Where the annulus around the stem has ground (at least eight 10 cm cells with
   points within 0.5 m of that level), a plane is fitted robustly to the cells' lowest
   points and evaluated at the axis (a slope is handled); else the base is that lowest
   dense level (the stem's foot). The top is the highest point with three neighbours within 0.3 m.
3. **Slabs.** At 1.3 m above the base and every ``step_m`` (0.5 m) up the stem, the
   points of a ``thickness_m`` (10 cm; 20 cm where that holds too few) horizontal slab
   within a window around the stem's predicted centre (the last clean slab's) are fitted
   with a circle: Kasa's algebraic fit to start, then geometric least squares
   (``scipy.optimize.least_squares``, Cauchy loss), refitted on the inliers. Per slab:
   diameter, centre, residual RMS, arc coverage (10° sectors holding an inlier), points,
   and a verdict: ``clean``, or ``sparse``/``ambiguous``/``forked`` with the reason. A
   second circle of at least a third the radius among the points the first leaves (a
   second stem) makes the slab ``forked``; the walk up the stem stops there, at the top
   of the cloud, or after three slabs in a row that are not clean.
4. **DBH** is the slab at 1.3 m; the **taper profile** is the clean slabs' diameters by
   height.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: Verdicts a slab can get.
VERDICTS = ("clean", "sparse", "ambiguous", "forked")

#: Fewest stem points a slab needs for a circle.
MIN_POINTS = 12
#: Arc coverage (degrees, 10° sectors) a clean slab needs; under ``SPARSE_COVERAGE_DEG``
#: the slab is ``sparse``.
CLEAN_COVERAGE_DEG = 120.0
SPARSE_COVERAGE_DEG = 90.0
#: Share of the window's points near the stem that must lie on the circle for ``clean``.
MIN_INLIER_SHARE = 0.5
#: Residual RMS a clean slab may have: ``max(RMS_FLOOR_M, RMS_REL * radius)``.
#: 0.2 r bounds the geometric fit's bias (about rms^2 / 2r) at 2 % of the radius.
RMS_FLOOR_M = 0.005
RMS_REL = 0.2
#: Standard error of the radius a clean slab may have, as a share of the radius (two
#: standard errors make the 3 % a DBH is held to).
MAX_SE_REL = 0.015


@dataclass(frozen=True)
class Circle:
    """A circle in plan: centre (m), radius (m), residual RMS of its inliers (m)."""

    cx_m: float
    cy_m: float
    radius_m: float
    rms_m: float
    inliers: np.ndarray = field(repr=False)
    coverage_deg: float = 0.0
    se_radius_m: float = float("inf")


@dataclass(frozen=True)
class Slab:
    """One horizontal slab's circle and verdict.

    Attributes
    ----------
    height_m : float
        Centre of the slab above the base, m.
    z_m : float
        Centre of the slab in the cloud's coordinates, m.
    thickness_m : float
    diameter_m : float or None
        The fitted circle's diameter (None where no circle could be fitted).
    centre_xy_m : (2,) float or None
    rms_m : float or None
        Residual RMS of the circle's inliers, m.
    coverage_deg : float
        Arc covered by the inliers (10° sectors holding at least one).
    n_points : int
        Inlier points on the circle.
    n_window : int
        Points of the slab inside the window around the predicted stem.
    verdict : str
        One of :data:`VERDICTS`.
    reason : str
        Why (empty for ``clean``).
    points_xy : (n, 2) float
        The slab's points near the stem (for pictures).
    inlier_mask : (n,) bool
        Which of ``points_xy`` are on the circle.
    """

    height_m: float
    z_m: float
    thickness_m: float
    diameter_m: float | None
    centre_xy_m: tuple[float, float] | None
    rms_m: float | None
    coverage_deg: float
    n_points: int
    n_window: int
    verdict: str
    reason: str
    points_xy: np.ndarray = field(repr=False)
    inlier_mask: np.ndarray = field(repr=False)

    @property
    def clean(self) -> bool:
        """True for a single stem with good coverage and residual."""
        return self.verdict == "clean"

    def describe(self) -> str:
        """One line: height, diameter, verdict and figures."""
        d = "-" if self.diameter_m is None else f"{self.diameter_m * 100:.1f} cm"
        rms = "-" if self.rms_m is None else f"{self.rms_m * 1000:.1f} mm"
        extra = f" ({self.reason})" if self.reason else ""
        return (
            f"{self.height_m:.2f} m: D {d}, {self.verdict}{extra}; rms {rms}, "
            f"coverage {self.coverage_deg:.0f} deg, {self.n_points} points"
        )


@dataclass(frozen=True)
class TreeReference:
    """The references of one tree.

    Attributes
    ----------
    base_z_m : float
        Ground (or, without ground, the stem's lowest dense level) under the stem, m.
    base_source : str
        ``"ground plane"`` or ``"stem foot"``.
    top_z_m : float
    height_m : float
        ``top_z_m - base_z_m``.
    axis_xy_m : (2,) float
        The stem's axis near the foot.
    dbh_slab : Slab
        The slab at 1.3 m.
    slabs : list of Slab
        Every slab, by height (1.3 m among them).
    """

    base_z_m: float
    base_source: str
    top_z_m: float
    height_m: float
    axis_xy_m: tuple[float, float]
    dbh_slab: Slab
    slabs: list[Slab]

    @property
    def dbh_m(self) -> float | None:
        """The 1.3 m slab's diameter where it is clean, else None."""
        return self.dbh_slab.diameter_m if self.dbh_slab.clean else None

    def taper(self) -> tuple[np.ndarray, np.ndarray]:
        """(heights above the base (m), diameters (m)) of the clean slabs, by height."""
        clean = [s for s in self.slabs if s.clean]
        h = np.array([s.height_m for s in clean], dtype=np.float64)
        d = np.array([s.diameter_m for s in clean], dtype=np.float64)
        return h, d


# ---------------------------------------------------------------------- circles


def kasa_circle(xy: np.ndarray) -> tuple[float, float, float]:
    """Algebraic (Kasa) circle through ``xy`` ((n, 2) m): (cx, cy, r) in m."""
    x, y = xy[:, 0], xy[:, 1]
    a = np.column_stack([x, y, np.ones_like(x)])
    b = x * x + y * y
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = sol[0] / 2.0, sol[1] / 2.0
    r2 = sol[2] + cx * cx + cy * cy
    return float(cx), float(cy), float(np.sqrt(max(r2, 1e-12)))


def coverage_deg(xy: np.ndarray, cx: float, cy: float, sector_deg: float = 10.0) -> float:
    """Arc (degrees) covered by ``xy`` around (cx, cy): sectors of ``sector_deg`` occupied."""
    if len(xy) == 0:
        return 0.0
    ang = np.degrees(np.arctan2(xy[:, 1] - cy, xy[:, 0] - cx)) % 360.0
    n = int(round(360.0 / sector_deg))
    occupied = np.unique(np.minimum((ang / sector_deg).astype(int), n - 1))
    return float(len(occupied) * sector_deg)


def fit_circle(
    xy: np.ndarray, *, start: tuple[float, float, float] | None = None, scale_m: float = 0.005
) -> Circle | None:
    """Robust circle fit: Kasa start, Cauchy-loss geometric least squares, inlier refit.

    Parameters
    ----------
    xy : (n, 2) float
        Points in plan, m.
    start : (cx, cy, r), optional
        Starting circle (Kasa's fit of ``xy`` when not given).
    scale_m : float
        Residual scale of the robust loss, m.

    Returns
    -------
    Circle or None
        None with fewer than 5 points or when the fit fails.
    """
    if len(xy) < 5:
        return None
    x0 = np.array(start if start is not None else kasa_circle(xy), dtype=np.float64)

    def resid(p: np.ndarray, pts: np.ndarray) -> np.ndarray:
        return np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1]) - p[2]

    try:
        sol = least_squares(resid, x0, args=(xy,), loss="cauchy", f_scale=scale_m)
        p = sol.x
        res = resid(p, xy)
        mad = 1.4826 * float(np.median(np.abs(res - np.median(res))))
        tol = max(3.0 * mad, scale_m)
        inl = np.abs(res) <= tol
        if inl.sum() >= 5:
            sol = least_squares(resid, p, args=(xy[inl],), loss="cauchy", f_scale=scale_m)
            p = sol.x
            res = resid(p, xy)
            inl = np.abs(res) <= tol
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(p)) or p[2] <= 0 or inl.sum() < 3:
        return None
    rms = float(np.sqrt(np.mean(res[inl] ** 2)))
    return Circle(
        se_radius_m=_radius_se(xy[inl], p, rms),
        cx_m=float(p[0]),
        cy_m=float(p[1]),
        radius_m=float(abs(p[2])),
        rms_m=rms,
        inliers=inl,
        coverage_deg=coverage_deg(xy[inl], p[0], p[1]),
    )


def _radius_se(xy: np.ndarray, p: np.ndarray, rms_m: float) -> float:
    """Standard error of the radius (m): ``rms^2 (J^T J)^-1`` of the geometric fit."""
    dx, dy = xy[:, 0] - p[0], xy[:, 1] - p[1]
    d = np.maximum(np.hypot(dx, dy), 1e-12)
    jac = np.column_stack([-dx / d, -dy / d, -np.ones(len(xy))])
    try:
        cov = rms_m**2 * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return float("inf")
    return float(np.sqrt(max(cov[2, 2], 0.0)))


def _clusters(xy: np.ndarray, eps_m: float) -> np.ndarray:
    """Connected components of points closer than ``eps_m`` (labels, (n,) int)."""
    if len(xy) == 0:
        return np.zeros(0, dtype=np.int64)
    tree = cKDTree(xy)
    graph = tree.sparse_distance_matrix(tree, eps_m, output_type="coo_matrix")
    _, labels = connected_components(graph, directed=False)
    return labels


# ---------------------------------------------------------------------- base, axis, top


def stem_axis_near_foot(points: np.ndarray, low_z_m: float) -> tuple[float, float, float]:
    """(x, y, radius) of the stem from vertical persistence 0.5-3 m above ``low_z_m``.

    Raises
    ------
    ValueError
        If no points lie in that window.
    """
    height = float(points[:, 2].max() - low_z_m)
    top = low_z_m + min(3.0, max(1.0, 0.3 * height))
    lo = low_z_m + min(0.5, 0.1 * height)
    sel = points[(points[:, 2] >= lo) & (points[:, 2] <= top)]
    if len(sel) < MIN_POINTS:
        raise ValueError(
            f"only {len(sel)} points between {lo - low_z_m:.1f} and {top - low_z_m:.1f} m above "
            "the cloud's low level: no stem to find"
        )
    cell = 0.05
    ij = np.floor(sel[:, :2] / cell).astype(np.int64)
    layer = np.floor((sel[:, 2] - lo) / 0.1).astype(np.int64)
    keys, inv = np.unique(ij, axis=0, return_inverse=True)
    inv = inv.ravel()
    pairs = np.unique(np.column_stack([inv, layer]), axis=0)
    layers = np.bincount(pairs[:, 0], minlength=len(keys))
    # ties broken by the layers a cell fills up to 3 m: a stem goes on above a shrub
    above = points[(points[:, 2] > top) & (points[:, 2] <= low_z_m + 3.0)]
    a_ij = np.floor(above[:, :2] / cell).astype(np.int64)
    a_layer = np.floor((above[:, 2] - lo) / 0.1).astype(np.int64)
    cell_of = {tuple(k): i for i, k in enumerate(keys.tolist())}
    a_cell = np.array([cell_of.get(tuple(k), -1) for k in a_ij.tolist()], dtype=np.int64)
    a_pairs = np.unique(np.column_stack([a_cell, a_layer])[a_cell >= 0], axis=0)
    more = np.bincount(a_pairs[:, 0], minlength=len(keys)) if len(a_pairs) else 0 * layers
    best = int(np.lexsort((-more, -layers))[0])
    strong = np.flatnonzero(layers >= 0.5 * layers[best])
    # the strong cells near the best one (gaps of a cell bridged: sparse stems)
    lab = _clusters(keys[strong].astype(np.float64), 2.5)
    mine = strong[lab == lab[int(np.flatnonzero(strong == best)[0])]]
    centres = (keys[mine] + 0.5) * cell
    w = layers[mine].astype(np.float64)
    cx, cy = (centres * w[:, None]).sum(axis=0) / w.sum()
    extent = float(np.hypot(centres[:, 0] - cx, centres[:, 1] - cy).max()) + cell / 2
    # a circle through the stem's points finds the centre of a one-sided arc too
    circ = fit_circle(sel[np.isin(inv, mine), :2])
    if circ is not None and circ.radius_m <= 3 * extent and circ.coverage_deg >= 60:
        return circ.cx_m, circ.cy_m, circ.radius_m
    return float(cx), float(cy), max(extent, cell)


#: The cloud's low level is the lowest height whose window of LOW_WINDOW_M holds
#: LOW_MIN_POINTS points: a few stray points below do not set it, and a sparse trunk under a
#: dense crown does (a percentile of the heights did not: rTLS's leaf-on tree holds 0.5 % of
#: its points in its 1.75 m of trunk, and its 0.5th percentile fell at the crown's base).
LOW_WINDOW_M = 0.1
LOW_MIN_POINTS = 10
#: Heights above the disk's lowest point against whose density the stem's foot is found.
FOOT_WINDOW_M = 1.5


def lowest_level(z: np.ndarray) -> float:
    """The lowest height whose window of :data:`LOW_WINDOW_M` above it holds
    :data:`LOW_MIN_POINTS` points (the lowest point of a smaller cloud)."""
    zs = np.sort(np.asarray(z, dtype=np.float64))
    if len(zs) < LOW_MIN_POINTS:
        return float(zs[0])
    full = zs[LOW_MIN_POINTS - 1 :] - zs[: len(zs) - LOW_MIN_POINTS + 1] <= LOW_WINDOW_M
    return float(zs[int(np.argmax(full))] if full.any() else zs[0])


def _lowest_dense_z(z: np.ndarray, bin_m: float = 0.02) -> float:
    """Lower edge of the first ``bin_m`` bin holding a fifth of the median bin's count."""
    edges = np.arange(z.min(), z.max() + 2 * bin_m, bin_m)
    counts, edges = np.histogram(z, bins=edges)
    nz = counts[counts > 0]
    need = max(3.0, 0.2 * float(np.median(nz)))
    k = int(np.flatnonzero(counts >= need)[0]) if (counts >= need).any() else 0
    return float(edges[k])


def base_height(
    points: np.ndarray, axis_xy: tuple[float, float], stem_radius_m: float, radius_m: float = 1.0
) -> tuple[float, str]:
    """The ground's height under the stem (or the stem's foot without ground), m.

    Returns
    -------
    z : float
    source : str
        ``"ground plane"`` or ``"stem foot"``.
    """
    d = np.hypot(points[:, 0] - axis_xy[0], points[:, 1] - axis_xy[1])
    disk = points[d <= max(radius_m, 3 * stem_radius_m)]
    # dense against the lowest metres only: a dense crown above a sparse trunk does not
    # make the trunk's foot look empty
    z_low = _lowest_dense_z(disk[disk[:, 2] <= disk[:, 2].min() + FOOT_WINDOW_M, 2])
    dd = np.hypot(disk[:, 0] - axis_xy[0], disk[:, 1] - axis_xy[1])
    ring = disk[(dd > stem_radius_m + 0.05) & (disk[:, 2] <= z_low + 0.5)]
    if len(ring) >= 8:
        ij = np.floor(ring[:, :2] / 0.1).astype(np.int64)
        keys, inv = np.unique(ij, axis=0, return_inverse=True)
        inv = inv.ravel()
        zmin = np.full(len(keys), np.inf)
        np.minimum.at(zmin, inv, ring[:, 2])
        if len(keys) >= 8:
            xy = (keys + 0.5) * 0.1 - np.asarray(axis_xy)
            a = np.column_stack([xy, np.ones(len(xy))])
            p0, *_ = np.linalg.lstsq(a, zmin, rcond=None)
            sol = least_squares(lambda p: a @ p - zmin, p0, loss="soft_l1", f_scale=0.02)
            return float(sol.x[2]), "ground plane"
    return z_low, "stem foot"


def top_height(points: np.ndarray, radius_m: float = 0.3, neighbours: int = 3) -> float:
    """The highest point with ``neighbours`` other points within ``radius_m``, m."""
    order = np.argsort(points[:, 2])[::-1]
    head = points[order[: min(len(points), 2000)]]
    tree = cKDTree(points)
    counts = np.array([len(c) - 1 for c in tree.query_ball_point(head, radius_m)])
    ok = np.flatnonzero(counts >= neighbours)
    return float(head[ok[0], 2] if len(ok) else head[0, 2])


# ---------------------------------------------------------------------- slabs


def fit_slab(
    points: np.ndarray,
    *,
    z_m: float,
    height_m: float,
    centre_xy: tuple[float, float],
    radius_m: float,
    thickness_m: float = 0.1,
    gap_m: float = 0.5,
) -> Slab:
    """Fit the stem's circle in the slab centred at ``z_m`` near the predicted stem.

    Parameters
    ----------
    points : (n, 3) float
    z_m : float
        Slab centre in the cloud's coordinates.
    height_m : float
        The same above the base (recorded).
    centre_xy, radius_m :
        The predicted stem (the slab below's circle, or the axis near the foot).
    thickness_m : float
        Slab thickness; doubled once when the window holds fewer than
        :data:`MIN_POINTS` points.
    gap_m : float
        Height between this slab and the one that predicted it (the lean allowed).
    """
    cx, cy = centre_xy
    window = radius_m * 1.6 + 0.05
    for t in (thickness_m, 2 * thickness_m):
        s = points[np.abs(points[:, 2] - z_m) <= t / 2]
        d = np.hypot(s[:, 0] - cx, s[:, 1] - cy)
        xy = s[d <= window, :2]
        if len(xy) >= MIN_POINTS:
            break
    common = dict(height_m=height_m, z_m=z_m, thickness_m=t, points_xy=xy)
    if len(xy) < MIN_POINTS:
        return _no_circle(
            common, "sparse", f"{len(xy)} points near the stem (fewer than {MIN_POINTS})"
        )
    # keep the clusters that reach the stem's predicted outline, drop detached blobs
    spacing = float(np.median(cKDTree(xy).query(xy, k=2)[0][:, 1]))
    lab = _clusters(xy, float(np.clip(4 * spacing, 0.01, 0.08)))
    dd = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy)
    near = np.unique(lab[dd <= radius_m * 1.25 + 0.02])
    keep = np.isin(lab, near)
    circ, agrees = _best_circle(xy[keep], (cx, cy), radius_m, gap_m, lab[keep])
    if circ is None:
        return _no_circle(common, "ambiguous", "no circle fits the points near the stem")
    inl = np.zeros(len(xy), dtype=bool)
    inl[np.flatnonzero(keep)[circ.inliers]] = True
    n_in = int(inl.sum())
    share = n_in / max(1, int(keep.sum()))
    verdict, reason = "clean", ""
    r = circ.radius_m
    second = _second_stem(xy[~inl], circ, spacing)
    if second is not None:
        verdict = "forked"
        reason = (
            f"a second stem of D {2 * second.radius_m * 100:.1f} cm "
            f"{np.hypot(second.cx_m - circ.cx_m, second.cy_m - circ.cy_m):.2f} m away"
        )
    elif not agrees:
        verdict = "ambiguous"
        reason = (
            f"no circle near the stem predicted from below (D {2 * radius_m * 100:.1f} cm); "
            f"best fit D {2 * r * 100:.1f} cm"
        )
    elif n_in < MIN_POINTS or circ.coverage_deg < SPARSE_COVERAGE_DEG:
        verdict = "sparse"
        reason = f"{n_in} points on {circ.coverage_deg:.0f} deg of arc"
    elif circ.coverage_deg < CLEAN_COVERAGE_DEG:
        verdict = "ambiguous"
        reason = f"only {circ.coverage_deg:.0f} deg of arc seen"
    elif circ.rms_m > max(RMS_FLOOR_M, RMS_REL * r):
        verdict = "ambiguous"
        reason = f"residual rms {circ.rms_m * 1000:.1f} mm on a {r * 100:.1f} cm radius"
    elif circ.se_radius_m > MAX_SE_REL * r:
        verdict = "ambiguous"
        reason = (
            f"radius uncertain: ±{circ.se_radius_m * 1000:.1f} mm (standard error) on "
            f"{r * 100:.1f} cm"
        )
    elif share < MIN_INLIER_SHARE:
        verdict = "ambiguous"
        reason = f"{(1 - share) * 100:.0f} % of the points at the stem off the circle"
    return Slab(
        **common,
        diameter_m=2 * r,
        centre_xy_m=(circ.cx_m, circ.cy_m),
        rms_m=circ.rms_m,
        coverage_deg=circ.coverage_deg,
        n_points=n_in,
        n_window=len(xy),
        verdict=verdict,
        reason=reason,
        inlier_mask=inl,
    )


def _no_circle(common: dict, verdict: str, reason: str) -> Slab:
    """A slab where no circle was fitted (``common``: its height, z, thickness, points)."""
    n = len(common["points_xy"])
    return Slab(
        **common,
        diameter_m=None,
        centre_xy_m=None,
        rms_m=None,
        coverage_deg=0.0,
        n_points=0,
        n_window=n,
        verdict=verdict,
        reason=reason,
        inlier_mask=np.zeros(n, dtype=bool),
    )


def _best_circle(
    xy: np.ndarray,
    centre: tuple[float, float],
    radius_m: float,
    gap_m: float,
    labels: np.ndarray,
) -> tuple[Circle | None, bool]:
    """The circle of the predicted stem among fits from several starts, and whether it
    agrees with the prediction.

    Starts: the prediction, Kasa's fit of all points, of the points near the predicted
    outline, and of each of the three largest clusters (``labels``). A candidate agrees
    when its centre is within the predicted radius plus 0.35 ``gap_m`` (a lean of 19°
    over the height from the predicting slab) of the predicted centre and its radius
    within 0.5-1.6 times the predicted one. Among those, the ones whose residual passes
    the clean test come first, then the most inliers win; with none agreeing, the same
    order over all fits and False (None when nothing fits at all).
    """
    cx, cy = centre
    near = np.abs(np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) - radius_m) <= 0.3 * radius_m + 0.01
    starts: list[tuple[float, float, float] | None] = [(cx, cy, radius_m), None]
    if near.sum() >= 5:
        starts.append(kasa_circle(xy[near]))
    for k in np.argsort(np.bincount(labels))[::-1][:3]:
        if (labels == k).sum() >= 5:
            starts.append(kasa_circle(xy[labels == k]))
    cands = [c for c in (fit_circle(xy, start=st) for st in starts) if c is not None]
    if not cands:
        return None, False

    def fits(c: Circle) -> bool:
        return (
            np.hypot(c.cx_m - cx, c.cy_m - cy) <= radius_m + 0.35 * gap_m
            and 0.5 * radius_m <= c.radius_m <= 1.6 * radius_m
        )

    good = [c for c in cands if fits(c)]

    def key(c: Circle) -> tuple[bool, int, float]:
        return (c.rms_m <= max(RMS_FLOOR_M, RMS_REL * c.radius_m), int(c.inliers.sum()), -c.rms_m)

    return max(good or cands, key=key), bool(good)


def _second_stem(rest: np.ndarray, first: Circle, spacing_m: float) -> Circle | None:
    """A second clean circle of at least a third of ``first``'s radius among ``rest``."""
    if len(rest) < MIN_POINTS:
        return None
    lab = _clusters(rest, float(np.clip(4 * spacing_m, 0.01, 0.08)))
    for k in np.argsort(np.bincount(lab))[::-1][:3]:
        pts = rest[lab == k]
        if len(pts) < MIN_POINTS:
            break
        c = fit_circle(pts)
        if c is None:
            continue
        gap = np.hypot(c.cx_m - first.cx_m, c.cy_m - first.cy_m)
        ok = (
            first.radius_m / 3 <= c.radius_m <= 2 * first.radius_m
            and c.coverage_deg >= SPARSE_COVERAGE_DEG
            and c.rms_m <= max(RMS_FLOOR_M, RMS_REL * c.radius_m)
            and c.inliers.mean() >= 0.6
            and gap >= 0.8 * (c.radius_m + first.radius_m)
        )
        if ok:
            return c
    return None


def reference(
    points: np.ndarray,
    *,
    thickness_m: float = 0.1,
    step_m: float = 0.5,
    first_m: float = 0.5,
    max_misses: int = 3,
) -> TreeReference:
    """The references of one single-tree cloud.

    Parameters
    ----------
    points : (n, 3) float
        The tree's points (any coordinates; a local frame is used internally).
    thickness_m : float
        Slab thickness.
    step_m : float
        Height step of the taper profile above ``first_m``; 1.3 m is always among the
        slabs.
    first_m : float
        Lowest slab above the base.
    max_misses : int
        The walk up the stem stops after this many slabs in a row that are not clean.

    Returns
    -------
    TreeReference

    Raises
    ------
    ValueError
        For fewer than 3 dimensions, non-finite values, or no stem to find.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 3 or len(pts) < MIN_POINTS:
        raise ValueError(f"points must be (n >= {MIN_POINTS}, 3), got shape {pts.shape}")
    pts = pts[:, :3]
    if not np.isfinite(pts).all():
        raise ValueError("points hold NaN or infinite values")
    origin = np.array([*np.median(pts[:, :2], axis=0), 0.0])
    local = pts - origin
    low = lowest_level(local[:, 2])
    ax, ay, r0 = stem_axis_near_foot(local, low)
    base, source = base_height(local, (ax, ay), r0)
    top = top_height(local)
    heights = sorted({1.3, *np.round(np.arange(first_m, top - base, step_m), 6)})
    slabs: list[Slab] = []
    # walk up the stem from the foot's axis, each slab predicted by the last clean one
    cen, rad, misses, h_pred = (ax, ay), r0, 0, 1.3
    for h in heights:
        if misses >= max_misses and h > 1.3:
            break
        s = fit_slab(
            local,
            z_m=base + h,
            height_m=float(h),
            centre_xy=cen,
            radius_m=rad,
            thickness_m=thickness_m,
            gap_m=abs(h - h_pred),
        )
        slabs.append(s)
        if s.verdict == "forked" and h >= 1.3:
            break
        if s.clean:
            cen, rad, misses, h_pred = s.centre_xy_m, s.diameter_m / 2, 0, h
        else:
            misses += 1
    slabs = [_shift(s, origin) for s in sorted(slabs, key=lambda s: s.height_m)]
    dbh = next(s for s in slabs if s.height_m == 1.3)
    return TreeReference(
        base_z_m=base + origin[2],
        base_source=source,
        top_z_m=top + origin[2],
        height_m=top - base,
        axis_xy_m=(ax + origin[0], ay + origin[1]),
        dbh_slab=dbh,
        slabs=slabs,
    )


def _shift(s: Slab, origin: np.ndarray) -> Slab:
    """``s`` in the cloud's coordinates."""
    from dataclasses import replace

    c = (
        None
        if s.centre_xy_m is None
        else (s.centre_xy_m[0] + origin[0], s.centre_xy_m[1] + origin[1])
    )
    return replace(s, z_m=s.z_m + origin[2], centre_xy_m=c, points_xy=s.points_xy + origin[:2])


# ---------------------------------------------------------------------- models


def stem_radius_at(
    start: np.ndarray,
    end: np.ndarray,
    radius0_m: np.ndarray,
    radius1_m: np.ndarray,
    z_m: float,
    xy: tuple[float, float],
) -> float | None:
    """A model's stem radius at height ``z_m`` (m), to hold against a slab.

    Parameters
    ----------
    start, end : (n, 3) float
        The stem cylinders' base and top centres, m.
    radius0_m, radius1_m : (n,) float
        Their base and top radii, m.
    z_m : float
    xy : (2,) float
        The slab's centre: where several cylinders cross ``z_m``, the one passing
        nearest is used.

    Returns
    -------
    float or None
        The radius interpolated along that cylinder, or None where no stem cylinder
        crosses ``z_m``.
    """
    s, e = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    if len(s) == 0:
        return None
    r0, r1 = np.asarray(radius0_m, dtype=np.float64), np.asarray(radius1_m, dtype=np.float64)
    lo, hi = np.minimum(s[:, 2], e[:, 2]), np.maximum(s[:, 2], e[:, 2])
    hit = np.flatnonzero((lo <= z_m) & (hi >= z_m) & (hi > lo))
    if len(hit) == 0:
        return None
    t = (z_m - s[hit, 2]) / (e[hit, 2] - s[hit, 2])
    p = s[hit] + t[:, None] * (e[hit] - s[hit])
    k = int(np.argmin(np.hypot(p[:, 0] - xy[0], p[:, 1] - xy[1])))
    return float(r0[hit[k]] + t[k] * (r1[hit[k]] - r0[hit[k]]))


# ---------------------------------------------------------------------- pictures


def render_slab(slab: Slab, path: str | Path, title: str = "") -> Path:
    """Write a PNG of ``slab``: its points, the inliers, the fitted circle, the verdict.

    Parameters
    ----------
    slab : Slab
    path : str or Path
        The PNG to write (its folder is created).
    title : str
        Put before the slab's own description in the title.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(4.2, 4.4), dpi=110)
    xy = slab.points_xy
    ref = np.asarray(slab.centre_xy_m) if slab.centre_xy_m is not None else xy.mean(axis=0)
    rel = (xy - ref) * 100 if len(xy) else xy
    if len(rel):
        ax.scatter(
            rel[~slab.inlier_mask, 0], rel[~slab.inlier_mask, 1], s=3, c="0.6", label="other points"
        )
        ax.scatter(
            rel[slab.inlier_mask, 0],
            rel[slab.inlier_mask, 1],
            s=3,
            c="tab:brown",
            label="on the circle",
        )
    if slab.diameter_m is not None:
        t = np.linspace(0, 2 * np.pi, 361)
        r = slab.diameter_m * 50
        ax.plot(r * np.cos(t), r * np.sin(t), c="tab:blue", lw=1, label="fitted circle")
    ax.set_aspect("equal")
    ax.set_xlabel("x (cm, from the centre)")
    ax.set_ylabel("y (cm)")
    d = "no circle" if slab.diameter_m is None else f"D {slab.diameter_m * 100:.1f} cm"
    head = f"{title}: " if title else ""
    lines = [f"{head}{slab.height_m:.2f} m, {d}, {slab.verdict}"]
    if slab.reason:
        lines.append(slab.reason)
    elif slab.rms_m is not None:
        lines.append(f"rms {slab.rms_m * 1000:.1f} mm, {slab.coverage_deg:.0f} deg of arc")
    ax.set_title("\n".join(lines), fontsize=8)
    ax.legend(fontsize=6, loc="upper right", markerscale=3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
