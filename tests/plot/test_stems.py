"""Stems, DBH and tree labels of a field plot (treesim.plot.stems) against analytic truth.

The synthetic plot is built here, with its truth exact by construction: a 15°-sloped ground
plane, leaning tapered stems scanned only on the sides five stations see (3 mm noise),
crowns of branch segments and leaf blobs that touch their neighbours', shrubs beside stems,
heights above ground from the known plane.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from tests.conftest import shared_path
from treesim.errors import InputFormatError, InvalidParameterError
from treesim.plot.stems import (
    LOW_REACH_M,
    Stem,
    StemParams,
    detect_stems,
    segment_trees,
    tree_heights,
)

SLOPE_DEG = 15.0
STATIONS_XY = [(0.0, 0.0), (7.0, 5.0), (-7.0, 5.0), (-6.0, -6.0), (6.0, -6.0)]


def _ground_z(xy: np.ndarray) -> np.ndarray:
    return 100.0 + math.tan(math.radians(SLOPE_DEG)) * xy[..., 0]


def _positions(rng, n: int, radius_m: float, spacing_m: float) -> np.ndarray:
    out: list[np.ndarray] = []
    while len(out) < n:
        p = rng.uniform(-radius_m, radius_m, 2)
        if np.hypot(*p) > radius_m:
            continue
        if any(np.hypot(*(p - q)) < spacing_m for q in out):
            continue
        if any(np.hypot(*(p - np.array(s))) < 1.0 for s in STATIONS_XY):
            continue
        out.append(p)
    return np.array(out)


def _frame(lean_deg: float, az: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    le = math.radians(lean_deg)
    a = np.array([math.sin(le) * math.cos(az), math.sin(le) * math.sin(az), math.cos(le)])
    u = np.cross(a, [0.0, 0.0, 1.0]) if lean_deg > 0 else np.array([1.0, 0.0, 0.0])
    u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-9 else np.array([1.0, 0.0, 0.0])
    return a, u, np.cross(a, u)


def _stem_points(rng, base, a, u, v, r13, height, density=1000.0):
    """Bark seen from the stations (outward normal facing one), 3 mm noise; and a leader
    in pieces."""
    t_top = 0.9 * height
    n = int(density * 2 * math.pi * r13 * 0.8 * (t_top + 0.3))
    t = rng.uniform(-0.3, t_top, n)
    th = rng.uniform(0, 2 * math.pi, n)
    r = r13 * (1.0 - 0.5 * (t - 1.3) / height) + rng.normal(0, 0.003, n)
    nrm = np.cos(th)[:, None] * u + np.sin(th)[:, None] * v
    p = base + t[:, None] * a + r[:, None] * nrm
    st = np.array([[x, y, _ground_z(np.array([x, y])) + 1.5] for x, y in STATIONS_XY])
    seen = (np.einsum("nk,mnk->mn", nrm, st[:, None, :] - p[None, :, :]) > 0).any(axis=0)
    # the leader seen in pieces (the needles and twigs around it hide the rest): 15 cm
    # seen, 45 cm hidden, wider gaps than the tree graph's links (the real scans' sparse
    # tops were left out of their trees)
    tl = np.arange(t_top, height, 0.01)
    tl = tl[(tl - t_top) % 0.6 < 0.15]
    leader = base + tl[:, None] * a + rng.normal(0, 0.005, (len(tl), 3))
    return p[seen], leader


def _crown(rng, base, a, height, reach_m):
    """Branches (2 cm spaced points, 1 cm noise) with a leaf blob at each tip, reaching at
    most ``reach_m`` out (crowns touch their neighbours': 0.6 of the spacing)."""
    cb, crown_r = 0.55 * height, min(1.3 + 0.1 * height, reach_m)
    parts = []
    for _ in range(20):
        t0 = rng.uniform(cb, 0.95 * height)
        length = crown_r * (1.0 - 0.6 * (t0 - cb) / (height - cb)) * rng.uniform(0.6, 1.0)
        az, el = rng.uniform(0, 2 * np.pi), math.radians(rng.uniform(5, 40))
        d = np.array([math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), math.sin(el)])
        length = min(length, (0.99 * height - t0) / max(d[2], 1e-3))
        s = np.arange(0, length, 0.02)
        parts.append(base + t0 * a + s[:, None] * d + rng.normal(0, 0.01, (len(s), 3)))
        tip = base + t0 * a + length * d
        blob = tip + rng.normal(0, 0.15, (150, 3))
        parts.append(blob[blob[:, 2] < base[2] + height])
    return np.vstack(parts)


