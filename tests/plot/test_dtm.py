"""The ground of a plot cloud (treesim.plot.dtm): CSF ground, DTM raster, no-ground refusal.

Oracles: the analytic terrain the synthetic scenes are sampled from (a 15° slope plus a
sinusoidal bump), the known label of every synthetic point (ground, stem, shrub, crown).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from tests.conftest import shared_path
from treesim.errors import InputFormatError
from treesim.plot import dtm as D
from treesim.plot._surface import read_asc, surface_from_dtm

SLOPE = np.tan(np.radians(15.0))
HALF_M = 10.0


def terrain_z(x, y):
    return SLOPE * x + 0.3 * np.sin(x / 3.0) * np.cos(y / 4.0)


def _stems(rng, n):
    stems = []
    while len(stems) < n:
        c = rng.uniform(-HALF_M + 1.5, HALF_M - 1.5, 2)
        if all(np.hypot(*(c - s[:2])) > 2.5 for s in stems):
            stems.append((c[0], c[1], rng.uniform(0.1, 0.3), rng.uniform(8, 20)))
    return np.array(stems)


def _ground(rng, stems, per_m2, litter):
    n = int(per_m2 * (2 * HALF_M) ** 2)
    xy = rng.uniform(-HALF_M, HALF_M, (n, 2))
    keep = np.ones(n, bool)
    for _ in range(6):  # density gaps
        keep &= np.hypot(*(xy - rng.uniform(-HALF_M, HALF_M, 2)).T) > rng.uniform(0.5, 1.5)
    for sx, sy, r, _h in stems:  # nothing inside a stem
        keep &= np.hypot(xy[:, 0] - sx, xy[:, 1] - sy) > r
    xy = xy[keep]
    z = terrain_z(xy[:, 0], xy[:, 1]) + rng.normal(0, 0.003, len(xy))
    if litter:  # 30 % of the ground points on leaves 0-5 cm up
        up = rng.random(len(z)) < 0.3
        z[up] += rng.uniform(0, 0.05, up.sum())
    return np.c_[xy, z]


def _stem_points(rng, stems):
    stations = np.array([[-5.0, -5.0], [5.0, 4.0], [0.0, -6.0]])
    out = []
    for sx, sy, r, h in stems:
        a = rng.uniform(0, 2 * np.pi, int(400 * h * r * 2 * np.pi))
        nrm = np.c_[np.cos(a), np.sin(a)]
        seen = (nrm @ (stations - np.array([sx, sy])).T > 0).any(1)  # sides facing a station
        z = terrain_z(sx, sy) - SLOPE * r + rng.uniform(0, h, len(a))
        p = np.c_[sx + r * nrm[:, 0], sy + r * nrm[:, 1], z][seen]
        out.append(p[p[:, 2] > terrain_z(p[:, 0], p[:, 1])])  # none under the ground
    return np.concatenate(out)


def _blobs(rng, stems, n_shrubs):
    shrubs = []
    for _ in range(n_shrubs):
        xy = rng.uniform(-HALF_M + 1, HALF_M - 1, 2) + rng.normal(0, 0.35, (1500, 2))
        shrubs.append(np.c_[xy, terrain_z(xy[:, 0], xy[:, 1]) + rng.uniform(0.2, 1.0, 1500)])
    crowns = []
    for sx, sy, _r, h in stems:
        xy = np.array([sx, sy]) + rng.normal(0, 1.5, (4000, 2))
        z = terrain_z(sx, sy) + rng.uniform(max(8, h - 6), h, 4000)
        crowns.append(np.c_[xy, z][(np.abs(xy) < HALF_M).all(1)])  # cropped to the plot
    return np.concatenate(shrubs), np.concatenate(crowns)


def scene(seed=0, *, ground=True, litter=False, n_stems=8):
    """A 20 m x 20 m plot: {label: points} and the stems (x, y, radius, height)."""
    rng = np.random.default_rng(seed)
    stems = _stems(rng, n_stems)
    parts = {"ground": _ground(rng, stems, 150, litter), "stems": _stem_points(rng, stems)}
    parts["shrubs"], parts["crowns"] = _blobs(rng, stems, 6)
    if not ground:
        del parts["ground"]
    return parts, stems


def _cloud(parts):
    pts = np.concatenate(list(parts.values()))
    label = np.concatenate([np.full(len(v), k) for k, v in parts.items()])
    return pts, label


@pytest.fixture(scope="module")
def plot0():
    parts, stems = scene(0)
    pts, label = _cloud(parts)
    mask, dtm, warnings = D.ground_and_dtm(pts)
    return pts, label, stems, mask, dtm, warnings


def _plot_errors(dtm):
    xs, ys = dtm.centres()
    X, Y = np.meshgrid(xs, ys)
    inside = (np.abs(X) <= HALF_M) & (np.abs(Y) <= HALF_M)
    return (dtm.z - terrain_z(X, Y))[inside]


@pytest.mark.parametrize("seed,litter", [(0, False), (1, True)])
def test_dtm_follows_the_true_terrain_over_the_plot_and_under_every_stem(seed, litter, plot0):
    if seed == 0:
        pts, label, stems, mask, dtm, warnings = plot0
    else:
        parts, stems = scene(seed, litter=litter)
        pts, label = _cloud(parts)
        mask, dtm, warnings = D.ground_and_dtm(pts)
    err = _plot_errors(dtm)
    under = dtm.height_at(stems[:, 0], stems[:, 1]) - terrain_z(stems[:, 0], stems[:, 1])
    print(f"p95 {np.percentile(np.abs(err), 95):.4f} m, median {np.median(err):.4f} m, "
          f"under stems max {np.abs(under).max():.4f} m")  # fmt: skip
    assert np.percentile(np.abs(err), 95) < 0.05
    assert np.abs(under).max() < 0.05
    assert dtm.coverage > 0.9 and warnings == []


def test_stems_shrubs_and_crowns_are_not_ground(plot0):
    pts, label, _stems, mask, _dtm, _w = plot0
    h = pts[:, 2] - terrain_z(pts[:, 0], pts[:, 1])
    for part in ("stems", "shrubs", "crowns"):
        high = (label == part) & (h > 0.5)
        assert mask[high].mean() < 0.01, part
    assert mask[label == "ground"].mean() > 0.95


def test_asc_round_trips_bit_for_bit_at_cell_centres(plot0, tmp_path):
    dtm = plot0[4]
    path = dtm.write_asc(tmp_path / "dtm.asc")
    xs, ys, z = read_asc(path)
    assert np.array_equal(z, dtm.z.T)
    X, Y = np.meshgrid(xs, ys)
    assert np.array_equal(surface_from_dtm(path)(X, Y), dtm.height_at(X, Y))
    assert np.array_equal(dtm.height_at(X, Y), dtm.z)


def test_a_cloud_at_a_projected_offset_gives_the_same_dtm_shifted(plot0):
    pts, _label, _stems, mask, dtm, _w = plot0
    shift = np.array([5e6, 5e6, 300.0])
    mask2, dtm2, _ = D.ground_and_dtm(pts + shift)
    assert (mask2 != mask).mean() < 1e-3
    assert dtm2.shape == dtm.shape
    assert dtm2.x0_m - dtm.x0_m == 5e6 and dtm2.y0_m - dtm.y0_m == 5e6
    np.testing.assert_allclose(dtm2.z - 300.0, dtm.z, atol=1e-6)


def test_same_cloud_same_mask(plot0):
    pts, _label, _stems, mask, _dtm, _w = plot0
    assert np.array_equal(D.classify_ground(pts), mask)


def test_a_cloud_without_its_ground_is_refused_in_words():
    pts, _ = _cloud(scene(0, ground=False)[0])
    with pytest.raises(InputFormatError, match="no ground found under the plot") as err:
        D.ground_and_dtm(pts)
    assert "cropped" in str(err.value) and "Traceback" not in str(err.value)


def test_csf_prints_nothing(capfd):
    pts, _ = _cloud(scene(2, n_stems=3)[0])
    D.classify_ground(pts)
    out, errs = capfd.readouterr()
    assert out == "" and errs == ""


@pytest.mark.slow
def test_a_plot_in_feet_does_not_crash():
    pts, _ = _cloud(scene(3, n_stems=3)[0])
    mask, dtm, _ = D.ground_and_dtm(pts * 3.2808)
    assert mask.any() and np.isfinite(dtm.z).all()


def test_a_single_tree_with_a_little_ground_gets_a_small_correct_dtm():
    parts, stems = scene(4, n_stems=1)
    sx, sy = stems[0, :2]
    g = parts["ground"]
    near = np.hypot(g[:, 0] - sx, g[:, 1] - sy) < 2.5
    pts = np.concatenate([g[near], parts["stems"], parts["crowns"]])
    keep = np.hypot(pts[:, 0] - sx, pts[:, 1] - sy) < 4.0
    try:
        mask, dtm, _ = D.ground_and_dtm(pts[keep])
    except InputFormatError as err:  # a clear refusal is acceptable
        assert "no ground found" in str(err)
        return
    under = dtm.height_at(sx, sy) - terrain_z(sx, sy)
    assert abs(float(under)) < 0.05


@pytest.mark.shared_data
def test_the_treels_pine_plot_has_a_dtm_and_its_stems_are_not_ground():
    import laspy

    las = laspy.read(shared_path("plots", "treels_pine_plot", "pine_plot.laz"))
    pts = np.c_[las.x, las.y, las.z].astype(np.float64)
    t0 = time.perf_counter()
    mask, dtm, warnings = D.ground_and_dtm(pts)
    took_s = time.perf_counter() - t0
    h = D.heights_above_ground(pts, dtm)
    print(
        f"pine plot: {len(pts)} points, {mask.mean():.1%} ground, {took_s:.2f} s, {dtm.figures()}"
    )
    assert dtm.coverage > 0.7 and warnings == []
    assert mask[h > 1.5].mean() < 0.005
    assert np.mean(h < -0.5) < 0.005
