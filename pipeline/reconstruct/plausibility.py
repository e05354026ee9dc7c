"""Plausibility checks: figures of a reconstructed tree, and a warning outside their range.

:func:`assess` reads a reconstruction's cylinder table (qsm) and figures and returns
``{"figures": {...}, "warnings": [...]}``. Each warning is a dict ``{"code", "message",
"value", "range", "likely_cause", "remedy"}``: the figure's value, the range it left, the
likely cause in words and what the user can do. A warning says a result is *implausible*
for a real tree; it does not say the result is wrong (a palm's stem does not taper, a
coppiced shrub has no single stem). Nothing here changes the model.

The figures and where their ranges come from (each threshold is a module constant below):

* **Stem form factor** ``f = V_stem / (g_1.3 · H_stem)`` (``g_1.3`` the basal area at
  breast height, ``H_stem`` the stem's vertical extent). Stems are modelled in forest
  mensuration as solids of revolution ``r² ∝ (H − z)^p``: neiloid (p = 3) at the butt,
  paraboloid (p = 1) in the middle, cone (p = 2) in the top; most stems lie between the
  cone and the paraboloid (Husch, Beers & Kershaw 2003, *Forest Mensuration*, 4th ed.,
  Wiley, ch. 6 "tree form"). Measured at 1.3 m instead of the base, such a solid's
  form factor is ``f(H) = (H / (H − 1.3))^p / (p + 1)`` (derived here from the solid's
  volume ``π r0² H / (p + 1)``), which grows as trees get short: a cone 20 m tall has
  0.377, 4 m tall 0.70. The plausible range is ``[FORM_LOW_SLACK · f_cone(H),
  FORM_HIGH_SLACK · f_paraboloid(H)]``: at 20 m 0.30 .. 0.62, consistent with published
  breast-height form factors of 0.33 .. 0.68 over conifers and broadleaves (review table
  of the Forests 2025, 16(1), 29 review, doi:10.3390/f16010029: Pinus 0.49 .. 0.63, Abies
  0.56, Tsuga 0.48, broadleaves 0.33 .. 0.68). A cylinder has 1.0. A stem with a palm's
  terminal crown (figure ``terminal_crown``, :func:`terminal_crown`) may reach a
  cylinder's 1.0 times the slack: a palm's stem does not taper.
* **Taper** along the stem (branch-order-0 cylinders): the largest rise of the radius
  upwards, the longest stretch over which the radius is held constant, the mean taper
  (cm of diameter per m from 1.3 m to the stem's top; figure only).
* **Radius jumps**: the largest ratio of consecutive cylinders' (base) radii along a
  branch, the largest
  child / parent radius at a junction (pipe-model theory, Shinozaki et al. 1964, and
  every QSM method: a child is no wider than its parent), and the largest ratio of a
  *modelled* radius over the measured radii of its own branch nearby.
* **The stem's foot**: the inclination of the stem's first metre, how far the stem's
  base lies above the lowest points, and how far the lowest points spread around it
  (ground, litter or understory left in).
* **Total volume** against a DBH-height envelope ``V in [f_low(H), f_high(H) ·
  (1 + BRANCH_TO_STEM_MAX)] · g_1.3 · H``. Not a fitted allometry: no published
  DBH-height-volume equation's coefficients could be verified for this project, so the
  envelope is the form-factor range above widened by the largest plausible branch
  share, and says so.
* **Leaves taken for wood**: on a leaf-on cloud, branch volume above
  ``LEAF_ON_BRANCH_TO_STEM_MAX`` times the stem volume; and **stem hidden**: less than
  ``STEM_MEASURED_MIN`` of the stem's length has measured radii.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ..models import CylinderTable

__all__ = [
    "add_plausibility",
    "assess",
    "form_factor_range",
    "solid_form_factor",
    "terminal_crown",
]

#: Breast height, m (the DBH convention of the whole project: 1.3 m above the stem base).
BREAST_HEIGHT_M = 1.3
#: Below this stem height the breast-height form factor and the volume envelope are not
#: judged: ``H / (H - 1.3)`` explodes as H nears 1.3 m (twice breast height).
MIN_HEIGHT_FOR_FORM_M = 2.0 * BREAST_HEIGHT_M
#: Lower bound of the form factor as a share of a cone's: butt swell reaching 1.3 m can
#: widen DBH by about 10 % (f × 1/1.1² = 0.83); a little more for measurement noise.
#: The procedural old-tupelo (Weber & Penn flare 1.0, a cone above) reads 0.89 × cone.
FORM_LOW_SLACK = 0.8
#: Upper bound as a share of a paraboloid's: the neiloid butt and DBH noise (a few %)
#: push fuller stems slightly above the paraboloid; at 20 m this gives 0.62, above the
#: 0.5 .. 0.6 of full-boled conifers in the review's table.
FORM_HIGH_SLACK = 1.15
#: Exponents p of the solids r² ∝ (H - z)^p (Husch et al. 2003).
CONE_P, PARABOLOID_P = 2.0, 1.0

#: A rise of the stem radius upwards is beyond noise when it exceeds the largest of this
#: (m; circle fits on TLS stems err by mm to 1-2 cm, e.g. Hackenberg et al. 2015,
#: Forests 6: 4245), this share of the radius below it, and 3 σ of the fit's noise.
RISE_MIN_M = 0.01
RISE_MIN_SHARE = 0.15
#: The radius counts as held constant while it changes by at most the larger of these
#: (m, share of the radius): a stem tapering 0.5 cm/m in diameter changes more than that
#: over a metre or two.
HOLD_TOL_M = 0.001
HOLD_TOL_SHARE = 0.02
#: Longest plausible stretch of constant stem radius, m. Nodes thinner than
#: ``HOLD_MIN_SHARE`` of the radius at 1.3 m (the twig floor at the top) are not counted.
HOLD_MAX_M = 3.0
HOLD_MIN_SHARE = 0.2

#: Largest ratio of consecutive radii along a branch, judged where the larger radius is
#: at least ``JUMP_MIN_RADIUS_M``: thinner branches span a few scan spacings (7 mm at
#: 10 m and 0.04 deg), so their fitted radii scatter by factors (the bundled coffee
#: tree's twigs jump 2.8x between 4 mm and 11 mm) and hold little of the volume.
JUMP_MAX_RATIO = 2.0
JUMP_MIN_RADIUS_M = 0.02
#: Largest child / parent radius at a junction (10 % for fit noise in imported tables).
CHILD_PARENT_MAX = 1.1
#: A modelled radius may exceed the largest measured radius of its own branch within
#: ``MODELLED_NEAR_M`` (along the branch) by this ratio (taper over 2 m of a big stem is
#: under 10 %), and by at least ``MODELLED_MIN_EXCESS_M`` (both radii under
#: ``JUMP_MIN_RADIUS_M``: not judged, as for jumps).
MODELLED_MAX_RATIO = 1.25
MODELLED_NEAR_M = 2.0
MODELLED_MIN_EXCESS_M = 0.01

#: Length of the stem's first run whose chord inclination is judged, m.
BASE_RUN_M = 1.0
#: Steepest plausible inclination of the stem's first metre from vertical, degrees
#: (leaning trees lean by tens of degrees; a stem starting horizontally is ground).
BASE_MAX_INCLINATION_DEG = 60.0
#: The stem's base may lie this far above the lowest points (m) ...
BASE_ABOVE_LOWEST_MAX_M = 0.5
#: ... and the points of the lowest ``BASE_BAND_M`` may reach this many DBH radii from
#: the stem base (95th percentile): root collars and buttresses of ordinary trees stay
#: within 2-3 radii; a ground disc or understory reaches much farther.
BASE_BAND_M = 0.3
BASE_SPREAD_MAX = 4.0

#: Largest plausible branch / stem volume ratio in the volume envelope. Not from a
#: verified source: the procedural presets read 0.13 .. 0.50; treesim's QSMs of the real
#: clouds (``benchmarks/bench_real_trees.py``, 2026-11-26, after the stem-slab fits)
#: 0.11 .. 1.58, and 2.00 on the leaf-on Lille and 2.26 on the palm, whose leaves and
#: fronds are kept as wood.
BRANCH_TO_STEM_MAX = 1.5
#: On a leaf-on cloud, a branch / stem volume ratio above this suggests leaves fitted as
#: wood. Not from a verified source: conifers read about 0.1 .. 0.3 (balsam-fir preset
#: 0.13; the real pines 0.11 .. 0.65, one at 1.07), broadleaves up to about 1; the leaf-on
#: Lille (2.00) and AdTree tree7 (1.55), whose leaf clumps the classifier keeps as wood,
#: read more (bench_real_trees.py, 2026-11-26).
LEAF_ON_BRANCH_TO_STEM_MAX = 1.2
#: Least share of the stem's length with measured radii before "stem hidden". Measured on
#: the real clouds with defaults (bench_real_trees.py, 2026-11-26): coffee tree 0.78,
#: pines 0.31 .. 0.52, aRchi trees 0.45, palm 0.35, rtls tree 0.24, AdTree tree7 0.16,
#: leaf-on Lille 0.09 (its stem in leaves).
STEM_MEASURED_MIN = 0.25


#: A palm's architecture (Corner's model, Hallé, Oldeman & Tomlinson 1978, *Tropical
#: Trees and Forests*, Springer: one unbranched stem carrying a terminal crown of leaves)
#: is recognised on a cylinder table by where its laterals leave the stem (above breast
#: height; lower ones are the foot's: a flare, ground, a sprout): 90 % of the
#: order-1 branch volume (the 5th to 95th volume-weighted percentile of the heights where
#: they leave it) within ``TERMINAL_CROWN_SPAN`` of the stem's height, none of it below
#: ``TERMINAL_CROWN_BASE`` of that height, and no lateral thicker at its base than
#: ``TERMINAL_CROWN_LATERAL_RATIO`` times the bare stem's median radius (a frond's rachis
#: is thin beside a palm's stem; a fork's or a pollard's limbs are not). Such a stem
#: barely tapers (a palm's stem has no secondary growth), so its form factor's plausible
#: ceiling is a cylinder's (1.0) times ``FORM_HIGH_SLACK``. Measured (2026-11-27): the
#: procedural palm's exact table 0.93 .. 1.0 of its stem, its QSM from a noisy 0.04° scan
#: 0.74 .. 0.85 (the QSM follows a frond up as the stem's top and merges crossing fronds,
#: so neither "at the top" nor "unbranched" holds there); the broadleaf and conifer
#: presets' crowns span 0.3 .. 0.7 of their stems. Of the real clouds (bench_real_trees'
#: QSMs), a lodgepole pine with a short crown (0.59 .. 0.76) passes the span and base
#: rules; its thickest lateral is as thick as its stem (a fork), against 0.36 on the
#: palm's QSM.
TERMINAL_CROWN_SPAN = 0.2
TERMINAL_CROWN_BASE = 0.5
TERMINAL_CROWN_LATERAL_RATIO = 0.5

#: Causes and remedies that several warnings name.
DBH_INFLATED = "a DBH inflated at 1.3 m (a fork, a buttress, a neighbour's stem)"
SEE_THE_STEM = "scan from more sides, or separate the leaves (--separate-leaves on)"

#: The figures :func:`assess` returns (None where one does not apply), in order.
FIGURES: tuple[str, ...] = (
    "stem_height_m",
    "stem_form_factor",
    "stem_form_factor_range",
    "terminal_crown",
    "stem_taper_cm_per_m",
    "stem_radius_rise_m",
    "stem_radius_held_m",
    "stem_measured_share",
    "stem_base_inclination_deg",
    "stem_base_above_lowest_m",
    "base_spread_radii",
    "radius_jump_ratio",
    "child_parent_ratio",
    "modelled_over_measured_ratio",
    "volume_total_factor",
    "volume_total_factor_range",
    "branch_to_stem_volume",
    "leaf_share",
)


def solid_form_factor(
    height_m: float, exponent: float, breast_height_m: float = BREAST_HEIGHT_M
) -> float:
    """Breast-height form factor of the solid ``r² ∝ (H − z)^p``.

    Parameters
    ----------
    height_m : float
        The solid's height H, m (> ``breast_height_m``).
    exponent : float
        p: 1 a paraboloid, 2 a cone, 3 a neiloid, 0 a cylinder.
    breast_height_m : float

    Returns
    -------
    float
        ``V / (π r(1.3)² H) = (H / (H − 1.3))^p / (p + 1)``.
    """
    h = float(height_m)
    return (h / (h - breast_height_m)) ** exponent / (exponent + 1.0)


def form_factor_range(height_m: float) -> tuple[float, float]:
    """The plausible breast-height stem form factor range for a stem ``height_m`` tall."""
    return (
        FORM_LOW_SLACK * solid_form_factor(height_m, CONE_P),
        FORM_HIGH_SLACK * solid_form_factor(height_m, PARABOLOID_P),
    )


def _warning(
    code: str, value: float, lo: float | None, hi: float | None, what: str, cause: str, fix: str
) -> dict[str, Any]:
    rng = [lo, hi]
    bounds = (
        f"{lo:.3g} .. {hi:.3g}"
        if lo is not None and hi is not None
        else (f"at most {hi:.3g}" if hi is not None else f"at least {lo:.3g}")
    )
    return {
        "code": code,
        "message": f"{what} (plausible: {bounds}): likely {cause}; {fix}",
        "value": float(value),
        "range": rng,
        "likely_cause": cause,
        "remedy": fix,
    }


def _outside(
    warns: list[dict[str, Any]],
    value: float,
    lo: float,
    hi: float,
    *,
    high: tuple[str, str, str, str],
    low: tuple[str, str, str, str],
) -> None:
    """Append the ``high`` or ``low`` warning (code, what, cause, remedy) when ``value``
    lies above ``hi`` or below ``lo``."""
    if value > hi:
        warns.append(_warning(high[0], value, lo, hi, *high[1:]))
    elif value < lo:
        warns.append(_warning(low[0], value, lo, hi, *low[1:]))


def _stem_rows(table: CylinderTable) -> np.ndarray:
    """Rows of the main stem (order 0, the branch of the lowest order-0 cylinder), in
    order along it."""
    order0 = np.flatnonzero(table.branch_order == 0)
    if order0.size == 0:
        return order0
    first = order0[np.argmin(table.start[order0, 2])]
    rows = order0[table.branch[order0] == table.branch[first]]
    return rows[np.argsort(table.position_in_branch[rows], kind="stable")]


def _profile(table: CylinderTable, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node heights (m, relative to the stem base) and radii along the stem: each
    cylinder's base and top, in order."""
    z = np.c_[table.start[rows, 2], table.end[rows, 2]].ravel()
    r = np.c_[table.radius_m[rows], table.end_radius_m[rows]].ravel()
    return z - z.min(), r


