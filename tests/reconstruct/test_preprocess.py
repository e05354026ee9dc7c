"""Input preparation: checks, voxel downsampling, outliers, ground, normals, leaves."""

from __future__ import annotations

import numpy as np
import pytest

from treesim.cloud import Cloud
from treesim.errors import EmptyInputError, InvalidGeometryError, InvalidParameterError
from treesim.reconstruct.preprocess import (
    PreparedCloud,
    PrepareParams,
    estimate_normals,
    prepare,
    validate_tree_cloud,
    voxel_downsample,
)

from .shapes import GEO, leaves, stem_on_ground, tube


def _steps(prep: PreparedCloud) -> dict[str, dict]:
    return {s["step"]: s for s in prep.steps}


# --------------------------------------------------------------------------- validation


def test_a_tube_is_accepted():
    pts, _ = tube(n=2000)
    validate_tree_cloud(Cloud(pts))
    validate_tree_cloud(pts + GEO)


def test_too_few_points_is_named():
    pts, _ = tube(n=299)
    with pytest.raises(EmptyInputError, match=r"only 299 points; a tree needs at least 300"):
        validate_tree_cloud(pts)
    with pytest.raises(EmptyInputError, match="only 299 points"):
        prepare(Cloud(pts))


def test_no_points():
    with pytest.raises(EmptyInputError, match="no points"):
        validate_tree_cloud(np.empty((0, 3)))


def test_nan_rows_are_counted_and_the_first_is_named():
    pts, _ = tube(n=1000)
    pts[17, 1] = np.nan
    pts[400, 2] = np.inf
    with pytest.raises(InvalidGeometryError, match=r"2 of 1000 points .*NaN.*first at row 17"):
        validate_tree_cloud(pts)


def test_identical_points():
    pts = np.tile([[500000.0, 5500000.0, 300.0]], (500, 1))
    with pytest.raises(InvalidGeometryError, match="all 500 points are identical"):
        prepare(Cloud(pts))


def test_flat_plane_is_named_with_its_thickness():
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(0, 2, 3000), rng.uniform(0, 1, 3000), 0.0005 * rng.normal(size=3000)]
    with pytest.raises(InvalidGeometryError, match=r"lie on a plane \(thickness .* mm over .* m\)"):
        validate_tree_cloud(pts + GEO)


def test_tilted_plane_is_a_plane_too():
    rng = np.random.default_rng(1)
    u, v = rng.uniform(0, 1, 2000), rng.uniform(0, 1, 2000)
    pts = np.c_[u, v, 0.3 * u + 0.7 * v]
    with pytest.raises(InvalidGeometryError, match="plane"):
        validate_tree_cloud(pts)


def test_line():
    t = np.linspace(0.0, 3.0, 1000)
    pts = np.c_[t, 2 * t, 0.5 * t] + 1e-5 * np.random.default_rng(0).normal(size=(1000, 3))
    with pytest.raises(InvalidGeometryError, match=r"lie on a line"):
        validate_tree_cloud(pts)


def test_bad_parameters():
    with pytest.raises(InvalidParameterError, match="voxel_size_m"):
        PrepareParams(voxel_size_m=0.0)
    with pytest.raises(InvalidParameterError, match="sor_std_ratio"):
        PrepareParams(sor_std_ratio=-1.0)
    with pytest.raises(InvalidParameterError, match="normals_neighbors"):
        PrepareParams(normals_neighbors=2)
    with pytest.raises(TypeError):
        PrepareParams(0.01)  # keyword-only


# --------------------------------------------------------------------------- voxels


def _grid_cloud(h: float = 0.01, dims=(8, 9, 10)) -> tuple[np.ndarray, np.ndarray]:
    """Three points in every voxel of a grid, with a known centroid per voxel."""
    ii = np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1).reshape(-1, 3)
    centres = (ii + 0.5) * h
    offsets = h * np.array([[-0.2, -0.15, -0.1], [0.15, 0.1, -0.2], [0.2, 0.2, 0.2]])
    pts = (centres[:, None, :] + offsets[None, :, :]).reshape(-1, 3)
    return pts, centres + offsets.mean(axis=0)


