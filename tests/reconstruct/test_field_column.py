"""Issue 21's generated field case: a tree cut from a scanned plot column (rough sloping
ground, litter, shrubs, neighbours' branches clipped at the column's walls, needle-on or
leaf-on, VZ-400 noise; :mod:`tests.reconstruct.fieldcolumn`), rebuilt with the defaults
(auto leaf separation) and scored against the target's exact cylinder table. Also cheap
checks that the generator makes the scene it claims to."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from treesim.cloud import Cloud
from treesim.models import generate_tree
from treesim.reconstruct import ReconstructParams, reconstruct

from .fieldcolumn import (
    DEFAULT_STEP_DEG,
    KINDS,
    PART_CODES,
    PARTS,
    cached_field_column,
    field_column,
)

#: A coarse step for the generator's own checks: every part is still hit, in seconds.
COARSE_STEP_DEG = 0.25


def _part(labels: np.ndarray, name: str) -> np.ndarray:
    return labels == PART_CODES[name]


def _ground_z(points: np.ndarray, labels: np.ndarray, xy: np.ndarray, k: int = 8) -> np.ndarray:
    """The median height of the ``k`` ground points nearest (in x, y) to each of ``xy``."""
    g = points[_part(labels, "ground")]
    _, idx = cKDTree(g[:, :2]).query(xy, k=k)
    return np.median(g[idx, 2], axis=1)


# ------------------------------------------------------------------ the generator itself


@pytest.mark.parametrize("kind", list(KINDS))
def test_column_holds_every_part_in_plausible_shares(kind):
    truth, pts, labels = cached_field_column(kind, 0, COARSE_STEP_DEG)
    assert pts.dtype == np.float64 and pts.shape == (len(labels), 3)
    assert labels.max() < len(PARTS)
    share = {name: float(_part(labels, name).mean()) for name in PARTS}
    print(kind, {k: round(v, 4) for k, v in share.items()})
    assert 0.2 <= share["ground"] <= 0.8, share
    assert share["target_wood"] >= 0.05, share
    assert share["target_leaf"] >= 0.1, share
    assert share["litter"] >= 0.005, share
    assert share["shrub"] >= 0.002, share
    assert share["neighbour"] >= 0.005, share
    assert truth["part_points"] == {n: int(_part(labels, n).sum()) for n in PARTS}
    # every point inside the square column, from below the ground to above the crown
    col = truth["column"]
    half = col["half_width_m"]
    assert (np.abs(pts[:, :2]) <= half).all()
    assert col["z_min_m"] <= pts[:, 2].min() and pts[:, 2].max() <= col["z_max_m"]
    # the target's exact mesh (the truth's bounds) lies inside, with the margin: the cut
    # clipped none of its crown
    lo, hi = np.asarray(truth["bounds_m"])
    assert (np.abs(np.concatenate([lo[:2], hi[:2]])) <= half - 0.5 * col["margin_m"]).all()
    assert hi[2] < col["z_max_m"]


@pytest.mark.parametrize("kind", list(KINDS))
def test_column_ground_slope_litter_shrubs_and_neighbours_are_where_they_belong(kind):
    truth, pts, labels = cached_field_column(kind, 0, COARSE_STEP_DEG)
    half = truth["column"]["half_width_m"]
    # the ground: a plane of the terrain's slope and aspect, rough by some cm
    g = pts[_part(labels, "ground")]
    a = np.column_stack([g[:, 0], g[:, 1], np.ones(len(g))])
    (gx, gy, _), *_ = np.linalg.lstsq(a, g[:, 2], rcond=None)
    slope = math.degrees(math.atan(math.hypot(gx, gy)))
    aspect = math.degrees(math.atan2(-gx, -gy)) % 360.0  # downhill, compass
    resid = g[:, 2] - a @ np.array([gx, gy, 0.0])
    resid_sd = float(np.std(resid - resid.mean()))
    t = truth["terrain"]
    print(
        kind,
        f"slope {slope:.2f} (truth {t['slope_deg']:.2f}) aspect {aspect:.1f} "
        f"(truth {t['aspect_deg']:.1f}) roughness {resid_sd * 1e3:.1f} mm",
    )
    assert 3.0 <= t["slope_deg"] <= 7.0
    assert abs(slope - t["slope_deg"]) <= 1.0
    assert abs((aspect - t["aspect_deg"] + 180.0) % 360.0 - 180.0) <= 10.0
    assert 0.01 <= resid_sd <= 0.06
    # litter lies on the ground: within 10 cm above the local ground points
    lit = pts[_part(labels, "litter")]
    above = lit[:, 2] - _ground_z(pts, labels, lit[:, :2])
    assert np.quantile(above, 0.02) >= -0.03 and np.quantile(above, 0.98) <= 0.10, np.quantile(
        above, [0.02, 0.5, 0.98]
    )
    # shrubs are low: below 2.5 m over the ground
    sh = pts[_part(labels, "shrub")]
    assert (sh[:, 2] - _ground_z(pts, labels, sh[:, :2]) <= 2.5).all()
    # one shrub at the stem foot (within 1.2 m of the stem axis)
    assert (np.hypot(sh[:, 0], sh[:, 1]) <= 1.2).any()
    # neighbours: branches clipped at the wall, reaching at most 2.5 m into the column
    nb = pts[_part(labels, "neighbour")]
    depth = half - np.abs(nb[:, :2]).max(axis=1)
    assert depth.max() <= 2.5, depth.max()
    # the target's stem foot meets the terrain: its lowest wood point near the stem axis
    # lies within the ground's heights around the stem (uphill side buried)
    w = pts[_part(labels, "target_wood")]
    foot = w[np.hypot(w[:, 0], w[:, 1]) <= 0.5, 2].min()
    ring = g[(np.hypot(g[:, 0], g[:, 1]) > 0.2) & (np.hypot(g[:, 0], g[:, 1]) <= 0.6), 2]
    assert ring.min() - 0.05 <= foot <= ring.max() + 0.05, (foot, ring.min(), ring.max())
    assert abs(foot - truth["base_z_m"]) <= 0.1


@pytest.mark.parametrize("kind", list(KINDS))
def test_column_truth_is_the_targets_own_table(kind):
    truth, _, _ = cached_field_column(kind, 0, COARSE_STEP_DEG)
    own = generate_tree(KINDS[kind].target, seed=0).cylinders.summary()
    for key in ("dbh_m", "height_m", "volume_stem_m3", "volume_total_m3"):
        assert truth[key] == pytest.approx(own[key], rel=1e-9), key
    assert truth["volume_stem_m3"] < truth["volume_total_m3"]


def test_column_seed_reproduces_bit_for_bit():
    a = cached_field_column("conifer", 0, COARSE_STEP_DEG)
    b = field_column("conifer", 0, COARSE_STEP_DEG)
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(a.labels, b.labels)
    assert json.dumps(a.truth, sort_keys=True) == json.dumps(b.truth, sort_keys=True)


def test_column_rejects_an_unknown_kind():
    with pytest.raises(ValueError, match="conifer, broadleaf"):
        field_column("palm")


# ------------------------------------------------------------- the reconstruction (issue 21)


def _errors(truth: dict, fig: dict) -> dict[str, float]:
    return {
        "dbh_mm": (fig["dbh_m"] - truth["dbh_m"]) * 1e3,
        "stem_pct": (fig["volume_stem_m3"] / truth["volume_stem_m3"] - 1) * 100,
        "total_pct": (fig["volume_total_m3"] / truth["volume_total_m3"] - 1) * 100,
    }


@pytest.mark.slow
@pytest.mark.parametrize(
    "kind",
    [
        "conifer",
        "broadleaf",
    ],
)
def test_field_column_rebuilt_with_defaults_meets_issue_21(kind):
    """Issue 21's acceptance on the generated plot column, with the defaults (auto leaf
    separation): DBH within 5 mm, stem volume within 5 %, total within 10 %."""
    truth, pts, _ = cached_field_column(kind, 0, DEFAULT_STEP_DEG)
    model = reconstruct(Cloud(np.array(pts)), ReconstructParams())
    fig = model.figures
    got = _errors(truth, fig)
    ground = [s for s in model.preparation["steps"] if s["step"] == "ground_removal"]
    print(
        kind,
        {k: round(v, 2) for k, v in got.items()},
        "ground removed:",
        ground[0]["removed"] if ground else None,
        "leaf share:",
        fig.get("leaf_share"),
    )
    assert abs(got["dbh_mm"]) <= 5.0, got
    assert abs(got["stem_pct"]) <= 5.0, got
    assert abs(got["total_pct"]) <= 10.0, got