def terminal_crown(table: CylinderTable, rows: np.ndarray) -> bool:
    """Whether the stem (its cylinder ``rows``, base to top) carries a palm's terminal
    crown: see :data:`TERMINAL_CROWN_SPAN`.

    Examples
    --------
    >>> from treesim.models import generate_tree
    >>> t = generate_tree("palm", seed=0, leaves=False).cylinders
    >>> terminal_crown(t, np.flatnonzero(t.branch_order == 0))
    True
    >>> t = generate_tree("sapling", seed=0).cylinders
    >>> terminal_crown(t, np.flatnonzero(t.branch_order == 0))
    False
    """
    order = table.branch_order
    first = np.flatnonzero((order == 1) & (table.position_in_branch == 1))
    if first.size == 0 or rows.size == 0:
        return False
    z0 = float(table.start[rows, 2].min())
    # laterals leaving below breast height are the foot's (a flare, ground, a sprout)
    first = first[table.start[first, 2] - z0 >= BREAST_HEIGHT_M]
    if first.size == 0:
        return False
    h = float(table.end[rows, 2].max()) - z0
    if h <= 0:
        return False
    # each order-1 branch's volume, at the height (share of the stem's) where it leaves
    branch_vol = np.bincount(table.branch[order == 1], weights=table.volume_m3[order == 1])
    per = branch_vol[table.branch[first]]
    if per.sum() <= 0:
        return False
    at = (table.start[first, 2] - z0) / h
    k = np.argsort(at)
    cum = np.cumsum(per[k]) / per.sum()
    lo = float(at[k][np.searchsorted(cum, 0.05)])
    hi = float(at[k][min(np.searchsorted(cum, 0.95), len(k) - 1)])
    if lo < TERMINAL_CROWN_BASE or hi - lo > TERMINAL_CROWN_SPAN:
        return False
    bare = rows[table.start[rows, 2] - z0 < lo * h]
    if bare.size == 0:
        return False
    thickest = float(table.radius_m[first].max())
    return thickest <= TERMINAL_CROWN_LATERAL_RATIO * float(np.median(table.radius_m[bare]))


