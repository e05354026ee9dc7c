"""Meshes of cylinder tables: closed, outward, watertight prisms with exact volumes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from treesim.errors import InvalidParameterError
from treesim.models import (
    CylinderTable,
    cylinder_mesh,
    cylinders_to_mesh,
    faces_per_cylinder,
    mesh_volume,
    read_cylinders,
    vertices_per_cylinder,
)


def _prism_volume(radius: float, height: float, facets: int) -> float:
    return facets / 2 * radius**2 * math.sin(2 * math.pi / facets) * height


def _assert_closed_and_outward(faces: np.ndarray) -> None:
    """Every edge is shared by exactly two faces, traversed once in each direction."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    base = np.int64(faces.max()) + 1
    keys = directed[:, 0] * base + directed[:, 1]
    keys.sort()
    assert (np.diff(keys) > 0).all(), "a directed edge is used twice: inconsistent winding"
    reverse = np.sort(directed[:, 1] * base + directed[:, 0])
    assert np.array_equal(keys, reverse), "an edge has no opposite: the mesh is open"


def _min_triangle_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.linalg.norm(np.cross(b - a, c - a), axis=1).min() / 2)


def _table(start, axis, length, radius, end_radius=None) -> CylinderTable:
    start = np.atleast_2d(np.asarray(start, dtype=float))
    n = len(start)
    return CylinderTable(
        start=start,
        axis=np.atleast_2d(axis),
        length_m=np.broadcast_to(length, n),
        radius_m=np.broadcast_to(radius, n),
        end_radius_m=None if end_radius is None else np.broadcast_to(end_radius, n),
        parent=np.full(n, -1),
        branch=np.arange(n),
        branch_order=np.zeros(n),
        position_in_branch=np.ones(n),
    )


@pytest.mark.parametrize("facets", [3, 4, 7, 32, 1000])
def test_single_cylinder_volume_is_the_analytic_prism(facets: int) -> None:
    vertices, faces = cylinder_mesh(0.37, 2.5, facets, base=(1.0, -2.0, 3.0))
    assert vertices.shape == (2 * facets + 2, 3) and faces.shape == (4 * facets, 3)
    assert vertices.dtype == np.float64 and faces.dtype == np.int64
    expected = _prism_volume(0.37, 2.5, facets)
    assert mesh_volume(vertices, faces) == pytest.approx(expected, rel=1e-12)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    _assert_closed_and_outward(faces)
    assert _min_triangle_area(vertices, faces) > 0


def test_volume_converges_to_the_cylinder() -> None:
    exact = math.pi * 0.2**2 * 1.5
    errors = [
        abs(mesh_volume(*cylinder_mesh(0.2, 1.5, f)) - exact) / exact for f in (8, 64, 512, 4096)
    ]
    assert all(b < a for a, b in zip(errors, errors[1:], strict=False))
    assert errors[-1] < 1e-6


def test_cylinder_mesh_stands_on_its_base() -> None:
    vertices, _ = cylinder_mesh(0.5, 2.0, 16, base=(10.0, 20.0, 30.0))
    assert vertices[:, 2].min() == pytest.approx(30.0)
    assert vertices[:, 2].max() == pytest.approx(32.0)
    radial = np.linalg.norm(vertices[:, :2] - [10.0, 20.0], axis=1)
    assert radial.max() == pytest.approx(0.5)


@pytest.mark.parametrize(
    "axis",
    [
        [0, 0, 1],
        [0, 0, -1],
        [1, 0, 0],
        [0, -1, 0],
        [1, 1, 1],
        [-1e-9, 1e-9, 1],
        [0.6, 0.0, -0.8],
        [0.9999999, 0.0004472, 0.0],
    ],
)
def test_any_axis_gives_an_outward_prism(axis: list[float]) -> None:
    unit = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    table = _table([0.3, -0.2, 5.0], unit, 0.8, 0.05, end_radius=0.03)
    vertices, faces = cylinders_to_mesh(table, facets=12)
    k = 12 * math.sin(2 * math.pi / 12) / (2 * math.pi)
    frustum = math.pi * 0.8 * (0.05**2 + 0.05 * 0.03 + 0.03**2) / 3
    assert mesh_volume(vertices, faces) == pytest.approx(k * frustum, rel=1e-12)
    _assert_closed_and_outward(faces)
    # Ring vertices lie on the circles around the axis, at the given radii.
    rel = vertices[:24] - table.start[0]
    along = rel @ unit
    radial = np.linalg.norm(rel - along[:, None] * unit, axis=1)
    np.testing.assert_allclose(along, [0.0] * 12 + [0.8] * 12, atol=1e-12, rtol=0)
    np.testing.assert_allclose(radial, [0.05] * 12 + [0.03] * 12, rtol=1e-12)


