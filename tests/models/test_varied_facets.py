"""Meshes with a facet count per cylinder: separate prisms per row, mitred tubes per tube.

An int ``facets`` (or an array of equal values) must give today's mesh bit for bit; per-row
counts must keep every guarantee of the uniform meshes: closed, outward, watertight, no
degenerate triangle, volume equal to the inscribed prisms' at the counts actually meshed,
and (procedural trees) every child's base disc inside its parent's tube.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from tests.models.geometry import (
    assert_closed_and_outward,
    assert_no_degenerate,
    winding_numbers,
)
from tests.models.test_procedural import _base_circles, _child_rows
from treesim.errors import InvalidParameterError
from treesim.models import (
    CylinderTable,
    cylinders_to_mesh,
    generate_tree,
    mesh_triangle_count,
    mesh_volume,
    meshed_facets,
    read_cylinders,
    tubes_to_mesh,
)
from treesim.models.procedural import MIN_JUNCTION_FACETS

BENT = [[0, 0, 0], [0, 0, 1.0], [0.5, 0, 1.8], [0.6, 0.4, 2.5], [0.2, 0.7, 3.0]]


def _random_table(n: int, seed: int) -> CylinderTable:
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return CylinderTable(
        start=rng.uniform(-1, 1, (n, 3)),
        axis=axis,
        length_m=rng.uniform(0.1, 1, n),
        radius_m=rng.uniform(0.01, 0.2, n),
        end_radius_m=rng.uniform(0.005, 0.2, n),
        parent=np.full(n, -1),
        branch=np.arange(n),
        branch_order=np.zeros(n),
        position_in_branch=np.ones(n),
    )


def _stem_and_branches() -> CylinderTable:
    """A bent stem of four frusta (branch 1), a step in radius at its second joint, and
    two branches (2 and 3, two cylinders each) starting inside it."""
    starts = [*BENT[:4], [0.02, 0, 0.5], [0.4, 0.1, 0.7], [0.5, 0.05, 2.0], [0.5, 0.6, 2.3]]
    ends = [*BENT[1:5], [0.4, 0.1, 0.7], [0.9, 0.1, 0.8], [0.5, 0.6, 2.3], [0.3, 1.0, 2.5]]
    return CylinderTable.from_endpoints(
        starts,
        ends,
        [0.12, 0.11, 0.09, 0.08, 0.03, 0.025, 0.03, 0.02],
        end_radius_m=[0.11, 0.10, 0.08, 0.07, 0.025, 0.02, 0.02, 0.01],
        parent=[-1, 0, 1, 2, 0, 4, 2, 6],
        branch=[1, 1, 1, 1, 2, 2, 3, 3],
        branch_order=[0, 0, 0, 0, 1, 1, 1, 1],
    )


def _same_arrays(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> bool:
    return all(
        x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
        for x, y in zip(a, b, strict=True)
    )


def _tube_arrays(t) -> tuple[np.ndarray, ...]:
    return (t.vertices, t.faces, t.face_cylinder, t.face_tube, t.tube_of_row, t.joined)


@pytest.mark.parametrize("facets", [3, 8, 32])
def test_an_array_of_equal_counts_is_the_int_mesh_bit_for_bit(facets: int) -> None:
    for table in (_random_table(30, 1), _stem_and_branches()):
        n = table.n_cylinders
        same = np.full(n, facets)
        for caps in (True, False):
            assert _same_arrays(
                cylinders_to_mesh(table, facets=facets, caps=caps),
                cylinders_to_mesh(table, facets=same, caps=caps),
            )
        assert _same_arrays(
            _tube_arrays(tubes_to_mesh(table, facets=facets)),
            _tube_arrays(tubes_to_mesh(table, facets=list(same))),
        )
        assert (tubes_to_mesh(table, facets=facets).tube_facets == facets).all()


def test_separate_prisms_honour_each_rows_count() -> None:
    table = _random_table(40, 3)
    facets = np.random.default_rng(4).integers(3, 40, table.n_cylinders)
    vertices, faces = cylinders_to_mesh(table, facets=facets)
    assert vertices.shape == (int((2 * facets + 2).sum()), 3)
    assert len(faces) == 4 * int(facets.sum()) == mesh_triangle_count(table, facets=facets)
    assert_closed_and_outward(faces)
    assert_no_degenerate(vertices, faces)
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight
    # Row i's faces come after those of rows 0..i-1 and use only its own vertices.
    f_off = np.concatenate([[0], np.cumsum(4 * facets)])
    v_off = np.concatenate([[0], np.cumsum(2 * facets + 2)])
    prism = table.prism_volume_m3(facets)
    for i in range(table.n_cylinders):
        own = faces[f_off[i] : f_off[i + 1]]
        assert own.min() >= v_off[i] and own.max() < v_off[i + 1]
        assert mesh_volume(vertices, own) == pytest.approx(prism[i], rel=1e-10)
        # Same vertices as that row meshed alone at its count.
        alone, _ = cylinders_to_mesh(table, facets=int(facets[i]))
        n_v = 2 * int(facets[i]) + 2
        np.testing.assert_array_equal(
            vertices[v_off[i] : v_off[i + 1]], alone[i * n_v : (i + 1) * n_v]
        )
    open_v, open_f = cylinders_to_mesh(table, facets=facets, caps=False)
    assert len(open_v) == 2 * facets.sum() and len(open_f) == 2 * facets.sum()
    assert mesh_triangle_count(table, facets=facets, caps=False) == len(open_f)


def test_tubes_take_the_largest_count_of_their_rows() -> None:
    table = _stem_and_branches()
    facets = np.array([9, 31, 12, 5, 3, 7, 16, 16])
    tubes = tubes_to_mesh(table, facets=facets)
    assert tubes.n_tubes == 3 and tubes.tube_of_row.tolist() == [0, 0, 0, 0, 1, 1, 2, 2]
    assert tubes.tube_facets.tolist() == [31, 7, 16]
    row_f = tubes.tube_facets[tubes.tube_of_row]
    assert (row_f >= facets).all()
    assert meshed_facets(table, facets=facets, joints="miter").tolist() == row_f.tolist()
    assert meshed_facets(table, facets=facets).tolist() == facets.tolist()
    assert tubes.n_triangles == mesh_triangle_count(table, facets=facets, joints="miter")
    assert_closed_and_outward(tubes.faces)
    assert_no_degenerate(tubes.vertices, tubes.faces)
    mesh = trimesh.Trimesh(tubes.vertices, tubes.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    prism = table.prism_volume_m3(row_f)
    for t in range(tubes.n_tubes):
        piece = tubes.faces[tubes.face_tube == t]
        assert_closed_and_outward(piece)
        rows = np.flatnonzero(tubes.tube_of_row == t)
        assert mesh_volume(tubes.vertices, piece) == pytest.approx(
            float(prism[rows].sum()), rel=1e-12
        )
        # Each tube is the tube meshed at its own count, vertex for vertex.
        alone = tubes_to_mesh(table, facets=int(tubes.tube_facets[t]))
        ring = np.unique(piece)
        alone_ring = np.unique(alone.faces[alone.face_tube == t])
        np.testing.assert_array_equal(tubes.vertices[ring], alone.vertices[alone_ring])
    # cylinders_to_mesh passes per-row facets on to the tubes.
    v, f = cylinders_to_mesh(table, facets=facets, joints="miter")
    assert np.array_equal(v, tubes.vertices) and np.array_equal(f, tubes.faces)


def test_procedural_tree_with_varied_counts_stays_closed_with_closed_junctions() -> None:
    tree = generate_tree("sapling", seed=0)
    table = tree.cylinders
    rng = np.random.default_rng(5)
    facets = rng.choice([MIN_JUNCTION_FACETS, 9, 12, 20, 31], table.n_cylinders)
    wood = tubes_to_mesh(table, facets=facets)
    assert len(np.unique(wood.tube_facets)) == 5
    assert_closed_and_outward(wood.faces)
    assert_no_degenerate(wood.vertices, wood.faces)
    mesh = trimesh.Trimesh(wood.vertices, wood.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    row_f = wood.tube_facets[wood.tube_of_row]
    # Procedural stems meet end to end: each tube holds its prisms' volume, as at one count.
    det = wood.vertices[wood.faces] - wood.vertices.mean(axis=0)
    det = np.einsum("ij,ij->i", det[:, 0], np.cross(det[:, 1], det[:, 2])) / 6.0
    per_tube = np.bincount(wood.face_tube, weights=det)
    expected = np.bincount(wood.tube_of_row, weights=table.prism_volume_m3(row_f))
    # (The mitred joints of the tapering frusta add ~3e-10 of it, as at one count.)
    np.testing.assert_allclose(per_tube, expected, rtol=1e-8)
    # Junctions: every child's base circle is inside its parent's tube, whose count may
    # differ from the child's (and is at least MIN_JUNCTION_FACETS).
    rows, parents = _child_rows(table)
    differ = wood.tube_facets[wood.tube_of_row[rows]] != wood.tube_facets[wood.tube_of_row[parents]]
    assert differ.sum() > 10
    circles = _base_circles(table, rows, m=24)
    for k, par in enumerate(parents):
        faces = wood.faces[wood.face_tube == wood.tube_of_row[par]]
        w = winding_numbers(circles[k], wood.vertices, faces)
        assert (w > 0.999).all(), f"row {rows[k] + 1}: base circle pokes out of its parent"


@pytest.mark.shared_data
def test_coffee_tree_with_varied_counts(treeqsm_csv: Path) -> None:
    table = read_cylinders(treeqsm_csv)
    facets = np.where(table.radius_m > 0.01, 24, 8)
    for joints in ("separate", "miter"):
        v, f = cylinders_to_mesh(table, facets=facets, joints=joints)
        assert len(f) == mesh_triangle_count(table, facets=facets, joints=joints)
        assert len(f) < mesh_triangle_count(table, facets=24, joints=joints)
        assert_closed_and_outward(f)
        assert_no_degenerate(v, f)
        volume = mesh_volume(v, f)
        row_f = meshed_facets(table, facets=facets, joints=joints)
        rel = 1e-10 if joints == "separate" else 0.005  # the CSV's gaps move tube joints
        assert volume == pytest.approx(float(table.prism_volume_m3(row_f).sum()), rel=rel)


def test_bad_per_row_facets() -> None:
    table = _stem_and_branches()
    n = table.n_cylinders
    for bad in (
        np.full(n - 1, 8),
        np.full((n, 1), 8),
        np.full(n, 8.0),
        np.full(n, True),
        [8] * (n - 1) + [2],
        [],
    ):
        for fn in (cylinders_to_mesh, tubes_to_mesh, mesh_triangle_count, meshed_facets):
            with pytest.raises(InvalidParameterError, match="facets"):
                fn(table, facets=bad)
    with pytest.raises(InvalidParameterError, match="facets"):
        table.prism_volume_m3(np.full(n - 1, 8))
    # A 0-d integer array is a single count.
    assert _same_arrays(
        cylinders_to_mesh(table, facets=np.array(12)), cylinders_to_mesh(table, facets=12)
    )