def _largest_rise(r: np.ndarray, noise_m: float) -> tuple[float, float]:
    """(rise m, tolerance m) of the largest increase of ``r`` over its running minimum."""
    low = np.minimum.accumulate(r)
    rise = r - low
    k = int(np.argmax(rise))
    tol = max(RISE_MIN_M, RISE_MIN_SHARE * float(low[k]), 3.0 * noise_m)
    return float(rise[k]), tol


def _longest_hold(z: np.ndarray, r: np.ndarray, floor_m: float) -> float:
    """Longest vertical extent (m) of consecutive nodes (radius >= ``floor_m``) whose
    radius stays within ``max(HOLD_TOL_M, HOLD_TOL_SHARE r)``."""
    best = 0.0
    n = len(r)
    for i in range(n):
        if r[i] < floor_m:
            continue
        tol = max(HOLD_TOL_M, HOLD_TOL_SHARE * r[i])
        lo = hi = r[i]
        zlo = zhi = z[i]
        for j in range(i + 1, n):
            if r[j] < floor_m:
                break
            lo, hi = min(lo, r[j]), max(hi, r[j])
            if hi - lo > tol:
                break
            zlo, zhi = min(zlo, z[j]), max(zhi, z[j])
        best = max(best, float(zhi - zlo))
    return best


