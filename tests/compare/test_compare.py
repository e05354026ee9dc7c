"""Known answers for treesim.compare: exact distances, occlusion, splits, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.compare.shapes import UTM, centroids, open_cylinder, sample_faces, sphere_mesh
from treesim.cloud import LABEL_CODES, Cloud
from treesim.compare import CompareParams, compare, write_comparison
from treesim.errors import (
    EmptyInputError,
    InvalidGeometryError,
    InvalidParameterError,
    TreesimError,
)
from treesim.geometry import closest_points_on_triangles, point_spacing, well_conditioned
from treesim.io import read_cloud
from treesim.scene import MeshPart, Scene

REQUIRED_STATS = ("n", "mean_m", "rms_m", "median_m", "p95_m", "p99_m", "max_m")


# -- exact point-to-triangle -----------------------------------------------------------
def test_closest_point_on_triangle_matches_dense_search():
    """Ericson's regions against a brute-force search over a fine barycentric grid."""
    rng = np.random.default_rng(5)
    n = 60
    a, b, c = rng.normal(size=(3, n, 3))
    p = rng.normal(size=(n, 3)) * 2.0
    q = closest_points_on_triangles(p, a, b, c)
    s = np.linspace(0.0, 1.0, 301)
    u, w = np.meshgrid(s, s)
    keep = u + w <= 1.0
    u, w = u[keep], w[keep]
    for i in range(n):
        grid = a[i] + u[:, None] * (b[i] - a[i]) + w[:, None] * (c[i] - a[i])
        brute = np.linalg.norm(grid - p[i], axis=1).min()
        exact = np.linalg.norm(q[i] - p[i])
        assert exact <= brute + 1e-12  # never worse than any point of the triangle
        assert brute - exact <= 0.02 * np.linalg.norm(b[i] - a[i]) + 0.02 * np.linalg.norm(
            c[i] - a[i]
        )  # and the grid's resolution away from the best grid point


# -- accuracy known answers ----------------------------------------------------------
@pytest.mark.parametrize("base", [(0.0, 0.0, 0.0), UTM], ids=["local", "utm"])
def test_cloud_sampled_on_mesh_has_zero_accuracy(base):
    v, f = open_cylinder(0.15, 2.0, 256, base)
    pts = sample_faces(v, f, np.ones(len(f), bool), 20_000, seed=7)
    res = compare(Cloud(pts), (v, f))
    assert res.accuracy.n == 20_000
    assert res.accuracy.max_m <= 1e-6
    assert res.accuracy_m.dtype == np.float64
    # float64 refinement: far below float32's ~0.1 m spacing at y = 5.5e6
    assert res.accuracy.max_m <= 1e-8
    assert res.coverage > 0.99