def _shrub(rng, centre_xy, h_m):
    n = 1500
    p = rng.normal(0, 1, (n, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    p *= rng.uniform(0, 1, n)[:, None] ** (1 / 3)
    p *= np.array([0.5, 0.5, h_m / 2])
    xy = centre_xy + p[:, :2]
    return np.column_stack([xy, _ground_z(xy) + h_m / 2 + p[:, 2]])


def make_plot(seed=7, n_trees=30, radius_m=15.0, n_shrubs=8, with_trees=True):
    """A plot cloud and its truth (see the module docstring)."""
    rng = np.random.default_rng(seed)
    xy = _positions(rng, n_trees, radius_m, 2.0) if with_trees else np.zeros((0, 2))
    parts, kind, tree = [], [], []
    truth = []
    for i, (x, y) in enumerate(xy):
        dbh = rng.uniform(0.08, 0.45)
        height = rng.uniform(8.0, 25.0)
        lean = rng.uniform(0, 5.0)
        a, u, v = _frame(lean, rng.uniform(0, 2 * np.pi))
        base = np.array([x, y, float(_ground_z(np.array([x, y])))])
        bark, leader = _stem_points(rng, base, a, u, v, dbh / 2, height)
        spacing = np.delete(np.hypot(*(xy - xy[i]).T), i).min(initial=10.0)
        crown = _crown(rng, base, a, height, 0.6 * spacing)
        for p, k in ((bark, 1), (leader, 2), (crown, 2)):
            parts.append(p)
            kind.append(np.full(len(p), k))
            tree.append(np.full(len(p), i))
        at13 = base + a * (1.3 / a[2])
        truth.append((at13[0], at13[1], dbh, height, lean, *base))
    for j in range(n_shrubs):
        if with_trees and j % 2 == 0:  # beside a stem
            k = rng.integers(len(xy))
            ang = rng.uniform(0, 2 * np.pi)
            c = xy[k] + rng.uniform(0.6, 1.2) * np.array([math.cos(ang), math.sin(ang)])
        else:
            c = rng.uniform(-0.7 * radius_m, 0.7 * radius_m, 2)
        p = _shrub(rng, c, rng.uniform(0.3, 1.5))
        parts.append(p)
        kind.append(np.full(len(p), 3))
        tree.append(np.full(len(p), -1))
    g = rng.uniform(-radius_m - 1, radius_m + 1, (int(80 * (2 * radius_m + 2) ** 2), 2))
    g = g[np.hypot(g[:, 0], g[:, 1]) < radius_m + 1]
    gz = _ground_z(g) + rng.normal(0, 0.01, len(g))
    parts.append(np.column_stack([g, gz]))
    kind.append(np.zeros(len(g), int))
    tree.append(np.full(len(g), -1))
    pts = np.vstack(parts)
    hag = pts[:, 2] - _ground_z(pts[:, :2])
    kind, tree = np.concatenate(kind), np.concatenate(tree)
    keep = (hag >= 0) | (kind == 0)  # nothing grows below the ground
    pts, hag, kind, tree = pts[keep], hag[keep], kind[keep], tree[keep]
    t = np.array(truth).reshape(-1, 8)
    top = np.array([hag[tree == i].max() for i in range(len(t))])
    return {"points": pts, "hag": hag, "kind": kind, "tree": tree, "truth": t, "top": top}


def _match(stems: list[Stem], truth: np.ndarray, tol_m: float = 0.1) -> dict[int, int]:
    """True stem index -> detection index, nearest within ``tol_m``."""
    if not stems:
        return {}
    found = np.array([[s.x_m, s.y_m] for s in stems])
    out = {}
    for i, (x, y) in enumerate(truth[:, :2]):
        d = np.hypot(found[:, 0] - x, found[:, 1] - y)
        if d.min() <= tol_m:
            out[i] = int(np.argmin(d))
    return out


@pytest.fixture(scope="module")
def plot():
    return make_plot()


@pytest.fixture(scope="module")
def found(plot):
    t0 = time.perf_counter()
    stems, warnings = detect_stems(plot["points"], plot["hag"])
    t1 = time.perf_counter()
    labels = segment_trees(plot["points"], plot["hag"], stems, ground=plot["kind"] == 0)
    t2 = time.perf_counter()
    print(f"\n{len(plot['points'])} points: detect {t1 - t0:.1f} s, segment {t2 - t1:.1f} s")
    return stems, warnings, labels


def test_stems_detected_where_they_stand(plot, found) -> None:
    """>= 95 % of stems with DBH >= 10 cm found, none invented, positions within 10 cm,
    DBH within 1 cm, base within 5 cm, lean within 2°."""
    stems, _, _ = found
    truth = plot["truth"]
    m = _match(stems, truth)
    big = np.flatnonzero(truth[:, 2] >= 0.10)
    rate = np.mean([i in m for i in big])
    assert rate >= 0.95, f"only {rate:.0%} of the stems >= 10 cm found"
    assert len(set(m.values())) == len(m), "one detection matched to two stems"
    assert len(stems) == len(m), f"{len(stems) - len(m)} stems invented"
    pos = np.array(
        [np.hypot(stems[j].x_m - truth[i, 0], stems[j].y_m - truth[i, 1]) for i, j in m.items()]
    )
    dbh = np.array([stems[j].dbh_m - truth[i, 2] for i, j in m.items()])
    base = np.array([np.subtract(stems[j].base_xyz_m, truth[i, 5:8]) for i, j in m.items()])
    lean = np.array([stems[j].lean_deg - truth[i, 4] for i, j in m.items()])
    print(
        f"found {len(m)}/{len(truth)}; position max {pos.max() * 100:.1f} cm; DBH error "
        f"max {np.abs(dbh).max() * 100:.2f} cm, mean {dbh.mean() * 100:+.2f} cm; base max "
        f"{np.abs(base).max() * 100:.1f} cm; lean max {np.abs(lean).max():.1f}°"
    )
    assert pos.max() <= 0.10
    assert np.abs(dbh).max() <= 0.01
    assert np.abs(base).max() <= 0.05
    assert np.abs(lean).max() <= 2.0


def test_each_stem_labelled_with_its_tree(plot, found) -> None:
    """>= 90 % of each found tree's bark points carry that tree's label."""
    stems, _, labels = found
    m = _match(stems, plot["truth"])
    bark = plot["kind"] == 1
    shares = {}
    for i, j in m.items():
        own = bark & (plot["tree"] == i)
        shares[i] = float(np.mean(labels[own] == j + 1))
    worst = min(shares, key=shares.get)
    print(
        f"bark labelled with its tree: worst {shares[worst]:.1%}, mean "
        f"{np.mean(list(shares.values())):.1%}"
    )
    assert shares[worst] >= 0.90, f"tree {worst}: {shares[worst]:.0%} of its stem points"
    assert not labels[plot["kind"] == 0].any(), "ground points labelled as trees"
    crown = plot["kind"] == 2
    right = np.mean(
        [
            labels[p] == m[t] + 1
            for p, t in zip(np.flatnonzero(crown), plot["tree"][crown], strict=True)
            if t in m
        ]
    )
    print(f"crown and leader points with their own tree: {right:.1%}")


def test_shrubs_beside_stems_stay_understory(plot, found) -> None:
    """A shrub point is labelled with a tree only within LOW_REACH_M of that tree's axis."""
    stems, _, labels = found
    shrub = np.flatnonzero(plot["kind"] == 3)
    lab = labels[shrub]
    assert len(shrub) > 0
    for k in np.unique(lab[lab > 0]):
        s = stems[k - 1]
        p = plot["points"][shrub[lab == k]]
        h = plot["hag"][shrub[lab == k]]
        base = np.array(s.base_xyz_m[:2])
        axis = base + np.outer(h / 1.3, np.array([s.x_m, s.y_m]) - base)
        assert np.hypot(*(p[:, :2] - axis).T).max() <= LOW_REACH_M + 1e-9
    print(f"shrub points labelled with a tree: {np.mean(lab > 0):.1%}")


def test_tree_heights_within_half_a_metre(plot, found) -> None:
    stems, _, labels = found
    m = _match(stems, plot["truth"])
    heights = tree_heights(plot["hag"], labels, len(stems))
    err = np.array([heights[j] - plot["top"][i] for i, j in m.items()])
    print(f"height error: max {np.abs(err).max():.2f} m, mean {err.mean():+.2f} m")
    assert np.abs(err).max() <= 0.5


def test_offset_cloud_gives_the_same_stems_shifted(plot, found) -> None:
    shift = np.array([5e6, 5e6, 300.0])
    stems, _, _ = found
    moved, _ = detect_stems(plot["points"] + shift, plot["hag"])
    assert len(moved) == len(stems)
    for a, b in zip(stems, moved, strict=True):
        assert b.x_m - a.x_m == pytest.approx(shift[0], abs=1e-4)
        assert b.y_m - a.y_m == pytest.approx(shift[1], abs=1e-4)
        assert np.allclose(np.subtract(b.base_xyz_m, a.base_xyz_m), shift, atol=1e-4)
        assert b.dbh_m == pytest.approx(a.dbh_m, abs=1e-4)


def test_one_tree_gives_one_stem() -> None:
    p = make_plot(seed=3, n_trees=1, radius_m=4.0, n_shrubs=2)
    stems, warnings = detect_stems(p["points"], p["hag"])
    assert len(stems) == 1, warnings
    s, t = stems[0], p["truth"][0]
    assert math.hypot(s.x_m - t[0], s.y_m - t[1]) <= 0.1
    assert s.dbh_m == pytest.approx(t[2], abs=0.01)
    labels = segment_trees(p["points"], p["hag"], stems, ground=p["kind"] == 0)
    assert tree_heights(p["hag"], labels, 1)[0] == pytest.approx(p["top"][0], abs=0.5)


def test_no_stems_gives_an_empty_list_and_a_warning() -> None:
    p = make_plot(seed=5, n_trees=0, radius_m=6.0, n_shrubs=6, with_trees=False)
    stems, warnings = detect_stems(p["points"], p["hag"])
    assert stems == []
    assert warnings and "no tree stems" in warnings[0]
    assert not segment_trees(p["points"], p["hag"], stems).any()
    flat, w = detect_stems(np.zeros((10, 3)), np.zeros(10))
    assert flat == [] and "above the ground" in w[0]


def test_bad_inputs_and_parameters_are_refused() -> None:
    with pytest.raises(InputFormatError, match="height above ground per point"):
        detect_stems(np.zeros((5, 3)), np.zeros(4))
    with pytest.raises(InputFormatError, match=r"\(n, 3\)"):
        detect_stems(np.zeros((5, 2)), np.zeros(5))
    with pytest.raises(InvalidParameterError, match="top"):
        StemParams(stripe_low_m=3.0, stripe_high_m=1.0)
    with pytest.raises(InvalidParameterError, match="breast height"):
        StemParams(stripe_low_m=1.5)
    with pytest.raises(InputFormatError, match="ground mask"):
        segment_trees(np.zeros((5, 3)), np.zeros(5), [], ground=np.zeros(3, bool))


def test_tree_heights_ignore_a_stray_point() -> None:
    h = np.array([0.5, 9.6, 9.8, 9.9, 10.0, 14.0, 3.0])
    lab = np.array([1, 1, 1, 1, 1, 1, 0])
    out = tree_heights(h, lab, 2)
    assert out[0] == pytest.approx(10.0)
    assert np.isnan(out[1])


def _kasa(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic (Kasa) circle fit: x² + y² + D x + E y + F = 0 by linear least squares."""
    o = xy.mean(axis=0)
    q = xy - o
    a = np.column_stack([q, np.ones(len(q))])
    (d, e, f), *_ = np.linalg.lstsq(a, -(q**2).sum(axis=1), rcond=None)
    c = np.array([-d / 2, -e / 2])
    return c + o, float(np.sqrt(max(c @ c - f, 0.0)))


@pytest.mark.shared_data
def test_pine_plot_stems_agree_with_a_simple_slab_fit() -> None:
    """The TreeLS pine plot (10 m x 10 m, ~114k points): its stems, each DBH against a Kasa
    circle of the 10 cm slab at 1.3 m around it (an independent, simpler fit)."""
    from treesim.io import read_cloud
    from treesim.plot.dtm import ground_and_dtm, heights_above_ground

    cloud = read_cloud(shared_path("plots", "treels_pine_plot", "pine_plot.laz"))
    pts = cloud.points
    ground, dtm, _ = ground_and_dtm(pts)
    hag = heights_above_ground(pts, dtm)
    t0 = time.perf_counter()
    stems, warnings = detect_stems(pts, hag)
    labels = segment_trees(pts, hag, stems, ground=ground)
    heights = tree_heights(hag, labels, len(stems))
    print(f"\npine plot: {len(stems)} stems in {time.perf_counter() - t0:.1f} s; {warnings}")
    assert len(stems) >= 12
    slab = np.abs(hag - 1.3) <= 0.05
    diffs = []
    for s, h in zip(stems, heights, strict=True):
        near = slab & (np.hypot(pts[:, 0] - s.x_m, pts[:, 1] - s.y_m) <= s.dbh_m / 2 + 0.05)
        _, r = _kasa(pts[near, :2])
        diffs.append(s.dbh_m - 2 * r)
        print(
            f"  ({s.x_m:.2f}, {s.y_m:.2f}) DBH {s.dbh_m * 100:.1f} cm (Kasa "
            f"{2 * r * 100:.1f} cm, arc {s.arc_deg:.0f}°), height {h:.1f} m"
        )
    diffs = np.array(diffs)
    seen = np.array([s.arc_deg >= 180 for s in stems])
    assert np.median(np.abs(diffs[seen])) <= 0.01
    assert np.abs(diffs[seen]).max() <= 0.03
    assert 0.05 <= min(s.dbh_m for s in stems) and max(s.dbh_m for s in stems) <= 0.6
    assert np.nanmax(heights) <= 25.0
