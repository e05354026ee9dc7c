"""Procedural trees: deterministic, exact tables, watertight crack-free wood, sane figures."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from tests.models.geometry import (
    assert_closed_and_outward,
    assert_no_degenerate,
    triangle_areas,
    winding_numbers,
)
from treesim.errors import InvalidParameterError, TreesimError
from treesim.models import (
    LEAF_SHAPES,
    SHAPES,
    LeafParams,
    StemLevel,
    TreeParams,
    generate_tree,
    mesh_volume,
    shape_ratio,
)
from treesim.models import (
    SPECIES as PRESETS,
)
from treesim.models import (
    species_preset as preset,
)
from treesim.models.mesh import _ring_basis
from treesim.models.procedural import CHILD_RADIUS_LIMIT, MIN_JUNCTION_FACETS

NAMES = list(PRESETS)

#: What each preset's description promises, as (low, high) for seed 0.
EXPECTED = {
    "aspen": {"dbh_m": (0.25, 0.36), "height_m": (14.0, 20.0)},
    "aspen-leafon": {"dbh_m": (0.25, 0.36), "height_m": (14.0, 20.0)},
    "balsam-fir": {"dbh_m": (0.18, 0.27), "height_m": (12.0, 17.0)},
    "sapling": {"dbh_m": (0.02, 0.045), "height_m": (3.0, 5.0)},
    "old-tupelo": {"dbh_m": (0.65, 0.95), "height_m": (24.0, 34.0)},
    "palm": {"dbh_m": (0.20, 0.30), "height_m": (10.0, 14.0)},
}


def _prism_factor(facets: int) -> float:
    return facets * math.sin(2 * math.pi / facets) / (2 * math.pi)


def _child_rows(table) -> tuple[np.ndarray, np.ndarray]:
    """First rows of stems that grow on another stem, and their parent rows."""
    rows = np.flatnonzero(table.parent >= 0)
    rows = rows[table.branch[table.parent[rows]] != table.branch[rows]]
    return rows, table.parent[rows]


def _base_circles(table, rows: np.ndarray, m: int = 48) -> np.ndarray:
    """(len(rows), m, 3) points on the base circles of ``rows``."""
    u, v = _ring_basis(table.unit_axis[rows])
    psi = 2 * np.pi * np.arange(m) / m
    ring = np.cos(psi)[None, :, None] * u[:, None, :] + np.sin(psi)[None, :, None] * v[:, None, :]
    return table.start[rows][:, None, :] + table.radius_m[rows][:, None, None] * ring


# ---------------------------------------------------------------------------- presets


def test_presets_are_documented() -> None:
    assert len(PRESETS) >= 5
    assert {"aspen", "aspen-leafon", "balsam-fir", "sapling", "old-tupelo"} <= set(PRESETS)
    for name, params in PRESETS.items():
        assert params.name == name and preset(name) is params
        assert "Weber & Penn" in params.source and len(params.description) > 20
    assert PRESETS["aspen-leafon"].leaves_on and not PRESETS["aspen"].leaves_on


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_tree_other_seed_other_tree(name: str, preset_trees) -> None:
    tree = preset_trees[name]
    again = generate_tree(name, seed=0)
    assert again.cylinders.identical(tree.cylinders)
    assert np.array_equal(again.leaf_vertices, tree.leaf_vertices)
    assert np.array_equal(again.leaf_faces, tree.leaf_faces)
    for a, b in zip(again.mesh(16), tree.mesh(16), strict=True):
        assert np.array_equal(a, b)
    other = generate_tree(name, seed=1)
    assert not other.cylinders.identical(tree.cylinders)
    assert (
        other.cylinders.summary()["volume_total_m3"] != tree.cylinders.summary()["volume_total_m3"]
    )


@pytest.mark.parametrize("name", NAMES)
def test_mesh_volume_matches_the_table_within_one_percent(name: str, preset_trees) -> None:
    truth = preset_trees[name].truth()  # the default, 32 facets
    assert truth["facets"] == 32
    assert abs(truth["mesh_volume_error"]) < 0.01
    # All of the difference is the inscribed polygon's (-0.64 %): mitred frusta keep volume.
    assert truth["mesh_volume_error"] == pytest.approx(_prism_factor(32) - 1.0, abs=2e-4)


@pytest.mark.parametrize("name", NAMES)
def test_wood_is_watertight_per_tube_and_nothing_is_degenerate(name: str, preset_trees) -> None:
    tree = preset_trees[name]
    wood = tree.wood_mesh(32)
    assert_closed_and_outward(wood.faces)
    mesh = trimesh.Trimesh(wood.vertices, wood.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert_no_degenerate(wood.vertices, wood.faces)
    # One tube per stem, each closed with a positive volume.
    assert wood.n_tubes == len(np.unique(tree.cylinders.branch))
    tri = wood.vertices[wood.faces] - wood.vertices.mean(axis=0)
    det = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    per_tube = np.bincount(wood.face_tube, weights=det)
    assert (per_tube > 0).all()
    if tree.has_leaves:
        assert_no_degenerate(tree.leaf_vertices, tree.leaf_faces)


@pytest.mark.parametrize("name", NAMES)
def test_truth_figures_are_sane(name: str, preset_trees) -> None:
    tree = preset_trees[name]
    table = tree.cylinders
    t = tree.truth()
    for key in ("dbh_m", "height_m", "volume_total_m3", "volume_stem_m3", "volume_branch_m3"):
        assert t[key] > 0, key
    lo, hi = EXPECTED[name]["dbh_m"]
    assert lo < t["dbh_m"] < hi
    lo, hi = EXPECTED[name]["height_m"]
    assert lo < t["height_m"] < hi
    assert t["volume_stem_m3"] + t["volume_branch_m3"] == pytest.approx(t["volume_total_m3"])
    assert t["volume_stem_m3"] > t["volume_branch_m3"]  # all presets are single-stemmed
    assert t["n_cylinders"] == table.n_cylinders
    bpo = t["branches_per_order"]
    levels = len(tree.params.levels)  # the palm has one level of fronds: two orders
    assert bpo[0] == 1 and len(bpo) >= min(3, levels)
    assert sum(bpo.values()) == len(np.unique(table.branch))
    assert (table.tag == "modelled").all()
    # Standing on the origin, trunk up, nothing below the ground.
    assert table.start[0].tolist() == [0.0, 0.0, 0.0]
    vertices, _, _ = tree.mesh(16)
    assert vertices[:, 2].min() >= 0.0
    assert t["height_m"] >= 0.8 * tree.params.trunk_length_m
    # The DBH is the stem's diameter 1.3 m up, interpolated on its frustum.
    stem = np.flatnonzero(table.branch_order == 0)
    z0, z1 = table.start[stem, 2], table.end[stem, 2]
    k = int(np.flatnonzero((z0 <= 1.3) & (z1 > 1.3))[0])
    i = stem[k]
    f = (1.3 - z0[k]) / (z1[k] - z0[k])
    expected_dbh = 2 * (table.radius_m[i] + f * (table.end_radius_m[i] - table.radius_m[i]))
    assert t["dbh_m"] == pytest.approx(expected_dbh, rel=1e-9)
    # Leaves: as many as claimed, each a blade of the preset's shape.
    if tree.has_leaves:
        pts, tris = LEAF_SHAPES[tree.params.leaves.shape]
        assert len(tree.leaf_faces) == tree.n_leaves * len(tris)
        assert len(tree.leaf_vertices) == tree.n_leaves * len(pts)
        assert t["leaf_area_m2"] == pytest.approx(
            float(triangle_areas(tree.leaf_vertices, tree.leaf_faces).sum())
        )
    else:
        assert t["n_leaves"] == 0 and t["n_triangles_leaf"] == 0


@pytest.mark.parametrize("name", NAMES)
def test_children_start_inside_their_parents(name: str, preset_trees) -> None:
    """Analytic: every child's base circle lies within its parent cylinder's axial range
    and inside the parent's polygon at MIN_JUNCTION_FACETS (the junction has no crack)."""
    table = preset_trees[name].cylinders
    rows, parents = _child_rows(table)
    assert len(rows) > 20
    circle = _base_circles(table, rows)
    a = table.unit_axis[parents]
    rel = circle - table.start[parents][:, None, :]
    t = np.einsum("kmj,kj->km", rel, a)
    radial = np.linalg.norm(rel - t[:, :, None] * a[:, None, :], axis=2)
    length = table.length_m[parents][:, None]
    assert (t >= 0).all() and (t <= length).all()
    r0, r1 = table.radius_m[parents][:, None], table.end_radius_m[parents][:, None]
    r_parent = r0 + (r1 - r0) * t / length
    assert (radial < r_parent * math.cos(math.pi / MIN_JUNCTION_FACETS)).all()
    assert (table.radius_m[rows] <= CHILD_RADIUS_LIMIT * np.maximum(r0, r1)[:, 0] + 1e-15).all()


