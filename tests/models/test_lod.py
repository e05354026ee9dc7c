"""Level of detail: facets per cylinder from the point spacing at the nearest station.

Known answers for analytic cylinders, monotonicity in distance, the bounds, and on whole
trees: fewer triangles than the uniform mesh, and a mesh within the stated fraction of
the point spacing of the uniform one (measured with :mod:`treesim.geometry`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from treesim.errors import InvalidParameterError
from treesim.geometry.sampling import sample_surface
from treesim.geometry.triangles import point_to_mesh_distances
from treesim.models import (
    LOD_MIN_FACETS,
    LOD_TOLERANCE,
    CylinderTable,
    cylinders_to_mesh,
    generate_tree,
    lod_facets,
    mesh_triangle_count,
    plan_lod,
    read_cylinders,
    tubes_to_mesh,
)
from treesim.models.lod import facets_for_sagitta, nearest_station_distance_m, sagitta_m
from treesim.scan.stations import ring_around

STEP_RAD = math.radians(0.04)


def _vertical(radius: float, height: float = 2.0, base=(0.0, 0.0, 0.0)) -> CylinderTable:
    return CylinderTable(
        start=[list(base)],
        axis=[[0.0, 0.0, 1.0]],
        length_m=[height],
        radius_m=[radius],
        parent=[-1],
        branch=[1],
        branch_order=[0],
        position_in_branch=[1],
    )


def _brute_force(r: float, limit: float, lo: int, hi: int) -> int:
    """The rule by enumeration, with the textbook sagitta r (1 - cos(pi / n))."""
    for n in range(3, hi + 1):
        if r * (1.0 - math.cos(math.pi / n)) <= limit:
            return min(max(n, lo), hi)
    return hi


def _ring(table: CylinderTable, distance_m: float, n: int = 4) -> np.ndarray:
    """Station positions as the station rule places them (1.5 m up, around the bounds)."""
    lo = np.minimum(table.start, table.end).min(axis=0)
    hi = np.maximum(table.start, table.end).max(axis=0)
    ring = ring_around(np.array([lo, hi]), n, distance_m=distance_m, height_m=1.5)
    return np.array([s.position_m for s in ring])


def test_defaults_are_half_the_spacing_and_the_junction_floor() -> None:
    assert LOD_TOLERANCE == 0.5 and LOD_MIN_FACETS == 8


@pytest.mark.parametrize(
    ("radius_m", "wanted", "expected"),
    [
        # At 10 m and 0.04 degrees the spacing is 6.981 mm; half of it 3.491 mm.
        (0.1, 12, 12),  # sagitta 3.407 mm at 12 facets, 4.051 mm at 11
        (0.3, 21, 21),  # 3.351 mm at 21, 3.694 mm at 20
        (0.02, 6, 8),  # 2.679 mm at 6, 3.820 mm at 5: the floor of 8 applies
    ],
)
def test_a_cylinder_at_10_m_gets_the_formulas_count(
    radius_m: float, wanted: int, expected: int
) -> None:
    table = _vertical(radius_m)
    station = [[10.0 + radius_m, 0.0, 1.0]]  # 10 m from the side facing it
    assert nearest_station_distance_m(table, station)[0] == pytest.approx(10.0, abs=1e-12)
    spacing = 10.0 * STEP_RAD
    assert spacing == pytest.approx(6.981317e-3, rel=1e-6)
    plan = plan_lod(table, station, STEP_RAD, max_facets=32)
    assert plan.wanted.tolist() == [wanted]
    assert plan.spacing_m[0] == pytest.approx(spacing, rel=1e-12)
    facets = lod_facets(table, station, STEP_RAD, max_facets=32)
    assert facets.tolist() == [expected] and facets.dtype == np.int64
    assert radius_m * (1 - math.cos(math.pi / wanted)) <= 0.5 * spacing
    assert radius_m * (1 - math.cos(math.pi / (wanted - 1))) > 0.5 * spacing
    assert _brute_force(radius_m, 0.5 * spacing, 8, 32) == expected


def test_the_rule_matches_enumeration_over_many_radii_and_distances() -> None:
    rng = np.random.default_rng(0)
    r = 10 ** rng.uniform(-4, 0, 3000)
    limit = 10 ** rng.uniform(-6, -1, 3000)
    for lo, hi in ((3, 64), (8, 32), (12, 12), (16, 9)):
        got = facets_for_sagitta(r, limit, min_facets=lo, max_facets=hi)
        want = [_brute_force(a, b, min(lo, hi), hi) for a, b in zip(r, limit, strict=True)]
        assert got.tolist() == want
        assert (got <= hi).all()
    # sagitta_m is the textbook formula, without its cancellation.
    n = np.arange(3, 200)
    np.testing.assert_allclose(sagitta_m(0.25, n), 0.25 * (1 - np.cos(np.pi / n)), rtol=1e-12)


def test_the_nearest_station_decides_and_distances_are_lower_bounds() -> None:
    table = _vertical(0.1)
    far, near = [30.1, 0.0, 1.0], [0.0, -2.1, 0.5]
    d = nearest_station_distance_m(table, [far, near])
    assert d[0] == pytest.approx(2.0, abs=1e-12)
    assert (
        lod_facets(table, [far, near], STEP_RAD, max_facets=64).tolist()
        == lod_facets(table, [near], STEP_RAD, max_facets=64).tolist()
    )
    # Above the top cap: 3 m to the disc; the bound (axis segment minus radius) says 2.9.
    assert nearest_station_distance_m(table, [0.0, 0.0, 5.0])[0] == pytest.approx(2.9)
    # Inside the cylinder: 0, and then the most facets allowed.
    assert nearest_station_distance_m(table, [0.05, 0.0, 1.0])[0] == 0.0
    assert lod_facets(table, [0.05, 0.0, 1.0], STEP_RAD, max_facets=20).tolist() == [20]
    # Georeferenced coordinates give the same distances as local ones.
    base = np.array([512_345.678, 5_432_109.876, 254.0])
    geo = _vertical(0.1, base=tuple(base))
    np.testing.assert_allclose(
        nearest_station_distance_m(geo, np.array([far, near]) + base), d, rtol=0, atol=1e-9
    )


def test_a_far_station_gives_fewer_triangles_than_a_near_one() -> None:
    table = generate_tree("balsam-fir", seed=0).cylinders
    # One station walking away along +x from beyond the crown: every cylinder gets farther.
    edge = np.maximum(table.start, table.end)[:, 0].max()
    counts = []
    facets = []
    for distance in (0.5, 2.0, 10.0, 30.0):
        f = lod_facets(table, [[edge + distance, 0.0, 1.5]], STEP_RAD, max_facets=32)
        facets.append(f)
        counts.append(len(cylinders_to_mesh(table, facets=f)[1]))
    assert counts == sorted(counts, reverse=True) and counts[0] > counts[-1]
    for near, far in zip(facets, facets[1:], strict=False):
        assert (far <= near).all()
    assert counts[0] < mesh_triangle_count(table, facets=32)


def test_max_facets_is_never_exceeded_and_min_facets_is_a_floor() -> None:
    table = _vertical(0.3)
    close = [[2.3, 0.0, 1.0]]  # 2 m: the rule asks for 47 facets
    assert _brute_force(0.3, 0.5 * 2.0 * STEP_RAD, 3, 100) == 47
    plan = plan_lod(table, close, STEP_RAD, max_facets=32)
    assert plan.wanted.tolist() == [33] and plan.facets.tolist() == [32]
    assert plan.describe()["n_capped"] == 1
    assert lod_facets(table, close, STEP_RAD, max_facets=64).tolist() == [47]
    assert lod_facets(table, close, STEP_RAD, max_facets=12).tolist() == [12]
    # 100 m away the rule asks for 7: capped at 6; a floor above max_facets is lowered.
    assert plan_lod(table, [[100.3, 0, 1]], STEP_RAD, max_facets=64).wanted.tolist() == [7]
    assert lod_facets(table, [[100.3, 0, 1]], STEP_RAD, max_facets=6).tolist() == [6]
    # 1000 m away it asks for 3: the floor (8 by default) holds, and can be lowered.
    far = [[1000.3, 0, 1]]
    assert plan_lod(table, far, STEP_RAD, max_facets=32).wanted.tolist() == [3]
    assert lod_facets(table, far, STEP_RAD, max_facets=32).tolist() == [8]
    assert lod_facets(table, far, STEP_RAD, max_facets=6, min_facets=3).tolist() == [3]
    assert lod_facets(table, far, STEP_RAD, max_facets=32, min_facets=5).tolist() == [5]
    sapling = generate_tree("sapling", seed=0).cylinders
    for distance in (0.2, 1.0, 10.0):
        f = lod_facets(sapling, _ring(sapling, distance), STEP_RAD, max_facets=16)
        assert f.max() <= 16 and f.min() >= LOD_MIN_FACETS


def _distances_to(
    vertices: np.ndarray, faces: np.ndarray, other_v: np.ndarray, other_f: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Exact distances from ``n`` points sampled on one mesh to the other, and the faces
    the samples lie on (coordinates shifted to a local origin first)."""
    origin = vertices.min(axis=0)
    pts, tri = sample_surface(vertices - origin, faces, n, seed=1)
    return point_to_mesh_distances(pts, other_v - origin, other_f, nthreads=2), tri