def test_many_cylinders_are_separate_closed_prisms_grouped_by_row() -> None:
    rng = np.random.default_rng(3)
    n, facets = 40, 9
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    table = _table(
        rng.uniform(-1, 1, (n, 3)), axis, rng.uniform(0.1, 1, n), rng.uniform(0.01, 0.2, n)
    )
    vertices, faces = cylinders_to_mesh(table, facets=facets)
    vpc, fpc = vertices_per_cylinder(facets), faces_per_cylinder(facets)
    assert vertices.shape == (n * vpc, 3) and faces.shape == (n * fpc, 3)
    _assert_closed_and_outward(faces)
    # Face i belongs to cylinder i // fpc and uses only that cylinder's vertices.
    owner = np.arange(len(faces)) // fpc
    assert (faces // vpc == owner[:, None]).all()
    per_cylinder = [mesh_volume(vertices, faces[owner == i]) for i in range(n)]
    np.testing.assert_allclose(per_cylinder, table.prism_volume_m3(facets), rtol=1e-10)
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_open_tubes_without_caps() -> None:
    table = _table([0, 0, 0], [0, 0, 1], 1.0, 0.1)
    vertices, faces = cylinders_to_mesh(table, facets=10, caps=False)
    assert vertices.shape == (20, 3) and faces.shape == (20, 3)
    assert faces_per_cylinder(10, caps=False) == 20
    assert not trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_bad_parameters() -> None:
    table = _table([0, 0, 0], [0, 0, 1], 1.0, 0.1)
    for facets in (2, 0, 3.5, True):
        with pytest.raises(InvalidParameterError, match="facets"):
            cylinders_to_mesh(table, facets=facets)
    with pytest.raises(InvalidParameterError, match="radius_m"):
        cylinder_mesh(-1.0, 1.0)
    with pytest.raises(InvalidParameterError, match="height_m"):
        cylinder_mesh(1.0, 0.0)


def test_georeferenced_coordinates_keep_float64_precision() -> None:
    base = (512_345.678, 5_432_109.876, 254.0)
    vertices, faces = cylinder_mesh(0.01, 0.05, 16, base=base)
    assert vertices.dtype == np.float64
    assert vertices[-2].tolist() == list(base)  # the base centre, bit for bit
    assert mesh_volume(vertices, faces) == pytest.approx(_prism_volume(0.01, 0.05, 16), rel=1e-9)
    assert _min_triangle_area(vertices, faces) > 0


@pytest.mark.shared_data
def test_coffee_mesh_volume_equals_the_table(treeqsm_csv: Path) -> None:
    table = read_cylinders(treeqsm_csv)
    vertices, faces = cylinders_to_mesh(table, facets=32)
    assert len(faces) == 1136 * faces_per_cylinder(32)
    assert vertices.dtype == np.float64
    assert vertices[:, 2].min() > 253.0  # input coordinates, not shifted
    volume = mesh_volume(vertices, faces)
    assert volume > 0
    assert volume == pytest.approx(float(table.prism_volume_m3(32).sum()), rel=1e-10)
    # The 32-gon prisms hold sin(2 pi / 32) * 32 / (2 pi) = 99.4 % of the cylinders.
    assert volume == pytest.approx(table.total_volume_m3, rel=0.01)
    _assert_closed_and_outward(faces)
    assert _min_triangle_area(vertices, faces) > 0
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_a_large_table_meshes_with_the_expected_counts() -> None:
    # speed is measured in benchmarks/, not asserted here
    rng = np.random.default_rng(11)
    n = 20_000
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    table = _table(
        rng.uniform(-10, 10, (n, 3)), axis, rng.uniform(0.01, 0.3, n), rng.uniform(0.002, 0.1, n)
    )
    vertices, faces = cylinders_to_mesh(table, facets=32)
    assert vertices.shape == (n * 66, 3) and faces.shape == (n * 128, 3)
    assert _min_triangle_area(vertices, faces) > 0