@pytest.mark.parametrize("name", ["sapling", "balsam-fir", "old-tupelo"])
def test_junctions_are_closed_in_the_mesh(name: str, preset_trees) -> None:
    """On the mesh: each child's base circle is inside its parent's tube (winding number 1)
    at the coarsest facet count the generator guarantees."""
    tree = preset_trees[name]
    wood = tree.wood_mesh(MIN_JUNCTION_FACETS)
    rows, parents = _child_rows(tree.cylinders)
    circles = _base_circles(tree.cylinders, rows, m=24)
    faces_of = {}
    for k, (row, par) in enumerate(zip(rows, parents, strict=True)):
        tube = int(wood.tube_of_row[par])
        if tube not in faces_of:
            faces_of[tube] = wood.faces[wood.face_tube == tube]
        w = winding_numbers(circles[k], wood.vertices, faces_of[tube])
        assert (w > 0.999).all(), f"row {row + 1}: base circle pokes out of its parent"


def test_wood_does_not_depend_on_leaves(preset_trees) -> None:
    leafless, leafy = preset_trees["aspen"], preset_trees["aspen-leafon"]
    assert leafless.cylinders.identical(leafy.cylinders)
    assert leafless.n_leaves == 0 and leafy.n_leaves > 5000
    on = generate_tree("aspen", seed=0, leaves=True)
    assert np.array_equal(on.leaf_vertices, leafy.leaf_vertices)
    off = generate_tree("aspen-leafon", seed=0, leaves=False)
    assert off.n_leaves == 0 and off.cylinders.identical(leafy.cylinders)