@pytest.mark.parametrize("base", [(0.0, 0.0, 0.0), UTM], ids=["local", "utm"])
@pytest.mark.parametrize("delta", [0.01, -0.01], ids=["outside", "inside"])
def test_sphere_offset_by_delta(base, delta):
    """Points on a sphere of radius r + δ against an icosphere inscribed in radius r.

    Every point of the icosphere lies between the sphere of radius ρ_min (the smallest
    distance from the centre to a face plane) and the sphere of radius r (its vertices).
    For a point p at radius R = r + δ > r, the closest point q has |q| ≤ r, so
    d = |p − q| ≥ R − r = δ; and the surface point on p's own ray lies at a radius ≥ ρ_min,
    so d ≤ R − ρ_min = δ + (r − ρ_min). Inside (δ < 0), symmetrically,
    |δ| − (r − ρ_min) ≤ d ≤ |δ|. The facet error is the sagitta s = r − ρ_min.
    """
    r = 1.0
    v, f = sphere_mesh(r, subdivisions=4, centre=base)
    local = v - np.asarray(base)
    n = np.cross(local[f[:, 1]] - local[f[:, 0]], local[f[:, 2]] - local[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rho_min = np.abs(np.einsum("ij,ij->i", n, local[f[:, 0]])).min()
    sag = r - rho_min
    assert 0 < sag < 2e-3  # 5120 facets: 1.1 mm on a 1 m sphere

    rng = np.random.default_rng(3)
    u = rng.normal(size=(20_000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pts = u * (r + delta) + np.asarray(base)
    res = compare(Cloud(pts), (v, f), tolerance_m=0.05)
    d = res.accuracy_m
    eps = 1e-9 if base == (0.0, 0.0, 0.0) else 1e-8  # float64 at 5.5e6 m: ~1e-9 m
    if delta > 0:
        lo, hi = delta, delta + sag
    else:
        lo, hi = -delta - sag, -delta
    assert d.min() >= lo - eps
    assert d.max() <= hi + eps
    # the figures say so
    st = res.accuracy
    assert lo - eps <= st.median_m <= st.p95_m <= st.p99_m <= st.max_m <= hi + eps
    assert lo - eps <= st.mean_m <= hi + eps
    assert abs(st.rms_m - math.sqrt(np.mean(d**2))) < 1e-15


def test_half_cylinder_coverage_shows_occlusion():
    """A cloud on exactly half of an open cylinder: accuracy 0, coverage 1/2 + τ/(πr).

    The uncovered half is within τ of the covered one only along its two edges (bands of
    width τ along the whole height): coverage = (πrh + 2τh) / (2πrh) = 1/2 + τ/(πr). The
    farthest uncovered point (angle π) is a chord r√2 from the nearest edge (angles ±π/2).
    """
    r, h = 0.2, 1.0
    v, f = open_cylinder(r, h, 512)
    half = centroids(v, f)[:, 0] > 0
    pts = sample_faces(v, f, half, 40_000, seed=11)
    res = compare(Cloud(pts), (v, f), seed=2)
    assert res.accuracy.max_m <= 1e-9
    tau = res.tolerance_m
    assert tau == pytest.approx(3 * res.point_spacing_m)
    expected = 0.5 + tau / (math.pi * r)
    assert res.coverage == pytest.approx(expected, abs=0.01)
    assert res.completeness.max_m == pytest.approx(r * math.sqrt(2), abs=3e-3)
    assert res.hausdorff_m == res.completeness.max_m
    # one-sided numbers cannot hide the missing half
    assert res.chamfer_m > 0.25 * res.completeness.mean_m
    assert res.completeness.p95_m > 0.25  # the far side is far from every point

    # an explicit τ changes coverage exactly as predicted
    res2 = compare(Cloud(pts), (v, f), tolerance_m=0.02, seed=2)
    assert res2.coverage == pytest.approx(0.5 + 0.02 / (math.pi * r), abs=0.01)


def test_agrees_with_pymeshlab_hausdorff():
    """Point-to-mesh distances against pymeshlab's Hausdorff filter on the same data.

    The cloud is handed to pymeshlab as a vertex-only mesh and every vertex is sampled
    (samplevert=True, samplenum = n), with maxdist large enough that no point is dropped.
    pymeshlab computes in single precision, hence the 1e-5 m tolerance.
    """
    pymeshlab = pytest.importorskip("pymeshlab")
    v, f = sphere_mesh(1.0, subdivisions=3)
    rng = np.random.default_rng(8)
    u = rng.normal(size=(3000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pts = u * rng.uniform(0.7, 1.4, size=(3000, 1))
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=pts))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v, face_matrix=f))
    ref = ms.get_hausdorff_distance(
        sampledmesh=0,
        targetmesh=1,
        samplevert=True,
        sampleface=False,
        samplenum=len(pts),
        maxdist=pymeshlab.PureValue(100.0),
    )
    assert ref["n_samples"] == len(pts)
    res = compare(Cloud(pts), (v, f))
    assert res.accuracy.max_m == pytest.approx(ref["max"], abs=1e-5)
    assert res.accuracy.mean_m == pytest.approx(ref["mean"], abs=1e-5)
    assert res.accuracy.rms_m == pytest.approx(ref["RMS"], abs=1e-5)
    assert res.accuracy_m.min() == pytest.approx(ref["min"], abs=1e-5)


# -- cloud references ----------------------------------------------------------------
def _grid(nx: int, ny: int, spacing: float) -> np.ndarray:
    x, y = np.meshgrid(np.arange(nx) * spacing, np.arange(ny) * spacing)
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


@pytest.mark.parametrize("base", [(0.0, 0.0, 0.0), UTM], ids=["local", "utm"])
def test_cloud_to_cloud_offset(base):
    """A grid against the same grid lifted by δ: every distance is δ, both ways."""
    g = _grid(80, 80, 0.01) + np.asarray(base)
    delta = 0.003
    res = compare(Cloud(g + [0.0, 0.0, delta]), Cloud(g))
    assert np.abs(res.accuracy_m - delta).max() < 1e-9
    assert np.abs(res.completeness_m - delta).max() < 1e-9
    assert res.point_spacing_m == pytest.approx(0.01, abs=1e-9)
    assert res.tolerance_m == pytest.approx(0.03, abs=1e-9)  # the documented 3 × spacing
    assert res.coverage == 1.0
    assert res.hausdorff_m == pytest.approx(delta, abs=1e-9)
    assert res.chamfer_m == pytest.approx(delta, abs=1e-9)
    assert res.sample_spacing_m is None
    assert res.reference_info["kind"] == "cloud"


def test_cloud_to_cloud_half_coverage():
    g = _grid(100, 100, 0.01)
    half = g[g[:, 0] < 0.495]
    res = compare(Cloud(half), Cloud(g), tolerance_m=0.005)
    assert res.accuracy.max_m == 0.0
    assert res.coverage == pytest.approx(0.5, abs=1e-12)
    assert res.completeness.max_m == pytest.approx(0.5, abs=1e-9)


# -- splits ----------------------------------------------------------------------------
def test_splits_by_label_and_station():
    """Two stations each see one half (wood / leaf) of a labelled cylinder."""
    r = 0.2
    v, f = open_cylinder(r, 1.0, 512)
    east = centroids(v, f)[:, 0] > 0
    scene = Scene(
        [
            MeshPart(vertices=v, faces=f[east], label="wood", name="east"),
            MeshPart(vertices=v, faces=f[~east], label="leaf", name="west"),
        ]
    )
    p0 = sample_faces(v, f, east, 20_000, seed=1)
    p1 = sample_faces(v, f, ~east, 20_000, seed=2)
    cloud = Cloud(
        np.concatenate([p0, p1]),
        {
            "station": np.repeat(np.array([0, 1], dtype=np.uint16), 20_000),
            "label": np.repeat(
                np.array([LABEL_CODES["wood"], LABEL_CODES["leaf"]], dtype=np.uint8), 20_000
            ),
        },
    )
    res = compare(cloud, scene)
    assert res.coverage > 0.99
    assert set(res.by_label) == {"wood", "leaf"}
    for name in ("wood", "leaf"):
        e = res.by_label[name]
        assert e["accuracy"]["n"] == 20_000
        assert e["accuracy"]["max_m"] <= 1e-9
        assert e["coverage"] > 0.99
        assert e["completeness"]["n"] > 0
    assert sum(e["completeness"]["n"] for e in res.by_label.values()) == res.completeness.n
    assert set(res.by_station) == {0, 1}
    expected = 0.5 + res.tolerance_m / (math.pi * r)
    for e in res.by_station.values():
        assert e["points"] == 20_000
        assert e["coverage"] == pytest.approx(expected, abs=0.012)
    # reference samples carry their part's label
    assert set(np.unique(res.reference_label)) == {LABEL_CODES["wood"], LABEL_CODES["leaf"]}


def test_no_split_fields_no_splits():
    v, f = sphere_mesh(1.0, 2)
    pts = sample_faces(v, f, np.ones(len(f), bool), 2000)
    res = compare(Cloud(pts), (v, f))
    assert res.by_label == {} and res.by_station == {}


# -- sampling, tolerance and parameters ------------------------------------------------
def test_sampling_is_seeded_and_density_follows_spacing():
    v, f = open_cylinder(0.2, 1.0, 128)
    pts = sample_faces(v, f, np.ones(len(f), bool), 30_000, seed=4)
    a = compare(Cloud(pts), (v, f), seed=5)
    b = compare(Cloud(pts), (v, f), seed=5)
    c = compare(Cloud(pts), (v, f), seed=6)
    assert np.array_equal(a.reference_points, b.reference_points)
    assert a.completeness == b.completeness
    assert not np.array_equal(a.reference_points, c.reference_points)
    area = a.reference_info["area_m2"]
    assert a.reference_info["samples"] == math.ceil(area / a.point_spacing_m**2)
    assert a.sample_spacing_m == pytest.approx(a.point_spacing_m, rel=1e-3)
    d = compare(Cloud(pts), (v, f), sample_spacing_m=0.01)
    assert d.reference_info["samples"] == math.ceil(area / 0.01**2)
    capped = compare(Cloud(pts), (v, f), params=CompareParams(max_samples=10_000))
    assert capped.reference_info["samples"] == 10_000
    assert capped.sample_spacing_m == pytest.approx(math.sqrt(area / 10_000))


def test_point_spacing_ignores_duplicates():
    g = _grid(30, 30, 0.02)
    assert point_spacing(np.concatenate([g, g])) == pytest.approx(0.02)


# -- validation --------------------------------------------------------------------------
def _mesh():
    return sphere_mesh(1.0, 1)


def _cloud(n=50):
    return Cloud(np.random.default_rng(0).normal(size=(n, 3)))


@pytest.mark.parametrize(
    ("cloud", "reference", "error", "words"),
    [
        (Cloud(np.empty((0, 3))), "mesh", EmptyInputError, "no points"),
        ("cloud", Cloud(np.empty((0, 3))), EmptyInputError, "no points"),
        ("cloud", (np.empty((0, 3)), np.empty((0, 3), int)), EmptyInputError, "no vertices"),
        ("cloud", (np.eye(3), np.empty((0, 3), int)), EmptyInputError, "no triangles"),
        (Cloud([[0.0, 0.0, 0.0]]), "mesh", EmptyInputError, "single point"),
        ("cloud", Cloud([[0.0, 0.0, 0.0]]), EmptyInputError, "single point"),
        (Cloud(np.eye(3)), "mesh", EmptyInputError, "only 3 points; a comparison needs at least 4"),
        ("cloud", Cloud(np.eye(3)), EmptyInputError, "only 3 points"),
        (Cloud([[0.0, 0, 0], [np.nan, 0, 0], [1, 1, 1]]), "mesh", InvalidGeometryError, "NaN"),
        ("cloud", Cloud([[0.0, 0, 0], [1, np.inf, 0]]), InvalidGeometryError, "NaN"),
        (Cloud(np.ones((5, 3))), "mesh", InvalidGeometryError, "coincide"),
        ("cloud", "a string", InvalidParameterError, "reference must be"),
        ("cloud", (np.ones((4, 2)), np.array([[0, 1, 2]])), InvalidGeometryError, "shape"),
    ],
)
def test_bad_inputs_give_clear_errors(cloud, reference, error, words):
    cloud = _cloud() if isinstance(cloud, str) else cloud
    reference = _mesh() if reference == "mesh" else reference
    with pytest.raises(error) as info:
        compare(cloud, reference)
    assert words in str(info.value)
    assert isinstance(info.value, TreesimError)


def test_coincident_points_need_explicit_spacings():
    cloud = Cloud(np.ones((5, 3)))
    res = compare(cloud, _mesh(), params=CompareParams(tolerance_m=0.1, sample_spacing_m=0.05))
    assert res.accuracy.n == 5 and math.isnan(res.point_spacing_m)
    with pytest.raises(InvalidGeometryError, match="tolerance_m"):
        compare(cloud, _mesh(), tolerance_m=0.1)


def test_well_conditioned_puts_the_longest_edge_opposite_the_first_corner():
    v = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 0.004, 0.0], [0.0, 1.0, 1.0]])
    f = np.array([[1, 2, 0], [2, 0, 1], [0, 1, 2]])
    g = well_conditioned(v, f)
    for row in g:
        a, b, c = v[row]
        assert np.linalg.norm(b - c) >= max(np.linalg.norm(c - a), np.linalg.norm(b - a))
    # same triangles, same orientation (cyclic rotations only)
    n0 = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n1 = np.cross(v[g[:, 1]] - v[g[:, 0]], v[g[:, 2]] - v[g[:, 0]])
    assert np.allclose(n0, n1)
    assert all(sorted(a) == sorted(b) for a, b in zip(f.tolist(), g.tolist(), strict=True))


