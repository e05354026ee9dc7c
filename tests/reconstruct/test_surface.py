"""Surface reconstruction: Poisson and ball pivoting in a child process, mesh cleaning."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from treesim.cloud import Cloud
from treesim.errors import InvalidGeometryError, InvalidParameterError, ReconstructionError
from treesim.reconstruct import surface
from treesim.reconstruct._pmlworker import FAULT_ENV
from treesim.reconstruct.preprocess import PreparedCloud, PrepareParams, prepare
from treesim.reconstruct.surface import (
    SurfaceResult,
    ball_pivoting,
    clean_mesh,
    edge_topology,
    poisson,
)

from .shapes import GEO, closed_cylinder, sphere

R_SPHERE = 0.3


@pytest.fixture(scope="module")
def geo_sphere() -> PreparedCloud:
    """A sphere of radius 0.3 m at UTM-like coordinates, prepared."""
    params = PrepareParams(voxel_size_m=None, sor_std_ratio=None)
    return prepare(Cloud(sphere(R_SPHERE, 5000) + GEO), params)


@pytest.fixture(scope="module")
def small_sphere() -> PreparedCloud:
    params = PrepareParams(voxel_size_m=None, sor_std_ratio=None)
    return prepare(sphere(R_SPHERE, 1500, seed=3), params)


# --------------------------------------------------------------------------- Poisson


def test_poisson_sphere_is_watertight_with_the_right_volume_and_surface(geo_sphere):
    res = poisson(geo_sphere, depth=6, trim_density_quantile=None)
    assert isinstance(res, SurfaceResult) and res.method == "poisson"
    assert res.watertight
    assert res.n_triangles == len(res.faces) > 1000
    assert res.vertices.dtype == np.float64 and res.faces.dtype == np.int64
    true_volume = 4.0 / 3.0 * np.pi * R_SPHERE**3
    assert res.volume_m3 == pytest.approx(true_volume, rel=0.03)
    # vertices come back in the input's (georeferenced) coordinates, on the sphere
    radius = np.linalg.norm(res.vertices - GEO, axis=1)
    assert np.abs(radius - R_SPHERE).max() < 0.01
    assert res.stats["boundary_edges"] == 0 and res.stats["components"] == 1
    assert set(res.timings) >= {"worker_s", "child_s", "clean_s", "total_s"}
    assert res.params["depth"] == 6 and res.params["n_points"] == len(geo_sphere)


def test_poisson_closed_cylinder_volume():
    pts = closed_cylinder(0.15, 0.6, 8000)
    prep = prepare(pts, PrepareParams(voxel_size_m=None))
    res = poisson(prep, depth=6, trim_density_quantile=0.0)
    assert res.watertight
    assert res.volume_m3 == pytest.approx(np.pi * 0.15**2 * 0.6, rel=0.03)
    v = res.vertices
    side = (v[:, 2] > 0.06) & (v[:, 2] < 0.54)  # Poisson rounds edges over ~2 cells
    dev = np.abs(np.hypot(v[side, 0], v[side, 1]) - 0.15)
    assert np.percentile(dev, 99) < 0.003 and dev.max() < 0.01  # a depth-6 cell is 1 cm


def test_poisson_trimming_removes_low_density_vertices(small_sphere):
    res = poisson(small_sphere, depth=5, trim_density_quantile=0.2)
    assert res.params["density_threshold"] is not None
    assert res.stats["trimmed_vertices"] > 0
    assert res.n_triangles < res.stats["untrimmed"]["n_triangles"]
    assert not res.watertight and res.volume_m3 is None
    assert res.stats["untrimmed"]["watertight"] is True
    assert res.stats["untrimmed"]["volume_m3"] > 0


def test_poisson_distance_trim_keeps_only_surface_near_the_points():
    # half a sphere: Poisson closes the other half, the distance trim removes it again
    pts = sphere(R_SPHERE, 3000, seed=4)
    half = pts[pts[:, 2] > 0.0]
    prep = prepare(half, PrepareParams(voxel_size_m=None, sor_std_ratio=None))
    res = poisson(prep, depth=5, trim_density_quantile=None, trim_distance_m=0.03)
    assert res.stats["distance_trimmed_vertices"] > 0
    assert res.local_vertices[:, 2].min() + prep.frame.origin[2] > -0.03
    assert res.params["cell_m"] == pytest.approx(1.1 * np.ptp(prep.points, axis=0).max() / 32)
    with pytest.raises(InvalidParameterError, match="trim_distance_m"):
        poisson(prep, trim_distance_m=-1.0)


def test_poisson_with_inward_normals_is_flipped_to_a_positive_volume(small_sphere):
    inward = dataclasses.replace(small_sphere, normals=-small_sphere.normals)
    res = poisson(inward, depth=5, trim_density_quantile=None)
    assert res.watertight and res.volume_m3 > 0
    assert res.stats.get("flipped") is True


def test_poisson_rejects_zero_normals(small_sphere):
    bad = small_sphere.normals.copy()
    bad[5] = 0.0
    with pytest.raises(InvalidGeometryError, match=r"1 of 1500 normals are zero .*row 5"):
        poisson(dataclasses.replace(small_sphere, normals=bad))


def test_poisson_with_no_faces_is_an_error(small_sphere, monkeypatch):
    def empty(*args, **kwargs):
        return {"vertices": np.zeros((0, 3)), "faces": np.zeros((0, 3), np.int64)}, 0.0

    monkeypatch.setattr(surface, "run_in_child", empty)
    with pytest.raises(ReconstructionError, match="returned no surface.*normals"):
        poisson(small_sphere, depth=5)


def test_poisson_parameters_are_checked(small_sphere):
    with pytest.raises(InvalidParameterError, match="depth"):
        poisson(small_sphere, depth=3)
    with pytest.raises(InvalidParameterError, match="trim_density_quantile"):
        poisson(small_sphere, trim_density_quantile=1.0)
    with pytest.raises(InvalidParameterError, match="timeout_s"):
        poisson(small_sphere, timeout_s=0)


# --------------------------------------------------------------------------- ball pivoting


def test_ball_pivoting_on_a_sphere(geo_sphere):
    res = ball_pivoting(geo_sphere)
    assert res.method == "bpa" and res.n_triangles > 2000
    assert isinstance(res.watertight, bool)
    assert (res.volume_m3 is None) == (not res.watertight)
    # BPA's vertices are input points: exactly on the sphere
    radius = np.linalg.norm(res.vertices - GEO, axis=1)
    assert np.abs(radius - R_SPHERE).max() < 1e-9
    radii = res.params["radii_m"]
    assert radii == pytest.approx(
        [1.0 * geo_sphere.spacing_m, 2.0 * geo_sphere.spacing_m, 3.0 * geo_sphere.spacing_m]
    )
    assert res.params["thinned"] is False


def test_ball_pivoting_thins_large_clouds_deterministically(geo_sphere):
    res = ball_pivoting(geo_sphere, max_points=1000)
    assert res.params["thinned"] is True and res.params["n_points"] <= 1000
    assert res.params["spacing_m"] > geo_sphere.spacing_m
    assert res.n_triangles > 0
    again = surface._thin_to(geo_sphere.points, geo_sphere.spacing_m, 1000)
    np.testing.assert_array_equal(
        again, surface._thin_to(geo_sphere.points, geo_sphere.spacing_m, 1000)
    )


def test_ball_pivoting_parameters_are_checked(small_sphere):
    with pytest.raises(InvalidParameterError, match="radii_m"):
        ball_pivoting(small_sphere, radii_m=[0.01, -0.02])
    with pytest.raises(InvalidParameterError, match="max_points"):
        ball_pivoting(small_sphere, max_points=10)


# --------------------------------------------------------------------------- the child process


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("abort", r"pymeshlab crashed \(signal 6, SIGABRT\) during screened Poisson"),
        ("segfault", r"pymeshlab crashed \(signal 11, SIGSEGV\)"),
        ("raise", r"pymeshlab failed during screened Poisson.*simulated failure"),
    ],
)
def test_a_worker_crash_is_a_reconstruction_error(small_sphere, monkeypatch, fault, message):
    monkeypatch.setenv(FAULT_ENV, fault)
    pid = os.getpid()
    with pytest.raises(ReconstructionError, match=message):
        poisson(small_sphere, depth=5)
    assert os.getpid() == pid  # the caller lives on


def test_a_bpa_crash_names_the_method(small_sphere, monkeypatch):
    monkeypatch.setenv(FAULT_ENV, "abort")
    with pytest.raises(ReconstructionError, match=r"crashed .* during ball pivoting on 1500"):
        ball_pivoting(small_sphere)


def test_a_hanging_worker_times_out(small_sphere, monkeypatch):
    monkeypatch.setenv(FAULT_ENV, "hang")
    with pytest.raises(ReconstructionError, match=r"did not finish within 1.5 s and was stopped"):
        poisson(small_sphere, depth=5, timeout_s=1.5)


# --------------------------------------------------------------------------- mesh tools


def _tetrahedron() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


def test_edge_topology():
    v, f = _tetrahedron()
    assert edge_topology(f)["watertight"]
    open_ = edge_topology(f[:3])
    assert open_["boundary_edges"] == 3 and not open_["watertight"]
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    assert edge_topology(flipped)["misoriented_edges"] == 3
    assert not edge_topology(np.zeros((0, 3), np.int64))["watertight"]


def test_clean_mesh_removes_duplicates_degenerates_and_small_pieces():
    v, f = _tetrahedron()
    big_v = np.vstack([v * 10.0 + [100, 0, 0] for _ in range(1)])
    # a big closed piece: a subdivided-free octahedron made of 8 faces around the origin
    octa_v = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    octa_f = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    verts = np.vstack([octa_v, octa_v[:1], big_v])  # vertex 6 duplicates vertex 0
    faces = np.vstack(
        [
            octa_f,
            [[6, 2, 4]],  # duplicate of face 0 through the duplicate vertex
            [[0, 0, 2]],  # degenerate
            f + 7,  # a separate tetrahedron (4 faces): smaller than 8 faces
        ]
    )
    cv, cf, stats = clean_mesh(verts, faces, min_component_fraction=0.6, min_component_faces=1)
    assert stats["merged_vertices"] == 1
    assert stats["degenerate_faces"] == 1
    assert stats["duplicate_faces"] == 1
    assert stats["components_removed"] == 1 and stats["small_component_faces"] == 4
    assert stats["components_kept"] == 1
    assert len(cf) == 8 and len(cv) == 6
    assert edge_topology(cf)["watertight"]


def test_clean_mesh_splits_a_zero_area_sliver_and_stays_closed():
    from treesim.models.mesh import mesh_volume

    octa_v = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    octa_f = [
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ]
    # put vertex 6 in the middle of edge 0-2 and a zero-area face (0, 2, 6) in the mesh
    v = np.vstack([octa_v, (octa_v[0] + octa_v[2]) / 2])
    f = np.array([[0, 6, 4], [6, 2, 4], *octa_f[1:], [0, 2, 6]])
    assert edge_topology(f)["watertight"]
    cv, cf, stats = clean_mesh(v, f)
    assert stats["slivers_split"] == 1 and stats["degenerate_faces"] == 0
    assert len(cf) == len(f) + 0  # the sliver and its neighbour became two faces
    assert edge_topology(cf)["watertight"]
    assert mesh_volume(cv, cf) == pytest.approx(mesh_volume(octa_v, np.array(octa_f)))