def test_leaf_mesh_labels_and_order(preset_trees) -> None:
    tree = preset_trees["aspen-leafon"]
    vertices, faces, label = tree.mesh(8)
    wood = tree.wood_mesh(8)
    assert vertices.dtype == np.float64 and faces.dtype == np.int64 and label.dtype == np.uint8
    assert (label[: wood.n_triangles] == 1).all() and (label[wood.n_triangles :] == 2).all()
    assert np.array_equal(vertices[faces[label == 2]], tree.leaf_vertices[tree.leaf_faces])


# ---------------------------------------------------------------------------- known answers


def _trunk_only(**kw) -> TreeParams:
    base = {
        "name": "test",
        "description": "a test tree",
        "source": "made up",
        "levels": (StemLevel(segments=4, taper=0.0),),
        "trunk_length_m": 10.0,
        "radius_ratio": 0.02,
        "flare": 0.0,
        "base_size": 0.0,
    }
    return TreeParams(**{**base, **kw})


def test_a_cylindrical_trunk_is_exact() -> None:
    tree = generate_tree(_trunk_only(), seed=5)
    table = tree.cylinders
    assert table.n_cylinders == 4
    np.testing.assert_allclose(table.radius_m, 0.2, rtol=1e-15)
    np.testing.assert_allclose(table.unit_axis, [[0, 0, 1]] * 4, atol=1e-15, rtol=0)
    s = table.summary()
    assert s["volume_total_m3"] == pytest.approx(math.pi * 0.2**2 * 10.0, rel=1e-12)
    assert s["dbh_m"] == pytest.approx(0.4, rel=1e-12)
    assert s["height_m"] == pytest.approx(10.0, rel=1e-12)
    assert s["branches_per_order"] == {0: 1}
    for facets in (8, 32):
        wood = tree.wood_mesh(facets)
        assert wood.n_tubes == 1 and wood.n_triangles == (2 * 4 + 2) * facets
        assert mesh_volume(wood.vertices, wood.faces) == pytest.approx(
            _prism_factor(facets) * s["volume_total_m3"], rel=1e-12
        )


