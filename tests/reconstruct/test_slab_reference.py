"""The slab reference on analytic shapes whose diameters, base and height are exact."""

from __future__ import annotations

import numpy as np
import pytest

from tests.reconstruct.slab_reference import (
    coverage_deg,
    fit_circle,
    reference,
    render_slab,
)

NOISE_M = 0.002


def stem_points(
    rng: np.random.Generator,
    radius_at,
    z0: float,
    z1: float,
    *,
    centre_at=lambda z: (0.0, 0.0),
    arc_deg: tuple[float, float] = (0.0, 360.0),
    per_m2: float = 6000.0,
) -> np.ndarray:
    """Points on a surface of revolution ``radius_at(z)`` between ``z0`` and ``z1`` with
    radial noise ``NOISE_M``, seen over ``arc_deg``."""
    rmax = max(radius_at(z0), radius_at(z1))
    n = int(per_m2 * 2 * np.pi * rmax * (z1 - z0) * (arc_deg[1] - arc_deg[0]) / 360)
    z = rng.uniform(z0, z1, n)
    a = np.radians(rng.uniform(*arc_deg, n))
    r = radius_at(z) + rng.normal(0.0, NOISE_M, n)
    cx, cy = centre_at(z)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a), z])


def ground(rng: np.random.Generator, half_m: float = 1.5, per_m2: float = 2000.0, slope=0.0):
    """A square of ground at z = slope * x (noise 5 mm), with a few points below it."""
    n = int(per_m2 * (2 * half_m) ** 2)
    xy = rng.uniform(-half_m, half_m, (n, 2))
    z = slope * xy[:, 0] + rng.normal(0.0, 0.005, n)
    below = np.column_stack([rng.uniform(-1, 1, (5, 2)), rng.uniform(-0.5, -0.1, 5)])
    return np.vstack([np.column_stack([xy, z]), below])


def crown(rng: np.random.Generator, z_m: float, radius_m: float = 1.0, n: int = 3000):
    """A blob of points (a crown) centred above the stem at ``z_m``."""
    p = rng.normal(0.0, radius_m / 2, (n, 3))
    return p + np.array([0.0, 0.0, z_m])


def test_circle_fit_and_coverage_are_exact_on_an_arc():
    rng = np.random.default_rng(0)
    a = np.radians(rng.uniform(0, 150, 400))
    xy = np.column_stack([1.0 + 0.2 * np.cos(a), -2.0 + 0.2 * np.sin(a)])
    c = fit_circle(xy)
    assert c is not None
    assert (c.cx_m, c.cy_m, c.radius_m) == pytest.approx((1.0, -2.0, 0.2), abs=1e-9)
    assert coverage_deg(xy, 1.0, -2.0) == pytest.approx(150.0, abs=10.0)


def test_noisy_cylinder_on_ground_gives_its_diameter_base_and_height():
    rng = np.random.default_rng(1)
    pts = np.vstack(
        [
            stem_points(rng, lambda z: 0.15 + 0 * z, 0.0, 6.0),
            ground(rng),
            crown(rng, 6.0, 0.6, 500),
        ]
    )
    pts[:, 2] += 250.0  # a real height above sea level; the reference must not care
    ref = reference(pts)
    assert ref.base_source == "ground plane"
    assert ref.base_z_m == pytest.approx(250.0, abs=0.01)
    assert ref.dbh_slab.verdict == "clean", ref.dbh_slab.describe()
    assert ref.dbh_m == pytest.approx(0.30, abs=0.003)
    assert ref.dbh_slab.centre_xy_m == pytest.approx((0.0, 0.0), abs=0.003)
    assert ref.dbh_slab.rms_m == pytest.approx(NOISE_M, rel=0.3)
    assert ref.dbh_slab.coverage_deg >= 350
    # the top: the crown's highest point that has neighbours (not a lone outlier)
    top = pts[:, 2].max()
    assert ref.top_z_m <= top and ref.height_m == pytest.approx(top - 250.0, abs=0.3)
    h, d = ref.taper()
    assert len(h) >= 8 and np.abs(d - 0.30).max() < 0.004


def test_cone_on_a_sloping_ground_gives_its_taper():
    rng = np.random.default_rng(2)
    radius = lambda z: 0.20 - 0.015 * z  # noqa: E731
    pts = np.vstack(
        [stem_points(rng, radius, -0.2, 8.0), ground(rng, slope=np.tan(np.radians(10)))]
    )
    ref = reference(pts)
    # the ground plane under the axis is at z = 0 whatever the slope
    assert ref.base_z_m == pytest.approx(0.0, abs=0.015)
    assert ref.dbh_slab.clean
    assert ref.dbh_m == pytest.approx(2 * radius(1.3), abs=0.004)
    h, d = ref.taper()
    assert h.max() >= 6.0
    assert np.abs(d - 2 * radius(h)).max() < 0.005