@pytest.mark.parametrize("joints", ["separate", "miter"])
def test_sapling_at_10_m_saves_triangles_within_half_the_spacing(joints: str) -> None:
    tree = generate_tree("sapling", seed=0)
    table = tree.cylinders
    stations = _ring(table, 10.0)
    plan = plan_lod(table, stations, STEP_RAD, max_facets=32)
    # The sapling is 4 cm thick at most: 8 facets leave 1.7 mm, under half of >= 6.2 mm.
    assert plan.distance_m.min() > 8.9
    assert (plan.facets == 8).all()
    v_lod, f_lod = cylinders_to_mesh(table, facets=plan.facets, joints=joints)
    v_32, f_32 = cylinders_to_mesh(table, facets=32, joints=joints)
    assert len(f_lod) * 4 == len(f_32)  # every ring 8 facets instead of 32
    about = plan.describe(joints=joints)
    assert about["n_triangles"] == len(f_lod) and about["n_triangles_uniform"] == len(f_32)
    assert about["triangles_saved_fraction"] == pytest.approx(0.75)
    # The LOD mesh lies within half the finest point spacing of the uniform one, and
    # the other way round (a symmetric Hausdorff distance, sampled).
    bound = LOD_TOLERANCE * float(plan.spacing_m.min())
    d_there, _ = _distances_to(v_lod, f_lod, v_32, f_32, 100_000)
    d_back, _ = _distances_to(v_32, f_32, v_lod, f_lod, 100_000)
    assert max(d_there.max(), d_back.max()) < bound
    # ... and is as far from it as 8 facets predict (the 8-gon's sagitta minus a little).
    worst = float(sagitta_m(np.maximum(table.radius_m, table.end_radius_m).max(), 8))
    assert 0.9 * worst < d_there.max() <= worst * (1 + 1e-9)