def _branch_paths(table: CylinderTable) -> np.ndarray:
    """(n,) distance (m) of each cylinder's base along its branch from the branch start."""
    s = np.zeros(table.n_cylinders)
    order = np.lexsort((table.position_in_branch, table.branch))
    b = table.branch[order]
    length = table.length_m[order]
    cum = np.cumsum(length) - length
    first = np.r_[True, b[1:] != b[:-1]]
    start_of = np.maximum.accumulate(np.where(first, np.arange(len(b)), 0))
    s[order] = cum - cum[start_of]
    return s


def _modelled_excess(table: CylinderTable) -> tuple[float, int] | None:
    """Largest modelled radius over the largest measured radius of its own branch within
    ``MODELLED_NEAR_M``: (ratio, row), counting cylinders of at least
    ``JUMP_MIN_RADIUS_M`` and capping at 1 a ratio whose excess is under
    ``MODELLED_MIN_EXCESS_M``; None when no modelled cylinder has measured neighbours
    (or the table carries no measured cylinder: a procedural or imported table)."""
    measured = table.tag == "measured"
    modelled = np.flatnonzero(table.tag == "modelled")
    if not measured.any() or modelled.size == 0:
        return None
    s = _branch_paths(table)
    best: tuple[float, int] | None = None
    by_branch: dict[int, np.ndarray] = {}
    for i in modelled:
        b = int(table.branch[i])
        if b not in by_branch:
            by_branch[b] = np.flatnonzero((table.branch == b) & measured)
        m = by_branch[b]
        if m.size == 0:
            continue
        near = m[np.abs(s[m] - s[i]) <= MODELLED_NEAR_M]
        if near.size == 0:
            continue
        ref = float(table.radius_m[near].max())  # the fitted (base) radii
        r = float(table.radius_m[i])
        if r < JUMP_MIN_RADIUS_M and ref < JUMP_MIN_RADIUS_M:
            continue  # twigs: a ratio of millimetres says nothing
        ratio = r / ref
        if r - ref < MODELLED_MIN_EXCESS_M:
            ratio = min(ratio, 1.0)  # within the excess allowed: never a warning
        if best is None or ratio > best[0]:
            best = (ratio, int(i))
    return best


