"""Known-answer tests of the planner's parts: visibility of an analytic scene, the set
cover on hand-made matrices, the DBH band on a cylinder, field-time arithmetic."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from pipeline.errors import InvalidParameterError
from pipeline.params import INSTRUMENTS, ScannerSpec, instrument
from pipeline.plan import (
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
from pipeline.plan.cover import reachable_trees
from pipeline.scene import MeshPart, Scene


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


def test_visibility_spacing_rule_and_range():
    samples = _samples()
    caster = VisibilityCaster(_scene(), samples, nthreads=1)
    # step 0.003 rad, τ = 1 cm: half-diagonal a/√2 at normal incidence passes at 3 m
    # (a = 9 mm: 6.4 mm) and fails at 7.3 m (a = 21.9 mm: 15.5 mm)
    step_deg = math.degrees(0.003)
    coarse = ScannerSpec(horizontal_resolution_deg=step_deg, vertical_resolution_deg=step_deg)
    q = visibility(caster, STATION, coarse, 0.01).quality[0]
    assert q[4] > 0 and q[1] == 0
    # the same rule by hand
    r = np.linalg.norm(samples.points[[1, 4]] - STATION[0], axis=1)
    assert max_spacing_ok(r, np.ones(2), 0.003, 0.01).tolist() == [False, True]
    # max range 5 m: the box only; min range 5 m: the cylinders only
    fine = ScannerSpec(horizontal_resolution_deg=0.01, vertical_resolution_deg=0.01)
    q = visibility(caster, STATION, fine.with_(max_range_m=5.0), 0.01).quality[0]
    assert (q > 0).tolist() == [False, False, False, False, True]
    q = visibility(caster, STATION, fine.with_(min_range_m=5.0), 0.01).quality[0]
    assert (q > 0).tolist() == [False, True, False, True, False]


def test_thin_feature_rule():
    # a twig 5 mm wide at a = 10 mm: hits every a²/w = 20 mm along it; half-diagonal of
    # (20 mm, 5 mm) = 10.3 mm: fails τ = 1 cm, passes τ = 1.1 cm
    a, w = 0.01, 0.005
    assert not max_spacing_ok(np.array([1.0]), np.ones(1), a, 0.010, np.array([w]))[0]
    assert max_spacing_ok(np.array([1.0]), np.ones(1), a, 0.011, np.array([w]))[0]


# -- set cover on hand-made matrices ------------------------------------------------------
def _matrix(rows: list[set[int]], n: int) -> np.ndarray:
    q = np.zeros((len(rows), n), np.uint8)
    for i, r in enumerate(rows):
        q[i, sorted(r)] = 200
    return q


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
    # from one side at 6 m the arc seen is the one the rule gives on the circle (a point
    # at angle φ from the station's direction meets the beam at cos i = (d cos φ - r)/|PS|),
    # to a sector (half a sector at each end); three stations 120° apart see all 360°
    spec = ScannerSpec(horizontal_resolution_deg=0.05, vertical_resolution_deg=0.05)
    caster = VisibilityCaster(Scene([_part(stem, "stem", 5)]), s, nthreads=1)
    obj = Objective(s, 0.0, 360.0)
    d, r, tau = 6.0, 0.2, 0.01
    phi = np.radians(np.arange(0, 180, 0.01))
    ps = np.hypot(d - r * np.cos(phi), r * np.sin(phi))
    cos_i = (d * np.cos(phi) - r) / ps
    ok = (cos_i > 0) & max_spacing_ok(ps, cos_i, math.radians(0.05), tau)
    arc_rule = 2 * np.degrees(phi[ok].max())
    assert 120 < arc_rule < 170  # the incidence limit bites
    a = np.radians([0, 120, 240])
    pos = np.column_stack([2 + d * np.cos(a), -1 + d * np.sin(a), np.full(3, 1.3)])
    q = visibility(caster, pos, spec, tau).quality
    one = obj.figures(q[0])["arc_deg"][0, 0]
    assert abs(one - arc_rule) <= 10.0
    assert obj.figures(q.max(axis=0))["arc_deg"][0, 0] == pytest.approx(360.0)


# -- field time --------------------------------------------------------------------------
def test_field_time_arithmetic():
    vz = instrument("riegl-vz400")
    spec = vz.spec()  # 0.04°, 360° × (-40°..60°)
    assert (spec.n_azimuth, spec.n_elevation) == (9000, 2501)
    assert vz.scan_time_s(spec) == pytest.approx(9000 * 2501 / 122_000)
    assert vz.station_time_s(spec) == pytest.approx(240 + 9000 * 2501 / 122_000)
    coarse = vz.spec(horizontal_resolution_deg=0.1, vertical_resolution_deg=0.1)
    assert vz.scan_time_s(coarse) == pytest.approx(3600 * 1001 / 122_000)
    for p in INSTRUMENTS.values():
        assert p.measurement_rate_hz > 0 and p.setup_time_min > 0 and p.timing_source


def test_params_refuse_no_goal_and_bad_band():
    with pytest.raises(InvalidParameterError, match="needs a goal"):
        PlanParams(goal_coverage=0.0, dbh_arc_deg=0.0)
    with pytest.raises(InvalidParameterError, match="dbh_band_m"):
        PlanParams(dbh_band_m=(1.5, 1.1))
    with pytest.raises(InvalidParameterError):
        PlanParams(goal_coverage=1.5)