def test_sapling_from_1_m_keeps_each_cylinder_within_its_own_spacing() -> None:
    """Close up the counts vary per cylinder; every sample of the LOD mesh is within the
    fraction of the spacing at its own cylinder of the uniform mesh (separate prisms and
    procedural tubes, whose joints keep their radius)."""
    table = generate_tree("sapling", seed=0).cylinders
    plan = plan_lod(table, _ring(table, 1.0), STEP_RAD, max_facets=32)
    assert len(np.unique(plan.facets)) >= 5 and (plan.wanted <= 32).all()
    bound = plan.tolerance * plan.spacing_m
    v, f = cylinders_to_mesh(table, facets=plan.facets)
    v32, f32 = cylinders_to_mesh(table, facets=32)
    d, tri = _distances_to(v, f, v32, f32, 100_000)
    row = np.searchsorted(np.cumsum(4 * plan.facets), tri, side="right")
    assert (d <= bound[row]).all()
    lod = tubes_to_mesh(table, facets=plan.facets)
    uni = tubes_to_mesh(table, facets=32)
    d, tri = _distances_to(lod.vertices, lod.faces, uni.vertices, uni.faces, 100_000)
    assert (d <= bound[lod.face_cylinder[tri]]).all()
    assert lod.n_triangles < uni.n_triangles


@pytest.mark.shared_data
def test_coffee_tree_describe_is_json_and_matches_the_meshes(treeqsm_csv: Path) -> None:
    table = read_cylinders(treeqsm_csv)
    stations = _ring(table, 3.0)
    plan = plan_lod(table, stations, STEP_RAD, max_facets=32)
    for joints in ("separate", "miter"):
        about = json.loads(json.dumps(plan.describe(joints=joints)))
        v, f = cylinders_to_mesh(table, facets=plan.facets, joints=joints)
        assert about["n_triangles"] == len(f)
        assert about["n_triangles_uniform"] == len(cylinders_to_mesh(table, joints=joints)[1])
        assert about["triangles_saved"] == about["n_triangles_uniform"] - len(f) > 0
        assert sum(about["facets_histogram"].values()) == table.n_cylinders
        assert sum(about["meshed_facets_histogram"].values()) == table.n_cylinders
        assert about["max_sagitta_over_spacing"] <= LOD_TOLERANCE
        assert 0.9 < about["prism_volume_ratio"] < 1.0
        assert about["n_stations"] == 4 and about["spacing_deg"] == pytest.approx(0.04)
        assert "nearest station" in about["rule"]
    # Separate prisms keep every sample within the spacing fraction at its cylinder.
    v, f = cylinders_to_mesh(table, facets=plan.facets)
    v32, f32 = cylinders_to_mesh(table, facets=32)
    d, tri = _distances_to(v, f, v32, f32, 100_000)
    row = np.searchsorted(np.cumsum(4 * plan.facets), tri, side="right")
    assert (d <= plan.tolerance * plan.spacing_m[row]).all()


def test_bad_parameters() -> None:
    table = _vertical(0.1)
    st = [[5.0, 0, 1]]
    for bad in (0.0, -1e-3, math.nan, math.inf, True, "0.04", math.pi):
        with pytest.raises(InvalidParameterError, match="spacing_rad"):
            lod_facets(table, st, bad, max_facets=32)
    for bad in (0.0, -0.5, math.nan):
        with pytest.raises(InvalidParameterError, match="tolerance"):
            lod_facets(table, st, STEP_RAD, max_facets=32, tolerance=bad)
    for bad in ([], [[1.0, 2.0]], [[math.nan, 0, 0]], np.zeros((2, 2, 3))):
        with pytest.raises(InvalidParameterError, match="station"):
            lod_facets(table, bad, STEP_RAD, max_facets=32)
    for kw in ({"max_facets": 2}, {"max_facets": 32, "min_facets": 0}):
        with pytest.raises(InvalidParameterError, match="facets"):
            lod_facets(table, st, STEP_RAD, **kw)