def test_nan_mesh_vertex_is_rejected():
    v, f = _mesh()
    v = v.copy()
    v[f[0, 0]] = np.nan
    with pytest.raises(InvalidGeometryError, match="NaN"):
        compare(_cloud(), (v, f))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"tolerance_m": -1.0},
        {"tolerance_m": float("nan")},
        {"sample_spacing_m": 0.0},
        {"max_samples": 0},
        {"nthreads": -2},
    ],
)
def test_bad_parameters(kwargs):
    with pytest.raises(InvalidParameterError):
        compare(_cloud(), _mesh(), params=CompareParams(**kwargs))


# -- distance clouds ---------------------------------------------------------------------
def test_written_distance_clouds_carry_scalar_distance(tmp_path):
    v, f = sphere_mesh(1.0, 3, centre=UTM)
    rng = np.random.default_rng(2)
    u = rng.normal(size=(4000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pts = u * rng.uniform(0.95, 1.05, size=(4000, 1)) + np.asarray(UTM)
    cloud = Cloud(pts, {"station": np.zeros(4000, np.uint16)})
    res = compare(cloud, (v, f))
    written = write_comparison(res, tmp_path)
    ply = read_cloud(written["cloud_distances_ply"])
    assert ply.fields["scalar_distance"].dtype == np.float64
    assert np.array_equal(ply.fields["scalar_distance"], res.accuracy_m)
    assert np.array_equal(ply.points, pts)
    assert "station" in ply.fields
    laz = read_cloud(written["cloud_distances_laz"])
    assert np.array_equal(laz.fields["scalar_distance"], res.accuracy_m)
    assert np.abs(laz.points - pts).max() <= 0.5e-4 + 1e-9  # LAZ 0.1 mm scale
    ref = read_cloud(written["reference_distances_ply"])
    assert np.array_equal(ref.fields["scalar_distance"], res.completeness_m)
    assert len(ref) == res.completeness.n
    import json

    summary = json.loads(written["comparison"].read_text())
    for key in ("accuracy", "completeness"):
        assert all(k in summary[key] for k in REQUIRED_STATS)
    for key in ("hausdorff_m", "chamfer_m", "tolerance_m", "coverage"):
        assert isinstance(summary[key], float)
    assert 0.0 <= summary["coverage"] <= 1.0
    assert summary["by_station"]["0"]["points"] == 4000
    assert summary["software"]["open3d"]