def test_one_sided_scan_of_150_degrees_still_gives_the_diameter():
    rng = np.random.default_rng(3)
    pts = np.vstack(
        [stem_points(rng, lambda z: 0.12 + 0 * z, 0.0, 4.0, arc_deg=(20, 170)), ground(rng)]
    )
    ref = reference(pts)
    s = ref.dbh_slab
    assert s.coverage_deg == pytest.approx(150, abs=15)
    assert s.verdict == "clean", s.describe()
    assert s.diameter_m == pytest.approx(0.24, abs=0.004)


def test_branch_and_shrub_beside_the_stem_are_not_the_stem():
    rng = np.random.default_rng(4)
    stem = stem_points(rng, lambda z: 0.15 + 0 * z, 0.0, 5.0)
    # a branch of radius 4 cm leaving the stem at 1.2 m, 45° up, towards +x
    t = rng.uniform(0, 1.2, 4000)
    a = rng.uniform(0, 2 * np.pi, 4000)
    u = np.array([np.sqrt(0.5), 0.0, np.sqrt(0.5)])
    e1, e2 = np.array([0.0, 1.0, 0.0]), np.cross(u, [0.0, 1.0, 0.0])
    branch = (
        np.array([0.1, 0.0, 1.2])
        + t[:, None] * u
        + 0.04 * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2)
    )
    # a shrub 35 cm from the stem's surface, up to 1.6 m
    shrub = np.column_stack(
        [rng.normal(-0.55, 0.12, 3000), rng.normal(0.1, 0.12, 3000), rng.uniform(0, 1.6, 3000)]
    )
    pts = np.vstack([stem, branch, shrub, ground(rng)])
    ref = reference(pts)
    s = ref.dbh_slab
    assert s.verdict == "clean", s.describe()
    assert s.diameter_m == pytest.approx(0.30, abs=0.003)
    assert s.centre_xy_m == pytest.approx((0.0, 0.0), abs=0.003)
    assert ref.base_z_m == pytest.approx(0.0, abs=0.01)


def test_a_stem_forked_below_breast_height_is_not_clean():
    rng = np.random.default_rng(5)
    trunk = stem_points(rng, lambda z: 0.12 + 0 * z, 0.0, 1.0)
    left = stem_points(
        rng, lambda z: 0.08 + 0 * z, 1.0, 4.0, centre_at=lambda z: (-(0.09 + 0.25 * (z - 1)), 0)
    )
    right = stem_points(
        rng, lambda z: 0.08 + 0 * z, 1.0, 4.0, centre_at=lambda z: (0.09 + 0.25 * (z - 1), 0)
    )
    ref = reference(np.vstack([trunk, left, right, ground(rng)]))
    below = [s for s in ref.slabs if s.height_m < 1.0]
    assert below and all(s.clean for s in below)
    assert below[0].diameter_m == pytest.approx(0.24, abs=0.004)
    assert ref.dbh_slab.verdict == "forked", ref.dbh_slab.describe()
    assert ref.dbh_m is None
    assert all(s.height_m <= 1.0 for s in ref.slabs if s.clean)


def test_too_few_points_is_sparse():
    rng = np.random.default_rng(6)
    pts = np.vstack([stem_points(rng, lambda z: 0.1 + 0 * z, 0.0, 4.0, per_m2=60), ground(rng)])
    assert reference(pts).dbh_slab.verdict == "sparse"


def test_render_writes_a_png(tmp_path):
    rng = np.random.default_rng(7)
    ref = reference(np.vstack([stem_points(rng, lambda z: 0.1 + 0 * z, 0.0, 3.0), ground(rng)]))
    out = render_slab(ref.dbh_slab, tmp_path / "img" / "slab.png", title="cylinder")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="points must be"):
        reference(np.zeros((5, 3)))
    bad = np.ones((100, 3))
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        reference(bad)


def test_a_sparse_trunk_under_a_dense_crown_keeps_its_foot():
    """A leaf-on tree whose 2 m of trunk holds under 0.5 % of the points (rTLS's tree in
    tests/data/trees): the cloud's low level is the trunk's foot, not the crown's base (a
    0.5th percentile of the heights put it at 1.9 m, the 1.3 m slab in the crown, 64 cm)."""
    rng = np.random.default_rng(7)
    trunk = stem_points(rng, lambda z: 0.09 + 0 * z, 0.0, 2.4, per_m2=700.0)
    ball = rng.uniform(-1.0, 1.0, (400_000, 3))  # a crown filling a ball 2.2-6.2 m up
    leaves = 2.0 * ball[np.linalg.norm(ball, axis=1) <= 1.0] + [0.0, 0.0, 4.2]
    pts = np.vstack([trunk, leaves])
    assert (pts[:, 2] < 2.0).mean() < 0.005  # the case: a sparse trunk under a dense crown
    ref = reference(pts)
    assert ref.base_z_m == pytest.approx(0.0, abs=0.02)
    assert ref.height_m == pytest.approx(6.2, abs=0.1)
    assert ref.dbh_slab.verdict == "clean", ref.dbh_slab.describe()
    assert ref.dbh_m == pytest.approx(0.18, abs=0.005)
