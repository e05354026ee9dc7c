"""Mitred tubes: one closed, crack-free tube per chain of cylinders, volume preserved."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tests.models.geometry import assert_closed_and_outward, assert_no_degenerate
from treesim.errors import InvalidParameterError
from treesim.models import (
    CylinderTable,
    cylinders_to_mesh,
    mesh_volume,
    read_cylinders,
    tubes_to_mesh,
)


def _chain(nodes, radii, end_radii=None, branch=None) -> CylinderTable:
    """Cylinders from consecutive nodes, each the parent of the next."""
    nodes = np.asarray(nodes, dtype=float)
    m = len(nodes) - 1
    return CylinderTable.from_endpoints(
        nodes[:-1],
        nodes[1:],
        np.asarray(radii, dtype=float),
        parent=np.arange(m) - 1,
        branch=np.ones(m) if branch is None else branch,
        branch_order=np.zeros(m),
        end_radius_m=None if end_radii is None else np.asarray(end_radii, dtype=float),
    )


BENT = [[0, 0, 0], [0, 0, 1.0], [0.5, 0, 1.8], [0.6, 0.4, 2.5], [0.2, 0.7, 3.0]]


def _prism_factor(facets: int) -> float:
    return facets * math.sin(2 * math.pi / facets) / (2 * math.pi)


@pytest.mark.parametrize("facets", [3, 5, 8, 32, 97])
def test_bent_chain_is_one_closed_tube_with_the_prisms_volume(facets: int) -> None:
    table = _chain(BENT, [0.1] * 4)
    tubes = tubes_to_mesh(table, facets=facets)
    assert tubes.n_tubes == 1 and tubes.joined.tolist() == [False, True, True, True]
    # Four sides of 2 f triangles and two caps of f: no internal caps at the joints.
    assert tubes.n_triangles == (2 * 4 + 2) * facets
    assert len(tubes.vertices) == 5 * facets + 2
    assert_closed_and_outward(tubes.faces)
    assert_no_degenerate(tubes.vertices, tubes.faces)
    mesh = trimesh.Trimesh(tubes.vertices, tubes.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    # An oblique cut through an axis point keeps area x axial length: exact.
    expected = _prism_factor(facets) * math.pi * 0.1**2 * table.total_length_m
    assert mesh_volume(tubes.vertices, tubes.faces) == pytest.approx(expected, rel=1e-12)
    assert mesh_volume(tubes.vertices, tubes.faces) == pytest.approx(
        float(table.prism_volume_m3(facets).sum()), rel=1e-12
    )


def test_joint_rings_lie_on_both_cylinders_and_in_the_bisecting_plane() -> None:
    table = _chain(BENT[:3], [0.1, 0.1])
    f = 16
    tubes = tubes_to_mesh(table, facets=f)
    joint = np.asarray(BENT[1], dtype=float)
    a, b = table.unit_axis
    bisector = (a + b) / np.linalg.norm(a + b)
    on_plane = np.abs((tubes.vertices - joint) @ bisector) < 1e-12
    ring = tubes.vertices[on_plane]
    assert len(ring) == f  # one shared ring, not two
    for axis in (a, b):
        rel = ring - joint
        radial = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)
        np.testing.assert_allclose(radial, 0.1, rtol=1e-12)


def test_straight_chain_does_not_twist() -> None:
    nodes = [[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.5]]
    tubes = tubes_to_mesh(_chain(nodes, [0.2, 0.2, 0.2]), facets=12)
    rings = [tubes.vertices[np.abs(tubes.vertices[:, 2] - z) < 1e-12] for z in (0, 1, 2, 3.5)]
    for ring in rings[1:]:
        # Same angles at every height (the caps' centres excluded).
        ring = ring[np.linalg.norm(ring[:, :2], axis=1) > 0.1]
        first = rings[0][np.linalg.norm(rings[0][:, :2], axis=1) > 0.1]
        np.testing.assert_allclose(ring[:, :2], first[:, :2], atol=1e-14, rtol=0)


@pytest.mark.parametrize("facets", [3, 5, 8, 32])
def test_frusta_chain_keeps_the_frustum_volume(facets: int) -> None:
    radii = [0.2, 0.15, 0.1, 0.06]
    end = [0.15, 0.1, 0.06, 0.01]  # a steep taper round bends of 32 to 42 degrees
    table = _chain(BENT, radii, end)
    tubes = tubes_to_mesh(table, facets=facets)
    assert tubes.n_tubes == 1 and tubes.n_triangles == 10 * facets
    assert_closed_and_outward(tubes.faces)
    assert_no_degenerate(tubes.vertices, tubes.faces)
    volume = mesh_volume(tubes.vertices, tubes.faces)
    assert volume == pytest.approx(float(table.prism_volume_m3(facets).sum()), rel=1e-12)


def test_radius_step_gets_an_annulus_and_keeps_the_volume() -> None:
    table = _chain(BENT[:3], [0.1, 0.07])
    f = 16
    tubes = tubes_to_mesh(table, facets=f)
    assert tubes.n_tubes == 1
    assert tubes.n_triangles == (2 * 2 + 2 + 2) * f  # sides, caps and the annulus
    assert (np.bincount(tubes.face_cylinder) == [3 * f, 5 * f]).all()
    assert_closed_and_outward(tubes.faces)
    assert_no_degenerate(tubes.vertices, tubes.faces)
    volume = mesh_volume(tubes.vertices, tubes.faces)
    assert volume == pytest.approx(float(table.prism_volume_m3(f).sum()), rel=1e-12)


def test_sharp_bends_and_gaps_start_new_tubes() -> None:
    # 120 degrees: beyond MAX_MITER_BEND_DEG.
    sharp = _chain([[0, 0, 0], [0, 0, 1.0], [0.87, 0, 0.5]], [0.05, 0.05])
    tubes = tubes_to_mesh(sharp, facets=8)
    assert tubes.n_tubes == 2 and not tubes.joined.any()
    assert_closed_and_outward(tubes.faces)
    assert tubes_to_mesh(sharp, facets=8, max_bend_deg=150.0).n_tubes == 1
    # A gap of one radius is not closed by default (half a radius is).
    gap = CylinderTable.from_endpoints(
        [[0, 0, 0], [0, 0, 1.1]],
        [[0, 0, 1.0], [0, 0, 2.0]],
        [0.1, 0.1],
        parent=[-1, 0],
        branch=[1, 1],
        branch_order=[0, 0],
    )
    assert tubes_to_mesh(gap, facets=8).n_tubes == 2
    closed = tubes_to_mesh(gap, facets=8, max_gap_ratio=1.5)
    assert closed.n_tubes == 1
    assert_closed_and_outward(closed.faces)
    # A short cylinder between two bends cannot hold both mitres: the chain breaks.
    short = _chain([[0, 0, 0], [0, 0, 1.0], [0.05, 0, 1.05], [0.05, 0, 2.0]], [0.2, 0.2, 0.2])
    broken = tubes_to_mesh(short, facets=8)
    assert broken.n_tubes >= 2
    assert_closed_and_outward(broken.faces)


def test_branches_are_separate_tubes() -> None:
    # A stem of two cylinders and a branch (another branch id) off its first cylinder.
    table = CylinderTable.from_endpoints(
        [[0, 0, 0], [0, 0, 1.0], [0.05, 0, 0.5]],
        [[0, 0, 1.0], [0, 0.1, 2.0], [0.8, 0, 0.9]],
        [0.1, 0.09, 0.03],
        parent=[-1, 0, 0],
        branch=[1, 1, 2],
        branch_order=[0, 0, 1],
    )
    tubes = tubes_to_mesh(table, facets=10)
    assert tubes.n_tubes == 2
    assert tubes.tube_of_row.tolist() == [0, 0, 1]
    assert tubes.joined.tolist() == [False, True, False]
    for t in range(2):
        piece = tubes.faces[tubes.face_tube == t]
        assert_closed_and_outward(piece)
        rows = np.flatnonzero(tubes.tube_of_row == t)
        assert mesh_volume(tubes.vertices, piece) == pytest.approx(
            float(table.prism_volume_m3(10)[rows].sum()), rel=1e-12
        )


def test_cylinders_to_mesh_options() -> None:
    table = _chain(BENT, [0.1] * 4)
    v, f = cylinders_to_mesh(table, facets=8, joints="miter")
    tubes = tubes_to_mesh(table, facets=8)
    assert np.array_equal(v, tubes.vertices) and np.array_equal(f, tubes.faces)
    v_sep, f_sep = cylinders_to_mesh(table, facets=8)  # default unchanged: separate prisms
    assert len(f_sep) == 4 * 4 * 8 and len(f) == 10 * 8
    assert mesh_volume(v_sep, f_sep) == pytest.approx(mesh_volume(v, f), rel=1e-12)
    with pytest.raises(InvalidParameterError, match="joints must be one of"):
        cylinders_to_mesh(table, joints="welded")
    with pytest.raises(InvalidParameterError, match="caps=False"):
        cylinders_to_mesh(table, joints="miter", caps=False)
    for kwargs in ({"facets": 2}, {"max_bend_deg": 180.0}, {"max_gap_ratio": -1.0}):
        with pytest.raises(InvalidParameterError):
            tubes_to_mesh(table, **kwargs)


def test_georeferenced_tubes_keep_float64() -> None:
    base = np.array([512_345.678, 5_432_109.876, 254.0])
    table = _chain(np.asarray(BENT) * 0.1 + base, [0.01] * 4)
    tubes = tubes_to_mesh(table, facets=16)
    assert tubes.vertices.dtype == np.float64
    assert_no_degenerate(tubes.vertices, tubes.faces)
    # float64 at 5e6 m resolves ~1e-9 m: 1e-8 of a 1 cm radius; volume to ~1e-7.
    assert mesh_volume(tubes.vertices, tubes.faces) == pytest.approx(
        float(table.prism_volume_m3(16).sum()), rel=1e-6
    )


@pytest.mark.shared_data
def test_coffee_tree_as_mitred_tubes(treeqsm_csv: Path) -> None:
    table = read_cylinders(treeqsm_csv)
    tubes = tubes_to_mesh(table, facets=32)
    v_sep, f_sep = cylinders_to_mesh(table, facets=32)
    # Most joints are mitred: far fewer pieces than cylinders. TreeQSM changes the radius
    # at nearly every joint, so most joints get an annulus instead of two caps.
    assert tubes.n_tubes < table.n_cylinders / 4
    assert tubes.n_triangles < len(f_sep)
    assert_closed_and_outward(tubes.faces)
    assert_no_degenerate(tubes.vertices, tubes.faces)
    assert trimesh.Trimesh(tubes.vertices, tubes.faces, process=False).is_watertight
    # The CSV's millimetre gaps are closed at their midpoints: the volume moves a little.
    volume = mesh_volume(tubes.vertices, tubes.faces)
    assert volume == pytest.approx(float(table.prism_volume_m3(32).sum()), rel=0.005)
    assert volume == pytest.approx(table.total_volume_m3, rel=0.01)
    assert volume * 1e3 == pytest.approx(21.6, abs=0.2)