def _jumps(table: CylinderTable) -> dict[str, Any]:
    """Largest consecutive-radius ratio along branches and child / parent ratio."""
    par = table.parent
    child = np.flatnonzero(par >= 0)
    p = par[child]
    same = table.branch[child] == table.branch[p]
    out: dict[str, Any] = {"radius_jump_ratio": None, "child_parent_ratio": None}
    c, q = child[same], p[same]
    if c.size:
        a, b = table.radius_m[q], table.radius_m[c]  # node radii, frustum or not
        big = np.maximum(a, b)
        keep = big >= JUMP_MIN_RADIUS_M
        if keep.any():
            ratio = big[keep] / np.minimum(a, b)[keep]
            k = int(np.argmax(ratio))
            out["radius_jump_ratio"] = float(ratio[k])
            out["_jump_row"] = int(c[keep][k])
    c, q = child[~same], p[~same]
    if c.size:
        ratio = table.radius_m[c] / np.maximum(table.radius_m[q], table.end_radius_m[q])
        k = int(np.argmax(ratio))
        out["child_parent_ratio"] = float(ratio[k])
        out["_child_row"] = int(c[k])
    return out


def _ground_fix(preparation: dict[str, Any] | None) -> str:
    steps = (preparation or {}).get("steps", [])
    ground = next((s for s in steps if s.get("step") == "ground_removal"), None)
    if ground is not None and ground.get("params", {}).get("enabled"):
        return (
            f"ground removal ran and removed {ground.get('removed', 0):,} points: crop the "
            "cloud's ground and understory by hand, or raise the ground tolerance"
        )
    return "reconstruct with --remove-ground, or crop the ground and understory first"


def _leaf_state(figures: dict[str, Any], leaves: dict[str, Any] | None) -> tuple[bool, float]:
    f = {**figures, **(leaves or {})}
    share = f.get("leaf_share", f.get("leaf_fraction"))
    return bool(f.get("leaves_present")), float(share) if share is not None else float("nan")