def test_a_conical_trunk_with_flare_is_exact() -> None:
    r, tip, length = 0.2, 0.001, 10.0
    cone = generate_tree(
        _trunk_only(levels=(StemLevel(segments=5, taper=1.0),), tip_radius_m=tip), seed=1
    )
    s = cone.cylinders.summary()
    # A linear taper cut into frusta sums to the whole truncated cone.
    whole = math.pi * length * (r * r + r * tip + tip * tip) / 3.0
    assert s["volume_total_m3"] == pytest.approx(whole, rel=1e-12)
    assert s["dbh_m"] == pytest.approx(2 * (r - (r - tip) * 1.3 / length), rel=1e-12)
    assert cone.cylinders.end_radius_m[-1] == pytest.approx(tip)
    flared = generate_tree(
        _trunk_only(levels=(StemLevel(segments=5, taper=1.0),), flare=1.0, tip_radius_m=tip),
        seed=1,
    ).cylinders
    # W&P's flare: 1 + flare (100^(1 - 8z) - 1) / 100 at the base, none above z = 1/8.
    assert flared.radius_m[0] == pytest.approx(r * 1.99, rel=1e-12)
    assert flared.n_cylinders > 5  # the flared base is subdivided
    above = flared.start[:, 2] >= length / 8 - 1e-9
    np.testing.assert_allclose(
        flared.radius_m[above], r - (r - tip) * flared.start[above, 2] / length, rtol=1e-12
    )


def test_weber_penn_rules_for_the_first_level() -> None:
    lev1 = StemLevel(
        branches=7,
        length_ratio=0.4,
        down_angle_deg=70.0,
        rotate_deg=137.5,
        segments=3,
    )
    params = _trunk_only(
        levels=(StemLevel(segments=6, taper=1.0), lev1),
        shape="spherical",
        base_size=0.3,
        ratio_power=1.5,
    )
    table = generate_tree(params, seed=2).cylinders
    s = table.summary()
    assert s["branches_per_order"] == {0: 1, 1: 7}
    rows, parents = _child_rows(table)
    assert (table.branch_order[rows] == 1).all()
    length, r0 = 10.0, 0.2
    # Straight vertical trunk: a child's height is its offset along the trunk.
    offset = table.start[rows, 2]
    assert (offset >= 0.3 * length).all()
    child_len = np.array([table.length_m[table.branch == b].sum() for b in table.branch[rows]])
    env = [shape_ratio("spherical", (length - o) / (length - 3.0)) for o in offset]
    np.testing.assert_allclose(child_len, length * 0.4 * np.array(env), rtol=1e-12)
    # Radius: W&P's power law, capped so the base fits in the parent cylinder it starts on.
    r_parent = np.minimum(table.radius_m[parents], table.end_radius_m[parents])
    expected = np.minimum(r0 * (child_len / length) ** 1.5, CHILD_RADIUS_LIMIT * r_parent)
    np.testing.assert_allclose(table.radius_m[rows], expected, rtol=1e-12)
    assert (table.radius_m[rows] < r0 * (child_len / length) ** 1.5).sum() >= 1  # capped
    # Down angle exactly 70 degrees; azimuths 137.5 degrees apart.
    axis = table.unit_axis[rows]
    np.testing.assert_allclose(np.degrees(np.arccos(axis[:, 2])), 70.0, atol=1e-9, rtol=0)
    az = np.degrees(np.arctan2(axis[:, 1], axis[:, 0]))
    np.testing.assert_allclose(np.diff(az) % 360.0, 137.5, atol=1e-9, rtol=0)


def test_splits_make_clones_one_order_up_that_fit_inside() -> None:
    lev1 = StemLevel(
        branches=2,
        length_ratio=0.5,
        down_angle_deg=50.0,
        segments=3,
        seg_splits=1.0,
        split_angle_deg=30.0,
    )
    params = _trunk_only(levels=(StemLevel(segments=4, taper=1.0), lev1), base_size=0.4)
    tree = generate_tree(params, seed=3)
    table = tree.cylinders
    # Per level-1 stem: clones at its two inner joints, and one at the first clone's joint.
    assert table.summary()["branches_per_order"] == {0: 1, 1: 2, 2: 4, 3: 2}
    wood = tree.wood_mesh(MIN_JUNCTION_FACETS)
    assert_closed_and_outward(wood.faces)
    rows, parents = _child_rows(table)
    circles = _base_circles(table, rows, m=24)
    for k, par in enumerate(parents):
        faces = wood.faces[wood.face_tube == wood.tube_of_row[par]]
        assert (winding_numbers(circles[k], wood.vertices, faces) > 0.999).all()
    # A clone starts with split_radius_ratio of its stem's radius at the split.
    clones = rows[table.branch_order[rows] >= 2]
    ratio = table.radius_m[clones] / table.end_radius_m[table.parent[clones]]
    assert (ratio < 0.81).all() and (ratio > 0.79).all()


