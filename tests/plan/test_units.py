"""Known-answer tests of the planner's parts: visibility of an analytic scene, the set
cover on hand-made matrices, the DBH band on a cylinder, field-time arithmetic."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from treesim.errors import InvalidParameterError
from treesim.params import INSTRUMENTS, ScannerSpec, instrument
from treesim.plan import (
    Objective,
    PlanParams,
    SampleSet,
    TreeTarget,
    VisibilityCaster,
    improve,
    lazy_greedy,
    max_spacing_ok,
    sample_trees,
    visibility,
)
from treesim.plan.cover import default_quality, reachable_trees, state
from treesim.plan.visibility import hit_probability, intensity_of
from treesim.scene import MeshPart, Scene


def _part(mesh: trimesh.Trimesh, name: str, tree_id: int = 0) -> MeshPart:
    return MeshPart(np.asarray(mesh.vertices), np.asarray(mesh.faces), "wood", name, tree_id)


def _cylinder(x: float, y: float, r: float = 0.3, h: float = 2.0) -> trimesh.Trimesh:
    c = trimesh.creation.cylinder(radius=r, height=h, sections=256)
    c.apply_translation((x, y, h / 2))
    return c


def _sample_set(points: np.ndarray, normals: np.ndarray) -> SampleSet:
    n = len(points)
    return SampleSet(
        points=np.asarray(points, float),
        normals=np.asarray(normals, float),
        tree_ids=np.array([1]),
        tree_of=np.zeros(n, np.int64),
        band=np.zeros(n, bool),
        block_starts=np.array([0]),
        block_tree=np.array([0]),
        block_sector=np.array([-1]),
        n_sectors=np.array([0]),
        stem_xy=np.full((1, 2), np.nan),
        stem_radius_m=np.full(1, np.nan),
        hidden_dropped=np.zeros(1, np.int64),
        arc_bin_deg=10.0,
    )


# -- visibility: a box in front of one cylinder, a second cylinder beside it ------------
# Station at (0, 0, 1). The box x 3..4, |y| <= 0.5, z 0..2 hides every direction with
# |y/x| <= 0.5/3 at that height; cylinder C1 at (7, 0) lies in its shadow, C2 at (7, 2)
# (direction y/x = 0.29) does not.
STATION = np.array([[0.0, 0.0, 1.0]])


def _scene() -> Scene:
    box = trimesh.creation.box(extents=(1, 1, 2))
    box.apply_translation((3.5, 0, 1))
    return Scene([_part(box, "box"), _part(_cylinder(7, 0), "c1"), _part(_cylinder(7, 2), "c2")])


def _front(cx: float, cy: float, r: float = 0.3, turn_deg: float = 0.0):
    """Point of the cylinder at (cx, cy) facing the station, turned by ``turn_deg``
    about its axis, at z = 1, and its outward normal."""
    a = math.atan2(-cy, -cx) + math.radians(turn_deg)
    n = np.array([math.cos(a), math.sin(a), 0.0])
    return np.array([cx, cy, 1.0]) + r * n, n


def _samples() -> SampleSet:
    pts, nrm = [], []
    for cx, cy, turn in ((7, 0, 0), (7, 2, 0), (7, 2, 180), (7, 2, 60)):
        p, n = _front(cx, cy, turn_deg=turn)
        pts.append(p)
        nrm.append(n)
    pts.append(np.array([3.0, 0.2, 1.0]))  # on the box's front face
    nrm.append(np.array([-1.0, 0, 0]))
    return _sample_set(np.array(pts), np.array(nrm))


def test_visibility_of_an_analytic_scene():
    samples = _samples()
    caster = VisibilityCaster(_scene(), samples, nthreads=1)
    fine = ScannerSpec(horizontal_resolution_deg=0.01, vertical_resolution_deg=0.01)
    q = visibility(caster, STATION, fine, 0.01).quality[0]
    # C1 behind the box: hidden; C2's front: seen at normal incidence; C2's back: hidden by
    # C2 itself; C2 turned 60°: seen at cos ~ 0.5 (incidence from the station ~ 60°+); box: seen
    assert q[0] == 0
    assert q[1] >= 253
    assert q[2] == 0
    p, n = _front(7, 2, turn_deg=60)
    d = p - STATION[0]
    cos_exact = abs(n @ d) / np.linalg.norm(d)
    assert abs(q[3] / 255 - cos_exact) < 0.01
    assert q[4] >= 250
    # thickness: the cylinder samples' inward rays cross the cylinder (0.6 m), the box 1 m
    assert caster.thickness_m[1] == pytest.approx(0.6, abs=1e-3)
    assert caster.thickness_m[4] == pytest.approx(1.0, abs=1e-3)


def test_visibility_hit_probability_and_range():
    samples = _samples()
    caster = VisibilityCaster(_scene(), samples, nthreads=1)
    # step 0.003 rad, τ = 1 cm: at 3 m (the box, a = 9 mm, b = a / cos i) the half-diagonal
    # is 6.4 mm: sure to hit; at 7.3 m (C2's front, normal incidence, a = 21.9 mm > 2τ)
    # one station hits within τ with the share of the cell a disc of radius τ covers
    step = 0.003
    coarse = ScannerSpec(
        horizontal_resolution_deg=math.degrees(step), vertical_resolution_deg=math.degrees(step)
    )
    vis = visibility(caster, STATION, coarse, 0.01)
    p = vis.probability[0]
    assert p[4] == pytest.approx(1.0, abs=2e-6)
    r = np.linalg.norm(samples.points[1] - STATION[0])
    a = r * step
    assert 2 * 0.01 < a
    assert p[1] == pytest.approx(math.pi * 0.01**2 / (a * a), rel=1e-5)
    # C2 turned 60°: b = a / cos i, the same formula
    d = samples.points[3] - STATION[0]
    cos_i = abs(samples.normals[3] @ d) / np.linalg.norm(d)
    a3 = np.linalg.norm(d) * step
    assert p[3] == pytest.approx(math.pi * 0.01**2 * cos_i / (a3 * a3), rel=1e-4)
    # hidden: 0; intensity is −ln(1 − p), float32; quality where p > 0
    assert p[0] == 0 and p[2] == 0
    assert vis.intensity.dtype == np.float32
    assert vis.intensity[0, 1] == pytest.approx(-math.log(1 - p[1]), rel=1e-6)
    assert ((vis.quality[0] > 0) == (p > 0)).all()
    # max range 5 m: the box only; min range 5 m: the cylinders only
    fine = ScannerSpec(horizontal_resolution_deg=0.01, vertical_resolution_deg=0.01)
    q = visibility(caster, STATION, fine.with_(max_range_m=5.0), 0.01).quality[0]
    assert (q > 0).tolist() == [False, False, False, False, True]
    q = visibility(caster, STATION, fine.with_(min_range_m=5.0), 0.01).quality[0]
    assert (q > 0).tolist() == [False, True, False, True, False]


def test_hit_probability_formula():
    tau, step = 0.01, 0.001
    # coarse grid: π τ² / (a b); a = 30 mm at 30 m, b = a / cos 60° = 60 mm
    p = hit_probability(np.array([30.0]), np.array([0.5]), step, tau)[0]
    assert p == pytest.approx(math.pi * tau**2 / (0.03 * 0.06))
    # p == 1 exactly where the half-diagonal rule holds (a = 10 mm: b <= 17.3 mm)
    cos = np.array([0.58, 0.57])
    assert (hit_probability(np.full(2, 10.0), cos, step, tau) == 1.0).tolist() == [True, False]
    assert max_spacing_ok(np.full(2, 10.0), cos, step, tau).tolist() == [True, False]
    # in between (a < 2τ < b) the discs overlap: a Monte Carlo of the lattice agrees, and
    # π τ² / (a b) would overstate it
    rng = np.random.default_rng(0)
    a, b = 0.005, 0.05
    xy = rng.uniform(0, 1, (200_000, 2)) * (a, b)
    near = np.stack(np.meshgrid([-1, 0, 1, 2], [-1, 0, 1, 2]), -1).reshape(-1, 2) * (a, b)
    dmin = np.min(np.linalg.norm(xy[:, None] - near[None], axis=2), axis=1)
    p = hit_probability(np.array([5.0]), np.array([a / b]), step, tau)[0]
    assert p == pytest.approx((dmin <= tau).mean(), abs=0.005)
    assert p < 0.5 * math.pi * tau**2 / (a * b)


def test_thin_feature_rule():
    # a twig 5 mm wide at a = 25 mm: hit once per a²/w = 125 mm of its length; covered
    # within ±τ along it: p = 2 τ w / a² = 0.16; at a = 10 mm hits are 20 mm apart <= 2τ
    tau, w = 0.01, 0.005
    p = hit_probability(np.array([25.0]), np.ones(1), 0.001, tau, np.array([w]))[0]
    assert p == pytest.approx(2 * tau * w / 0.025**2)
    p = hit_probability(np.array([10.0]), np.ones(1), 0.001, tau, np.array([w]))[0]
    assert p == 1.0
    # seen from k stations at the same geometry: expected coverage 1 − (1 − p)^k, by the
    # sum of intensities, for a tree of such samples
    p = 0.16
    obj = Objective(_sample_set(np.zeros((5, 3)), np.zeros((5, 3))), 0.9, 0.0)
    lam = np.tile(intensity_of(np.full(5, p)), (4, 1))
    for k in range(1, 5):
        cov = obj.figures(lam[:k].sum(axis=0))["coverage"][0, 0]
        assert cov == pytest.approx(1 - (1 - p) ** k, rel=1e-6)
    # adding and removing a station: sums; certain and never (a measured cloud)
    lam_all = lam.sum(axis=0, dtype=np.float64)
    assert obj.figures(lam_all - lam[0])["coverage"][0, 0] == pytest.approx(1 - (1 - p) ** 3)
    seen = np.array([np.inf, np.inf, 0, np.inf, 0])
    assert obj.figures(seen)["coverage"][0, 0] == pytest.approx(0.6)


# -- set cover on hand-made matrices ------------------------------------------------------
def _matrix(rows: list[set[int]], n: int, p: float = 1.0) -> np.ndarray:
    """Intensities: each row hits its samples with probability ``p`` (1: surely)."""
    lam = np.zeros((len(rows), n), np.float32)
    for i, r in enumerate(rows):
        lam[i, sorted(r)] = intensity_of(p)
    return lam


def test_greedy_then_swaps_on_the_classic_trap():
    # A = {0,1,2,3} is the greedy's first pick; B = {0,1,4} and C = {2,3,5} cover all
    obj = Objective(_sample_set(np.zeros((6, 3)), np.zeros((6, 3))), 1.0, 0.0)
    q = _matrix([{0, 1, 2, 3}, {0, 1, 4}, {2, 3, 5}], 6)
    reach = reachable_trees(obj, q)
    assert reach.tolist() == [True]
    g = lazy_greedy(obj, q, 10, reachable=reach)
    assert g.chosen[0] == 0 and len(g.chosen) == 3 and g.stop_reason == "goal met"
    assert g.gains[0] == pytest.approx(4 / 6, abs=1e-5)
    better = improve(obj, q, g, reachable=reach)
    assert sorted(better.chosen) == [1, 2]


def test_swap_needed_to_drop_a_station():
    # 10 samples; greedy takes A (6 new), D (3 new), C (1 new); B and C cover all. No
    # station of the greedy's can simply go: dropping C (the least loss) leaves {A, D}, a
    # local optimum of single swaps (9 of 10); dropping A leaves {D, C}, and the swap
    # D -> B reaches the goal with two stations
    rows = [{0, 1, 2, 3, 4, 5}, {0, 1, 2, 6, 7}, {3, 4, 5, 8, 9}, {6, 7, 8}, {9}]
    obj = Objective(_sample_set(np.zeros((10, 3)), np.zeros((10, 3))), 1.0, 0.0)
    q = _matrix(rows, 10)
    reach = reachable_trees(obj, q)
    g = lazy_greedy(obj, q, 10, reachable=reach)
    assert g.chosen[:2] == [0, 3] and len(g.chosen) == 3
    better = improve(obj, q, g, reachable=reach)
    assert sorted(better.chosen) == [1, 2]
    assert better.swaps >= 1


def test_greedy_on_hit_probabilities():
    # 4 samples, goal 0.7. A and B hit every sample with p = ½ (each alone: 0.5); C hits
    # samples 0, 1 surely and 2 with p = 0.2 (0.55). No station alone reaches the goal;
    # C then A (or B) gives (1 + 1 + (1 − 0.8·0.5) + 0.5) / 4 = 0.775, A and B together
    # 1 − ¼ = 0.75. A 0/1 rule ("seen when p = 1") would call the goal unreachable.
    obj = Objective(_sample_set(np.zeros((4, 3)), np.zeros((4, 3))), 0.7, 0.0)
    p = np.array([[0.5] * 4, [0.5] * 4, [1.0, 1.0, 0.2, 0.0]])
    lam = intensity_of(p)
    assert reachable_trees(obj, lam).tolist() == [True]
    assert reachable_trees(obj, intensity_of(np.where(p >= 1, 1.0, 0.0))).tolist() == [False]
    q = default_quality(lam, None)
    assert obj.figures(*state(lam, q, [0, 1]))["coverage"][0, 0] == pytest.approx(0.75)
    g = lazy_greedy(obj, lam, 10)
    assert g.chosen[0] == 2 and g.chosen[1] in (0, 1) and g.stop_reason == "goal met"
    assert g.gains[0] == pytest.approx(0.55 / 0.7, rel=1e-5)
    assert g.values[-1] == pytest.approx(1.0 + 1e-6 * 0.75, rel=1e-5)  # capped; tie-break
    assert obj.figures(*state(lam, q, g.chosen))["coverage"][0, 0] == pytest.approx(0.775)
    better = improve(obj, lam, g, reachable=np.array([True]))
    assert len(better.chosen) == 2


def test_budget_and_unreachable_goal():
    obj = Objective(_sample_set(np.zeros((4, 3)), np.zeros((4, 3))), 1.0, 0.0)
    q = _matrix([{0}, {1}, {2}], 4)  # sample 3: no candidate sees it
    reach = reachable_trees(obj, q)
    assert reach.tolist() == [False]
    g = lazy_greedy(obj, q, 2, reachable=reach)
    assert len(g.chosen) == 2 and g.stop_reason == "budget spent"
    g = lazy_greedy(obj, q, 10, reachable=reach)
    assert len(g.chosen) == 3
    # a partial goal caps the gain: 50 % coverage needs two of the four samples
    obj = Objective(_sample_set(np.zeros((4, 3)), np.zeros((4, 3))), 0.5, 0.0)
    g = lazy_greedy(obj, q, 10)
    assert len(g.chosen) == 2 and g.stop_reason == "goal met"


# -- the DBH band of a cylinder ------------------------------------------------------------
def test_band_samples_of_a_stem():
    stem = _cylinder(2.0, -1.0, r=0.2, h=4.0)
    t = TreeTarget(5, [_part(stem, "stem", 5)], (2.0, -1.0, 0.0))
    s = sample_trees([t], samples_per_tree=300, band_samples=720, arc_bin_deg=10.0, seed=3)
    band = s.points[s.band]
    assert len(band) >= 600
    assert band[:, 2].min() >= 1.1 and band[:, 2].max() <= 1.5
    assert s.n_sectors[0] == 36
    assert np.allclose(s.stem_xy[0], (2.0, -1.0), atol=0.01)
    assert s.stem_radius_m[0] == pytest.approx(0.2, abs=0.002)
    # sectors are contiguous blocks, band first then coverage
    assert s.block_sector.tolist() == list(range(36)) + [-1]
    # from one side at 6 m the arc seen is the one the model gives on the circle (a point
    # at angle φ from the station's direction meets the beam at cos i = (d cos φ - r)/|PS|;
    # a sector counts when its expected share hit is >= ½, i.e. p >= ½ there), to a sector
    # (half a sector at each end); three stations 120° apart see all 360°
    spec = ScannerSpec(horizontal_resolution_deg=0.05, vertical_resolution_deg=0.05)
    caster = VisibilityCaster(Scene([_part(stem, "stem", 5)]), s, nthreads=1)
    obj = Objective(s, 0.0, 360.0)
    d, r, tau = 6.0, 0.2, 0.01
    phi = np.radians(np.arange(0, 180, 0.01))
    ps = np.hypot(d - r * np.cos(phi), r * np.sin(phi))
    cos_i = (d * np.cos(phi) - r) / ps
    p = hit_probability(ps, np.maximum(cos_i, 0), math.radians(0.05), tau)
    ok = (cos_i > 0) & (p >= 0.5)
    arc_rule = 2 * np.degrees(phi[ok].max())
    assert 120 < arc_rule < 170  # the incidence limit bites
    a = np.radians([0, 120, 240])
    pos = np.column_stack([2 + d * np.cos(a), -1 + d * np.sin(a), np.full(3, 1.3)])
    lam = visibility(caster, pos, spec, tau).intensity
    one = obj.figures(lam[0])["arc_deg"][0, 0]
    assert abs(one - arc_rule) <= 10.0
    assert obj.figures(lam.sum(axis=0))["arc_deg"][0, 0] == pytest.approx(360.0)


# -- field time --------------------------------------------------------------------------
def test_field_time_arithmetic():
    vz = instrument("riegl-vz400")
    spec = vz.spec()  # 0.04°, 360° × (-40°..60°)
    assert (spec.n_azimuth, spec.n_elevation) == (9000, 2501)
    # the mechanics (data sheet: 300 kHz pulses, a 240° mirror cycle, at most 120 lines
    # per second): one line per 0.04° of head turn, each lasting 240/0.04 pulses
    line_s = max(240 / 0.04 / 300_000, 1 / 120)
    assert vz.scan_time_s(spec) == pytest.approx(9000 * line_s) == pytest.approx(180.0)
    assert vz.station_time_s(spec) == pytest.approx(240 + 180.0)
    coarse = vz.spec(horizontal_resolution_deg=0.1, vertical_resolution_deg=0.1)
    # at 0.1° the mirror would need 125 lines/s: the line rate's ceiling of 120 rules
    assert vz.scan_time_s(coarse) == pytest.approx(3600 / 120)
    for p in INSTRUMENTS.values():
        assert p.measurement_rate_hz > 0 and p.setup_time_min > 0 and p.timing_source


def test_params_refuse_no_goal_and_bad_band():
    with pytest.raises(InvalidParameterError, match="needs a goal"):
        PlanParams(goal_coverage=0.0, dbh_arc_deg=0.0)
    with pytest.raises(InvalidParameterError, match="dbh_band_m"):
        PlanParams(dbh_band_m=(1.5, 1.1))
    with pytest.raises(InvalidParameterError):
        PlanParams(goal_coverage=1.5)