def assess(
    table: CylinderTable | None,
    figures: dict[str, Any],
    *,
    preparation: dict[str, Any] | None = None,
    leaves: dict[str, Any] | None = None,
    points: np.ndarray | None = None,
    points_origin: np.ndarray | None = None,
) -> dict[str, Any]:
    """Plausibility figures of a reconstruction and the warnings they raise.

    Parameters
    ----------
    table : CylinderTable or None
        The QSM (None for a surface method: only the volume envelope applies).
    figures : dict
        The reconstruction's figures (``dbh_m``, ``height_m``, ``volume_total_m3``,
        ``volume_stem_m3``, ``volume_branch_m3``, ``leaves_present``, ``leaf_share`` or
        ``leaf_fraction``, ``noise_sd_m``, ``leaf_separation``).
    preparation : dict, optional
        What preparation did (``TreeModel.preparation``): names the remedy for ground.
    leaves : dict, optional
        The wood/leaf separation's figures, if not already in ``figures``.
    points : (n, 3) float, optional
        The points the model was built from, in ``table``'s coordinates minus
        ``points_origin``; enables the foot checks against the lowest points.
    points_origin : (3,) float, optional
        Origin of ``points`` in ``table``'s coordinates (default zero).

    Returns
    -------
    dict
        ``figures``: each figure (None where it does not apply), and ``warnings``: a
        list of ``{"code", "message", "value", "range", "likely_cause", "remedy"}``.
    """
    out: dict[str, Any] = dict.fromkeys(FIGURES)
    warns: list[dict[str, Any]] = []
    dbh = figures.get("dbh_m")
    dbh = float(dbh) if dbh else None
    height = figures.get("height_m")
    height = float(height) if height else None
    leafy, leaf_share = _leaf_state(figures, leaves)
    out["leaf_share"] = None if math.isnan(leaf_share) else leaf_share
    ground_fix = _ground_fix(preparation)

    if table is not None and table.n_cylinders:
        _assess_table(table, figures, dbh, out, warns, ground_fix, points, points_origin)

    # total volume envelope (every method)
    vt = figures.get("volume_total_m3")
    if vt and dbh and height and height >= MIN_HEIGHT_FOR_FORM_M:
        g_h = math.pi / 4.0 * dbh * dbh * height
        lo, hi = form_factor_range(height)
        hi *= 1.0 + BRANCH_TO_STEM_MAX
        f = float(vt) / g_h
        out["volume_total_factor"] = f
        out["volume_total_factor_range"] = [lo, hi]
        sizes = f"(DBH {dbh * 100:.1f} cm, height {height:.1f} m)"
        _outside(
            warns,
            f,
            lo,
            hi,
            high=(
                "volume_total_high",
                f"total volume {float(vt) * 1000:.0f} L is {f:.2f} x basal area x height {sizes}",
                "ground, understory or leaves taken for wood, or a stem wider than the data",
                "check the warnings above, reconstruct with --remove-ground or "
                "--separate-leaves on",
            ),
            low=(
                "volume_total_low",
                f"total volume {float(vt) * 1000:.0f} L is only {f:.2f} x basal area x "
                f"height {sizes}",
                DBH_INFLATED + " or a height taken from noise above the crown",
                "check the stem at 1.3 m in the cloud and the outliers above the tree",
            ),
        )

    # leaves taken for wood
    vs, vb = figures.get("volume_stem_m3"), figures.get("volume_branch_m3")
    out["branch_to_stem_volume"] = float(vb) / float(vs) if vs and vb is not None else None
    ratio = out["branch_to_stem_volume"]
    if leafy and ratio is not None and ratio > LEAF_ON_BRANCH_TO_STEM_MAX:
        used = str(figures.get("leaf_separation", (leaves or {}).get("leaf_separation", "off")))
        separated = used in ("on", "auto")
        warns.append(
            _warning(
                "leaves_as_wood",
                ratio,
                None,
                LEAF_ON_BRANCH_TO_STEM_MAX,
                f"on a leaf-on cloud (leaf share {leaf_share:.2f}) the branches hold "
                f"{ratio:.2f} x the stem's volume",
                "leaves or needles taken for wood (twig radii fitted to leaf clumps)",
                (
                    "the separation kept leaf clumps as wood: look at labels.laz"
                    if separated
                    else "reconstruct with --separate-leaves on"
                ),
            )
        )
    return {"figures": out, "warnings": warns}


def _assess_table(
    table: CylinderTable,
    figures: dict[str, Any],
    dbh: float | None,
    out: dict[str, Any],
    warns: list[dict[str, Any]],
    ground_fix: str,
    points: np.ndarray | None,
    points_origin: np.ndarray | None,
) -> None:
    rows = _stem_rows(table)
    if rows.size:
        _assess_stem(table, rows, figures, dbh, out, warns, ground_fix, points, points_origin)

    j = _jumps(table)
    out["radius_jump_ratio"] = j["radius_jump_ratio"]
    out["child_parent_ratio"] = j["child_parent_ratio"]
    if j["radius_jump_ratio"] is not None and j["radius_jump_ratio"] > JUMP_MAX_RATIO:
        i = j["_jump_row"]
        warns.append(
            _warning(
                "radius_jump",
                j["radius_jump_ratio"],
                None,
                JUMP_MAX_RATIO,
                f"the radius jumps {j['radius_jump_ratio']:.2f}x between consecutive "
                f"cylinders of a branch (row {i + 1}, order {int(table.branch_order[i])})",
                "a circle fitted to leaves, a neighbour or a fork, or a radius modelled "
                "where the data are missing",
                "look at that branch in cylinders.csv and the cloud",
            )
        )
    if j["child_parent_ratio"] is not None and j["child_parent_ratio"] > CHILD_PARENT_MAX:
        i = j["_child_row"]
        warns.append(
            _warning(
                "child_wider_than_parent",
                j["child_parent_ratio"],
                None,
                CHILD_PARENT_MAX,
                f"a branch starts {j['child_parent_ratio']:.2f}x wider than its parent "
                f"(row {i + 1})",
                "a wrong topology (a neighbour's stem or the ground joined as a branch) "
                "or a radius fitted to a clump",
                "look at that junction in cylinders.csv and the cloud",
            )
        )
    mx = _modelled_excess(table)
    out["modelled_over_measured_ratio"] = None if mx is None else mx[0]
    if mx is not None and mx[0] > MODELLED_MAX_RATIO:
        i = mx[1]
        warns.append(
            _warning(
                "modelled_radius_above_measured",
                mx[0],
                None,
                MODELLED_MAX_RATIO,
                f"a modelled radius ({float(table.radius_m[i]) * 100:.1f} cm, row {i + 1}) "
                f"is {mx[0]:.2f}x the measured radii of its own branch nearby",
                "the pipe model extrapolated where the data are missing (ground or a "
                "wrong topology under the cylinder)",
                "check the cloud there; " + ground_fix,
            )
        )


