"""The occlusion profile: coverage and density by height slice, with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from tests.compare.shapes import open_cylinder, sample_faces
from treesim.cloud import Cloud
from treesim.compare import compare
from treesim.report import ReportData
from treesim.report.profile import auto_bin_m, occlusion_profile

R, H, N = 0.2, 1.2, 24_000
TAU = 0.01


@pytest.fixture(scope="module")
def layered():
    """Station 0 sees the cylinder wall below 0.6 m, station 1 only above 0.9 m: the
    slices 0.6-0.8 m (but for τ at its lower edge) and 0.8-0.9 m are seen by nobody."""
    v, f = open_cylinder(R, H, 256)
    p = sample_faces(v, f, np.ones(len(f), bool), N, seed=3)
    z = p[:, 2]
    s0, s1 = z < 0.6, z > 0.9
    cloud = Cloud(
        np.concatenate([p[s0], p[s1]]),
        {"station": np.repeat(np.array([0, 1], np.uint16), [s0.sum(), s1.sum()])},
    )
    res = compare(cloud, (v, f), tolerance_m=TAU)
    return res, occlusion_profile(ReportData.from_comparison(res), bin_m=0.2)


def test_slices_and_coverage_follow_what_each_station_saw(layered):
    res, p = layered
    assert p["bin_m"] == 0.2 and p["stations"] == ["S0", "S1"]
    assert p["edges_m"] == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.2])
    c0, c1, call = p["coverage"]["S0"], p["coverage"]["S1"], p["coverage"]["all"]
    assert min(c0[:3]) > 0.99 and max(c1[:3]) == 0.0  # below 0.6 m: station 0 only
    assert c0[3] < 0.1 and c1[3] == 0.0  # 0.6-0.8: τ = 1 cm of 20 cm beside the seen part
    assert c1[4] == pytest.approx(0.5, abs=0.1) and c0[4] == 0.0  # 0.8-1.0: half above 0.9
    assert c1[5] > 0.99 and c0[5] == 0.0
    assert call == pytest.approx(np.maximum(c0, c1), abs=0.02)
    # the slices, weighted by their samples, give back the comparison's figures
    n = np.array(p["reference_points"])
    for key, cov in (("all", res.coverage), ("S0", res.by_station[0]["coverage"])):
        assert (np.array(p["coverage"][key]) * n).sum() / n.sum() == pytest.approx(cov, abs=1e-12)


def test_density_is_points_per_square_metre_of_surface(layered):
    res, p = layered
    rho = N / (2 * np.pi * R * H)  # the sampling's density, everywhere on the wall
    d0, d1 = p["density_per_m2"]["S0"], p["density_per_m2"]["S1"]
    assert d0[:3] == pytest.approx([rho] * 3, rel=0.1)
    assert d1[5] == pytest.approx(rho, rel=0.1)
    assert d0[3] == d0[4] == d0[5] == 0.0
    counts = p["cloud_points"]
    assert sum(counts["all"]) == sum(counts["S0"]) + sum(counts["S1"]) == len(res.cloud)
    assert sum(p["area_m2"]) == pytest.approx(2 * np.pi * R * H, rel=0.02)


def test_a_cloud_reference_counts_points_on_both_sides():
    rng = np.random.default_rng(0)
    ref = Cloud(
        np.column_stack([rng.uniform(0, 1, 4000), rng.uniform(0, 1, 4000), rng.uniform(0, 2, 4000)])
    )
    base = ref.points[:, 2].min()  # slices start at the reference's lowest point
    cloud = Cloud(ref.points[ref.points[:, 2] < base + 1.0] + [1e-4, 0.0, 0.0])
    p = occlusion_profile(ReportData.from_comparison(compare(cloud, ref, tolerance_m=0.01)))
    assert p["bin_m"] == 0.1 and "density_per_m2" not in p and p["stations"] == []
    assert p["cloud_points"]["all"][10:] == [0] * 10
    assert p["cloud_points"]["all"][:10] == p["reference_points"][:10]
    assert p["coverage"]["all"][:10] == [1.0] * 10 and p["coverage"]["all"][11:] == [0.0] * 9


@pytest.mark.parametrize(
    ("height", "step"), [(1.2, 0.1), (3.7, 0.2), (20.0, 1.0), (45.0, 2.5), (0.0, 1.0)]
)
def test_automatic_slices_are_round(height, step):
    assert auto_bin_m(height) == step
    if height:
        assert height / step <= 20
