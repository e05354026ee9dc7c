"""Known answers on a 0.30 m × 2 m vertical cylinder scanned from 10 m."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.conftest import cylinder_arrays
from tests.scan.test_scan_precision import BOUND_M
from treesim.scan import ScannerSpec, Station, ring_layout, scan
from treesim.scene import MeshPart, Scene

R, H, D, ZS, SECTIONS = 0.15, 2.0, 10.0, 1.5, 2048
UTM = (500000.0, 5500000.0, 300.0)
# The analytic facets differ from the mesh by the rounding of its vertices: half an ULP
# of the largest coordinate (y = 5.5e6 m: 4.7e-10 m; 0 at the origin up to 1e-16 m).
VERTEX_ROUNDING_M = float(np.spacing(5.5e6)) / 2
# docs/concepts.md, "Precision": points lie within BOUND_M of the mesh, so of the analytic facets
# within BOUND_M + the vertices' rounding.
ON_FACET_M = BOUND_M + VERTEX_ROUNDING_M


def cylinder_scene(base=(0.0, 0.0, 0.0)) -> Scene:
    v, f = cylinder_arrays(R, H, SECTIONS, base)
    return Scene([MeshPart(vertices=v, faces=f, label="wood", name="cylinder")])


def analytic_count(res: float, el0: float = -40.0) -> int:
    """Pulses of a full-turn grid that hit the analytic cylinder seen from (D, 0, ZS)."""
    n_az = int(round(360 / res))
    alpha = np.radians(np.arange(n_az) * res) - np.pi
    alpha = (alpha + np.pi) % (2 * np.pi) - np.pi
    ok = (np.abs(D * np.sin(alpha)) < R) & (np.cos(alpha) > 0)
    a = alpha[ok]
    s = D * np.cos(a) - np.sqrt(R * R - (D * np.sin(a)) ** 2)  # horizontal range to surface
    top = np.degrees(np.arctan2(H - ZS, s))
    bot = np.degrees(np.arctan2(0 - ZS, s))
    i_top = np.ceil((top - el0) / res) - 1
    i_bot = np.floor((bot - el0) / res) + 1
    return int(np.sum(i_top - i_bot + 1))


@pytest.mark.parametrize("base", [(0.0, 0.0, 0.0), UTM], ids=["local", "utm"])
def test_point_count_and_float64_accuracy(base):
    scene = cylinder_scene(base)
    st = Station(position_m=(base[0] + D, base[1], base[2] + ZS))
    res = scan(
        scene, [st], ScannerSpec(horizontal_resolution_deg=0.04, vertical_resolution_deg=0.04)
    )
    expected = analytic_count(0.04)
    n = len(res.cloud)
    assert abs(n - expected) <= 0.02 * expected, (n, expected)
    p = res.cloud.points - np.asarray(base)
    # every point lies on the mesh surface within the manual's bound: radially between the
    # facet planes (r cos(pi/n)) and the vertices (r), and on the side wall in z
    rad = np.hypot(p[:, 0], p[:, 1])
    assert rad.max() <= R + ON_FACET_M
    assert rad.min() >= R * math.cos(math.pi / SECTIONS) - ON_FACET_M
    # distance to the hit facet's plane (facets are known analytically)
    ang = np.arctan2(p[:, 1], p[:, 0]) % (2 * np.pi)
    k = np.floor(ang / (2 * np.pi / SECTIONS))
    mid = (k + 0.5) * 2 * np.pi / SECTIONS
    plane_d = np.abs(
        p[:, 0] * np.cos(mid) + p[:, 1] * np.sin(mid) - R * math.cos(math.pi / SECTIONS)
    )
    assert plane_d.max() <= ON_FACET_M
    assert p[:, 2].min() >= -ON_FACET_M and p[:, 2].max() <= H + ON_FACET_M
    # ranges are float64 distances from the station
    rng = np.linalg.norm(res.cloud.points - st.position, axis=1)
    np.testing.assert_allclose(res.cloud.fields["range_m"], rng, atol=BOUND_M, rtol=0)


def test_one_station_sees_half_three_see_all():
    scene = cylinder_scene()
    # fine in azimuth so the arc near the silhouette is sampled, coarse in elevation
    spec = ScannerSpec(horizontal_resolution_deg=0.002, vertical_resolution_deg=1.0)
    bins = 180

    def polar(stations):
        res = scan(scene, stations, spec)
        return np.degrees(np.arctan2(res.cloud.points[:, 1], res.cloud.points[:, 0]))

    ang = polar([Station(position_m=(D, 0.0, ZS))])
    # the visible arc is |theta| <= acos(r/D) = 89.14 deg: 49.5 % of the circumference
    limit = math.degrees(math.acos(R / D))
    assert np.abs(ang).max() <= limit + 1e-6
    one = np.unique(np.floor((ang % 360) / (360 / bins))).size / bins
    assert 0.46 <= one <= 2 * limit / 360 + 1 / bins, one
    ang3 = polar(ring_layout(3, distance_m=D, height_m=ZS, centre_xy=(0, 0)))
    three = np.unique(np.floor((ang3 % 360) / (360 / bins))).size / bins
    assert three == 1.0


def test_window_casts_same_points_with_far_fewer_rays():
    scene = cylinder_scene()
    st = [Station(position_m=(D, 0.0, ZS))]
    spec = ScannerSpec(horizontal_resolution_deg=0.1, vertical_resolution_deg=0.1)
    win = scan(scene, st, spec, window=True)
    full = scan(scene, st, spec, window=False)
    assert len(win.cloud) == len(full.cloud) > 0
    kw = np.lexsort((win.cloud.fields["scan_column"], win.cloud.fields["scan_line"]))
    kf = np.lexsort((full.cloud.fields["scan_column"], full.cloud.fields["scan_line"]))
    np.testing.assert_array_equal(win.cloud.points[kw], full.cloud.points[kf])
    for name in ("scan_line", "scan_column", "label", "range_m"):
        np.testing.assert_array_equal(win.cloud.fields[name][kw], full.cloud.fields[name][kf])
    print(f"rays cast: window {win.rays_cast}, full field of view {full.rays_cast}")
    assert full.rays_cast == spec.n_azimuth * spec.n_elevation
    assert win.rays_cast * 50 < full.rays_cast


def test_chunking_does_not_change_the_result():
    scene = cylinder_scene()
    st = ring_layout(3, distance_m=D, height_m=ZS, centre_xy=(0, 0))
    spec = ScannerSpec(
        horizontal_resolution_deg=0.1,
        vertical_resolution_deg=0.1,
        range_noise_sd_m=0.01,
        angular_jitter_sd_deg=0.01,
        seed=3,
    )
    a = scan(scene, st, spec)
    b = scan(scene, st, spec, chunk_rays=997)
    np.testing.assert_array_equal(a.cloud.points, b.cloud.points)
    np.testing.assert_array_equal(a.cloud.fields["intensity"], b.cloud.fields["intensity"])


def test_seeded_noise_is_reproducible_and_has_the_requested_sigma():
    scene = cylinder_scene()
    st = [Station(position_m=(D, 0.0, ZS))]
    base = ScannerSpec(horizontal_resolution_deg=0.03, vertical_resolution_deg=0.03)
    sigma = 0.005
    clean = scan(scene, st, base)
    noisy1 = scan(scene, st, base.with_(range_noise_sd_m=sigma, seed=7))
    noisy2 = scan(scene, st, base.with_(range_noise_sd_m=sigma, seed=7))
    other = scan(scene, st, base.with_(range_noise_sd_m=sigma, seed=8))
    np.testing.assert_array_equal(noisy1.cloud.points, noisy2.cloud.points)
    assert not np.array_equal(noisy1.cloud.points, other.cloud.points)
    # the noise-free scan hits the same pulses; compare range per pulse
    assert len(clean.cloud) == len(noisy1.cloud)
    err = noisy1.cloud.fields["range_m"] - clean.cloud.fields["range_m"]
    n = len(err)
    assert n > 10000
    assert abs(err.mean()) < 4 * sigma / math.sqrt(n)
    assert abs(err.std() / sigma - 1) < 0.03
    # points move along the beam: the noisy point is at the noisy range
    rng = np.linalg.norm(noisy1.cloud.points - st[0].position, axis=1)
    np.testing.assert_allclose(rng, noisy1.cloud.fields["range_m"], atol=BOUND_M, rtol=0)


def test_angular_jitter_is_seeded_and_scaled():
    scene = cylinder_scene()
    st = [Station(position_m=(D, 0.0, ZS))]
    base = ScannerSpec(horizontal_resolution_deg=0.05, vertical_resolution_deg=0.05)
    a = scan(scene, st, base.with_(angular_jitter_sd_deg=0.01, seed=1))
    b = scan(scene, st, base.with_(angular_jitter_sd_deg=0.01, seed=1))
    np.testing.assert_array_equal(a.cloud.points, b.cloud.points)
    # elevation of each point vs its grid elevation: spread = the jitter sigma
    rel = a.cloud.points - st[0].position
    el = np.degrees(np.arctan2(rel[:, 2], np.hypot(rel[:, 0], rel[:, 1])))
    grid_el = -40.0 + a.cloud.fields["scan_line"] * 0.05
    assert abs((el - grid_el).std() / 0.01 - 1) < 0.05