def _assess_stem(
    table: CylinderTable,
    rows: np.ndarray,
    figures: dict[str, Any],
    dbh: float | None,
    out: dict[str, Any],
    warns: list[dict[str, Any]],
    ground_fix: str,
    points: np.ndarray | None,
    points_origin: np.ndarray | None,
) -> None:
    """The stem's checks (its cylinder ``rows``, base to top): its form factor, taper and
    radius profile, measured share, and foot; figures into ``out``, warnings appended to
    ``warns``."""
    z, r = _profile(table, rows)
    h_stem = float(z.max())
    out["stem_height_m"] = h_stem
    vol = float(table.volume_m3[table.branch_order == 0].sum())
    noise = float(figures.get("noise_sd_m") or 0.0)
    out["terminal_crown"] = terminal_crown(table, rows)
    fronds = figures.get("leaf_model") == "fronds"
    _stem_form(dbh, vol, h_stem, out, warns, ground_fix, fronds)
    _stem_radii(z, r, dbh, h_stem, noise, out, warns)
    _stem_hidden(table, rows, out, warns)
    _stem_foot(table, rows, dbh, out, warns, ground_fix, points, points_origin)


def _stem_form(
    dbh: float | None,
    vol: float,
    h_stem: float,
    out: dict[str, Any],
    warns: list[dict[str, Any]],
    ground_fix: str,
    fronds: bool = False,
) -> None:
    """The stem's form factor (volume over a cylinder of its DBH and height) against the
    range expected for its height. ``fronds``: the frond model's labels were kept (a
    second opinion), so a stem that does not taper, a palm's, is named as a cause."""
    if dbh and h_stem >= MIN_HEIGHT_FOR_FORM_M:
        f = vol / (math.pi / 4.0 * dbh * dbh * h_stem)
        lo, hi = form_factor_range(h_stem)
        if out.get("terminal_crown"):
            hi = FORM_HIGH_SLACK * solid_form_factor(h_stem, 0.0)
        out["stem_form_factor"] = f
        out["stem_form_factor_range"] = [lo, hi]
        what = (
            f"stem form factor {f:.2f} (stem {vol * 1000:.0f} L, DBH "
            f"{dbh * 100:.1f} cm, stem {h_stem:.1f} m tall"
        )
        _outside(
            warns,
            f,
            lo,
            hi,
            high=(
                "form_factor_high",
                what + "; a cylinder is 1.0)",
                (
                    "a palm's stem, which does not taper (the frond model found fronds), or "
                    if fronds
                    else ""
                )
                + "a stem too wide above 1.3 m: ground left in under the stem, radii "
                "held constant or modelled where the stem is hidden",
                "see the stem warnings; " + ground_fix,
            ),
            low=(
                "form_factor_low",
                what + ")",
                DBH_INFLATED + " or a stem that ends low (the leader taken for a branch)",
                "check the stem at 1.3 m and the stem's top in cylinders.csv",
            ),
        )


def _stem_radii(
    z: np.ndarray,
    r: np.ndarray,
    dbh: float | None,
    h_stem: float,
    noise: float,
    out: dict[str, Any],
    warns: list[dict[str, Any]],
) -> None:
    """The stem's radius profile (``r`` at heights ``z``): its taper, the largest rise
    upwards, and the longest stretch over which it is held constant."""
    if dbh and h_stem > BREAST_HEIGHT_M:
        top = z >= h_stem - 1e-9
        r_top = float(r[top].min())
        out["stem_taper_cm_per_m"] = (dbh - 2.0 * r_top) * 100.0 / (h_stem - BREAST_HEIGHT_M)
    rise, tol = _largest_rise(r, noise)
    out["stem_radius_rise_m"] = rise
    if rise > tol:
        warns.append(
            _warning(
                "stem_wider_upwards",
                rise,
                None,
                tol,
                f"the stem's radius grows upwards by {rise * 100:.1f} cm",
                "a circle fitted to a branch whorl, leaves or a neighbour around the stem",
                "look at the stem's radii in cylinders.csv; try --separate-leaves on",
            )
        )
    floor = HOLD_MIN_SHARE * (dbh / 2.0 if dbh else float(r.max()))
    held = _longest_hold(z, r, floor)
    out["stem_radius_held_m"] = held
    if held > HOLD_MAX_M:
        warns.append(
            _warning(
                "stem_radius_held",
                held,
                None,
                HOLD_MAX_M,
                f"the stem's radius is held constant over {held:.1f} m of height",
                "the stem hidden (by needles, leaves or occlusion) between few measured "
                "nodes, so its radius was carried over metres it cannot see",
                SEE_THE_STEM,
            )
        )