def test_shape_ratio_known_values() -> None:
    assert shape_ratio("conical", 1.0) == pytest.approx(1.0)
    assert shape_ratio("conical", 0.0) == pytest.approx(0.2)
    assert shape_ratio("spherical", 0.5) == pytest.approx(1.0)
    assert shape_ratio("hemispherical", 1.0) == pytest.approx(1.0)
    assert shape_ratio("cylindrical", 0.3) == 1.0
    assert shape_ratio("tapered_cylindrical", 0.0) == pytest.approx(0.5)
    assert shape_ratio("flame", 0.7) == pytest.approx(1.0)
    assert shape_ratio("flame", 1.0) == pytest.approx(0.0)
    assert shape_ratio("inverse_conical", 1.0) == pytest.approx(0.2)
    assert shape_ratio("tend_flame", 0.7) == pytest.approx(1.0)
    assert shape_ratio("tend_flame", 0.0) == pytest.approx(0.5)
    assert len(SHAPES) == 8
    with pytest.raises(InvalidParameterError, match="shape must be one of"):
        shape_ratio("blob", 0.5)


# ---------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: StemLevel(segments=0), "segments"),
        (lambda: StemLevel(segments=2.5), "segments must be an integer"),
        (lambda: StemLevel(taper=1.5), "taper"),
        (lambda: StemLevel(branches=-1), "branches"),
        (lambda: StemLevel(length_ratio=float("nan")), "length_ratio"),
        (lambda: LeafParams(shape="star"), "leaf shape"),
        (lambda: LeafParams(length_m=0.0), "length_m"),
        (lambda: LeafParams(down_angle_deg=5.0), "point away"),
        (lambda: _trunk_only(levels=()), "levels"),
        (lambda: _trunk_only(shape="blob"), "shape must be one of"),
        (lambda: _trunk_only(trunk_length_m=-3.0), "trunk_length_m"),
        (lambda: _trunk_only(split_radius_ratio=0.95), "split_radius_ratio"),
        (lambda: _trunk_only(leaves_on=True), "leaves_on needs leaf parameters"),
        (lambda: generate_tree("oak"), "unknown species 'oak'; choose one of aspen"),
        (lambda: generate_tree("sapling", seed=-1), "seed must be an integer >= 0"),
        (lambda: generate_tree("sapling", seed=1.5), "seed must be an integer >= 0"),
        (lambda: generate_tree(_trunk_only(), leaves=True), "has no leaf parameters"),
        (lambda: generate_tree(42), "species must be a preset name"),
    ],
)
def test_bad_parameters_raise_clear_errors(make, match: str) -> None:
    with pytest.raises(InvalidParameterError, match=match) as info:
        make()
    assert isinstance(info.value, TreesimError)


def test_trunk_splits_fork_the_stem_and_stay_closed() -> None:
    trunk = StemLevel(segments=6, taper=1.0, seg_splits=0.5, split_angle_deg=25.0)
    lev1 = StemLevel(branches=12, length_ratio=0.3, down_angle_deg=60.0, segments=3)
    tree = generate_tree(_trunk_only(levels=(trunk, lev1), base_size=0.3), seed=4)
    table = tree.cylinders
    rows, parents = _child_rows(table)
    # Clones start on their parent's axis (branches start off it, toward the surface).
    rel = table.start[rows] - table.start[parents]
    a = table.unit_axis[parents]
    off_axis = np.linalg.norm(rel - np.einsum("ij,ij->i", rel, a)[:, None] * a, axis=1)
    clone = off_axis < 1e-9
    # Error diffusion of 0.5 per joint above the bare base (joints at 2/6 .. 5/6): clones at
    # 3/6 and 5/6; the first, three segments long, splits once more (at its 2/3).
    assert sorted(table.branch_order[rows[clone]].tolist()) == [1, 1, 2]
    assert table.summary()["branches_per_order"][0] == 1
    wood = tree.wood_mesh(MIN_JUNCTION_FACETS)
    assert_closed_and_outward(wood.faces)
    circles = _base_circles(table, rows, m=24)
    for k, par in enumerate(parents):
        faces = wood.faces[wood.face_tube == wood.tube_of_row[par]]
        assert (winding_numbers(circles[k], wood.vertices, faces) > 0.999).all()