def test_voxel_downsample_known_grid_gives_exact_counts_and_centroids():
    pts, expected = _grid_cloud()
    cent, counts, inv = voxel_downsample(pts, 0.01, anchor=np.zeros(3))
    assert len(cent) == 8 * 9 * 10
    assert np.all(counts == 3)
    np.testing.assert_allclose(cent, expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(np.bincount(inv), counts)


def test_prepare_voxel_step_on_a_georeferenced_grid():
    pts, expected = _grid_cloud()
    params = PrepareParams(voxel_size_m=0.01, sor_std_ratio=None)
    prep = prepare(Cloud(pts + GEO), params)
    step = _steps(prep)["voxel_downsample"]
    assert (step["points_before"], step["points_after"], step["removed"]) == (2160, 720, 1440)
    assert np.all(prep.weights == 3)
    assert prep.n_input == 2160
    np.testing.assert_allclose(prep.global_points - GEO, expected, rtol=0, atol=1e-8)


def test_duplicates_are_merged_with_the_grid_off():
    pts, _ = tube(n=2000)
    cloud = Cloud(np.vstack([pts, pts, pts[:500]]) + GEO)
    prep = prepare(cloud, PrepareParams(voxel_size_m=None, sor_std_ratio=None))
    step = _steps(prep)["deduplicate"]
    assert step["removed"] == 2500
    assert len(prep) == 2000
    assert prep.weights.sum() == 4500
    assert sorted(np.unique(prep.weights).tolist()) == [2, 3]


# --------------------------------------------------------------------------- outliers


def test_far_outliers_are_removed_and_counted():
    pts, _ = tube(n=6000, noise_m=0.0005)
    rng = np.random.default_rng(5)
    direction = rng.normal(size=(25, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    outliers = np.array([0.0, 0.0, 0.5]) + direction * rng.uniform(1.0, 3.0, (25, 1))
    prep = prepare(Cloud(np.vstack([pts, outliers])), PrepareParams(voxel_size_m=None))
    step = _steps(prep)["outlier_removal"]
    assert 25 <= step["removed"] <= 25 + 60  # every outlier, at most 1 % of the tube
    local_far = np.hypot(*(prep.global_points[:, :2].T)) > 0.5
    assert not local_far.any()


def test_outlier_removal_can_be_turned_off():
    pts, _ = tube(n=2000)
    prep = prepare(pts, PrepareParams(sor_std_ratio=None))
    step = _steps(prep)["outlier_removal"]
    assert step["removed"] == 0 and step["params"]["enabled"] is False


# --------------------------------------------------------------------------- ground


def test_ground_plane_under_a_stem_is_removed_and_the_stem_kept():
    pts, n_stem = stem_on_ground()
    params = PrepareParams(voxel_size_m=None, remove_ground=True)
    prep = prepare(Cloud(pts + GEO), params)
    step = _steps(prep)["ground_removal"]
    n_ground = len(pts) - n_stem
    assert step["params"]["detected"] is True
    assert step["removed"] >= 0.99 * n_ground
    z = prep.global_points[:, 2] - GEO[2]
    r = np.hypot(*(prep.global_points[:, :2] - GEO[:2]).T)
    assert np.all(r < 0.2)  # nothing of the ground is left
    # every stem point clearly above the tolerance is kept
    stem_z = pts[:n_stem, 2]
    assert (z > 0.06).sum() >= (stem_z > 0.06).sum() - 0.01 * n_stem


def test_ground_removal_keeps_a_stem_base_without_ground():
    stem, _ = tube(radius=0.15, height=2.0, n=8000, noise_m=0.001)
    prep = prepare(stem, PrepareParams(voxel_size_m=None, remove_ground=True))
    step = _steps(prep)["ground_removal"]
    assert step["removed"] == 0
    assert step["params"]["detected"] is False
    assert prep.points[:, 2].min() < prep.points[:, 2].max() - 1.99  # the base is still there


def test_ground_and_understory_removal_are_on_by_default():
    pts, _ = stem_on_ground()
    prep = prepare(pts, PrepareParams(voxel_size_m=None))
    steps = _steps(prep)
    assert steps["ground_removal"]["params"]["enabled"] is True
    assert steps["ground_removal"]["params"]["detected"] is True
    assert steps["understory_removal"]["params"]["enabled"] is True


def _blob(centre, size, n, rng):
    return np.asarray(centre) + rng.uniform(-size / 2, size / 2, size=(n, 3))


def test_understory_and_litter_go_a_detached_crown_piece_stays():
    """A stem on ground with a shrub growing from the ground 1 m away, a twig lying on
    the ground 0.8 m away and a piece of crown 1.6-1.9 m up, 0.6 m from the stem (no
    link to it): the shrub and the twig go, the crown piece and the stem stay, and the
    foot is found on the stem's axis."""
    pts, n_stem = stem_on_ground()
    rng = np.random.default_rng(7)
    shrub = np.vstack([_blob((1.0, 0.2, z), 0.12, 150, rng) for z in np.arange(0.08, 0.9, 0.06)])
    twig = np.c_[np.linspace(-0.9, -0.5, 400), np.full(400, -0.5), np.full(400, 0.12)]
    twig += 0.003 * rng.normal(size=twig.shape)
    crown = np.vstack([_blob((0.6, -0.2, z), 0.1, 150, rng) for z in np.arange(1.6, 1.9, 0.05)])
    cloud = np.vstack([pts, shrub, twig, crown])
    prep = prepare(Cloud(cloud + GEO), PrepareParams(voxel_size_m=None))
    kept = prep.global_points - GEO
    near = lambda c, r: np.linalg.norm(kept[:, :2] - np.asarray(c)[None, :2], axis=1) < r  # noqa: E731
    assert near((1.0, 0.2), 0.15).sum() == 0, "the shrub is understory"
    assert (near((-0.7, -0.5), 0.25) & (kept[:, 2] < 0.3)).sum() == 0, "the twig is litter"
    assert near((0.6, -0.2), 0.1).sum() >= 0.9 * len(crown), "the crown piece stays"
    assert (np.hypot(kept[:, 0], kept[:, 1]) < 0.2).sum() >= 0.98 * (pts[:n_stem, 2] > 0.06).sum()
    foot = prep.foot
    assert foot is not None and foot.plane is not None
    xy_global = foot.xy + np.asarray(prep.frame.origin)[:2] - GEO[:2]
    assert np.hypot(*xy_global) < 0.03  # the stem's axis is at (0, 0)
    assert foot.z_m + prep.frame.origin[2] - GEO[2] == pytest.approx(0.0, abs=0.02)


# --------------------------------------------------------------------------- normals


@pytest.mark.parametrize("radius", [0.01, 0.15, 0.5])
def test_normals_on_a_cylinder_point_outward(radius):
    pts, radial = tube(radius=radius, height=1.0, n=int(4000 + 40000 * radius), noise_m=0.0003)
    normals = estimate_normals(pts, 24)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12, rtol=0)
    outward = np.einsum("nd,nd->n", normals, radial) > 0
    assert outward.mean() >= 0.98


def test_normals_from_axis_points():
    pts, radial = tube(radius=0.05, height=1.0, n=3000)
    axis = np.c_[np.zeros(50), np.zeros(50), np.linspace(0, 1, 50)]
    normals = estimate_normals(pts, 16, axis_points=axis)
    assert (np.einsum("nd,nd->n", normals, radial) > 0).all()


def test_prepared_normals_point_outward_and_are_deterministic():
    pts, _ = tube(radius=0.1, height=1.5, n=8000, noise_m=0.0005)
    a = prepare(Cloud(pts + GEO))
    b = prepare(Cloud(pts + GEO))
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.normals, b.normals)
    assert a.steps == b.steps
    g = a.global_points - GEO
    radial = np.c_[g[:, :2], np.zeros(len(g))]
    assert (np.einsum("nd,nd->n", a.normals, radial) > 0).mean() >= 0.98
    assert 0.002 < a.spacing_m < 0.01


def test_normals_can_be_skipped():
    pts, _ = tube(n=2000)
    prep = prepare(pts, PrepareParams(normals_neighbors=None))
    assert prep.normals is None


def test_georeferenced_input_prepares_like_local_input():
    pts, _ = tube(radius=0.1, height=1.5, n=6000, noise_m=0.0005)
    local = prepare(pts)
    geo = prepare(pts + GEO)
    assert len(local) == len(geo)
    np.testing.assert_allclose(geo.global_points - GEO, local.global_points, atol=1e-6, rtol=0)
    np.testing.assert_allclose(geo.normals, local.normals, atol=1e-6, rtol=0)
    assert geo.frame.origin[0] == pytest.approx(GEO[0], abs=1.0)


# --------------------------------------------------------------------------- leaves


def test_leaves_are_reported_on_leaf_on_input_only():
    stem, _ = tube(radius=0.08, height=2.0, n=10000, noise_m=0.0005)
    foliage = leaves(n_leaves=500, centre=(0.0, 0.0, 1.6), crown_radius=0.45)
    leafy = prepare(np.vstack([stem, foliage]))
    bare = prepare(stem)
    assert leafy.leaves_present and leafy.leaf_fraction > 0.3
    assert not bare.leaves_present and bare.leaf_fraction < 0.05
    summary = leafy.summary()
    assert summary["leaves_present"] is True
    assert [s["step"] for s in summary["steps"]] == [
        "voxel_downsample",
        "outlier_removal",
        "ground_removal",
        "understory_removal",
    ]