def _stem_hidden(
    table: CylinderTable, rows: np.ndarray, out: dict[str, Any], warns: list[dict[str, Any]]
) -> None:
    """The share of the stem's length with measured radii."""
    tags = table.tag
    if (tags == "measured").any():
        length = table.length_m[rows]
        share = float(length[tags[rows] == "measured"].sum() / length.sum())
        out["stem_measured_share"] = share
        if share < STEM_MEASURED_MIN:
            warns.append(
                _warning(
                    "stem_hidden",
                    share,
                    STEM_MEASURED_MIN,
                    1.0,
                    f"only {share * 100:.0f} % of the stem's length has measured radii",
                    "the stem hidden by needles, leaves or occlusion: its radii follow "
                    "the pipe model",
                    SEE_THE_STEM,
                )
            )


def _stem_foot(
    table: CylinderTable,
    rows: np.ndarray,
    dbh: float | None,
    out: dict[str, Any],
    warns: list[dict[str, Any]],
    ground_fix: str,
    points: np.ndarray | None,
    points_origin: np.ndarray | None,
) -> None:
    """The stem's foot: its inclination, its height above the lowest points and the
    spread of the lowest points around it (ground or understory left in)."""
    start, end = table.start[rows], table.end[rows]
    along = np.cumsum(table.length_m[rows])
    run = min(BASE_RUN_M, 0.5 * float(along[-1]))
    k = int(np.searchsorted(along, run))
    k = min(k, len(rows) - 1)
    chord = end[k] - start[0]
    incl = math.degrees(math.atan2(math.hypot(chord[0], chord[1]), chord[2]))
    out["stem_base_inclination_deg"] = incl
    if incl > BASE_MAX_INCLINATION_DEG:
        warns.append(
            _warning(
                "stem_base_not_upright",
                incl,
                None,
                BASE_MAX_INCLINATION_DEG,
                f"the stem's first {run:.1f} m runs {incl:.0f} degrees from vertical",
                "ground left in: the stem starts along the ground or a root",
                ground_fix,
            )
        )
    if points is not None and len(points):
        o = np.zeros(3) if points_origin is None else np.asarray(points_origin, np.float64)
        base = start[0] - o
        zlow = float(points[:, 2].min())
        above = float(base[2] - zlow)
        out["stem_base_above_lowest_m"] = above
        if above > BASE_ABOVE_LOWEST_MAX_M:
            warns.append(
                _warning(
                    "stem_base_above_ground",
                    above,
                    None,
                    BASE_ABOVE_LOWEST_MAX_M,
                    f"the stem's base is {above:.2f} m above the lowest points",
                    "ground or understory left in below the tree",
                    ground_fix,
                )
            )
        if dbh:
            band = points[points[:, 2] <= zlow + BASE_BAND_M]
            d = np.hypot(band[:, 0] - base[0], band[:, 1] - base[1])
            spread = float(np.percentile(d, 95)) / (dbh / 2.0)
            out["base_spread_radii"] = spread
            if spread > BASE_SPREAD_MAX:
                warns.append(
                    _warning(
                        "ground_left_in",
                        spread,
                        None,
                        BASE_SPREAD_MAX,
                        f"the lowest {BASE_BAND_M:.1f} m of points reach "
                        f"{spread:.1f} DBH radii from the stem",
                        "ground, litter or understory left in around the stem's foot",
                        ground_fix,
                    )
                )


def add_plausibility(model: Any, prepared: Any) -> None:
    """Assess a ``TreeModel`` built from ``prepared`` (a ``PreparedCloud``: the points the
    model saw, local) and set ``figures["plausibility"]`` and ``figures["warnings"]``
    (a list, empty when everything is plausible)."""
    result = assess(
        model.cylinders,
        model.figures,
        preparation=model.preparation,
        points=prepared.points,
        points_origin=prepared.frame.origin_array,
    )
    model.figures["plausibility"] = result["figures"]
    model.figures["warnings"] = result["warnings"]
