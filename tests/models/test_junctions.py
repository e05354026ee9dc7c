"""Closed junctions: each branch's tube starts inside its parent (known geometry)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.models.geometry import triangle_areas
from treesim.geometry import inside_other_parts, mesh_parts, sample_surface
from treesim.models import CylinderTable, branch_tubes, mesh_volume, sink_branches

R_TRUNK, R_BRANCH = 0.15, 0.06


def t_table(angle_deg: float = 90.0, offset: float = R_TRUNK) -> CylinderTable:
    """A 2 m trunk (two rows meeting at z = 1) and a branch leaving it at 1 m, at
    ``angle_deg`` from the trunk's axis, starting ``offset`` from the axis along its own
    direction (a QSM starts it at the parent's surface: offset = the parent's radius)."""
    a = math.radians(angle_deg)
    d = np.array([math.sin(a), 0.0, math.cos(a)])
    s = np.array([0.0, 0.0, 1.0]) + offset * d
    return CylinderTable.from_endpoints(
        np.array([[0, 0, 0], [0, 0, 1.0], s]),
        np.array([[0, 0, 1.0], [0, 0, 2.0], s + 0.8 * d]),
        np.array([R_TRUNK, R_TRUNK, R_BRANCH]),
        end_radius_m=np.array([R_TRUNK, 0.1, 0.04]),
        parent=np.array([-1, 0, 0]),
        branch=np.array([1, 1, 2]),
        branch_order=np.array([0, 0, 1]),
    )


@pytest.mark.parametrize("angle", [90.0, 45.0, 135.0])
def test_a_branch_start_is_sunk_to_its_parents_axis(angle):
    table = t_table(angle)
    sunk = sink_branches(table)
    assert (sunk.n_input, sunk.branch_starts, sunk.n_plugs) == (3, 1, 1)
    plug = sunk.table
    # the input's rows are kept bit for bit; the plug is row 3, before the branch
    for name in ("start", "axis", "length_m", "radius_m", "end_radius_m", "branch"):
        assert np.array_equal(getattr(plug, name)[:3], getattr(table, name)), name
    assert list(plug.parent) == [-1, 0, 3, 0] and plug.extension[3] == 2
    assert list(sunk.source_row) == [0, 1, 2, 2] and bool(plug.added[3])
    # from the trunk's axis at z = 1 to the branch's start: the parent's radius long
    assert np.allclose(plug.start[3], [0, 0, 1.0], atol=1e-12)
    assert plug.length_m[3] == pytest.approx(R_TRUNK, rel=1e-12)
    assert plug.radius_m[3] == plug.end_radius_m[3] == R_BRANCH
    assert np.allclose(plug.axis[3], table.axis[2], atol=1e-12)


@pytest.mark.parametrize(
    ("table", "why"),
    [
        (t_table(0.0), "parallel to its parent"),
        (t_table(90.0, offset=-0.05), "already starts past the parent's axis"),
    ],
)
def test_no_plug_where_none_fits(table, why):
    assert sink_branches(table).n_plugs == 0, why


def test_no_plug_when_the_branch_does_not_meet_its_parent():
    t = t_table(90.0)
    far = CylinderTable.from_endpoints(
        t.start + [[0, 0, 0], [0, 0, 0], [0, 0, 3.0]],
        t.end + [[0, 0, 0], [0, 0, 0], [0, 0, 3.0]],
        t.radius_m,
        end_radius_m=t.end_radius_m,
        parent=t.parent,
        branch=t.branch,
        branch_order=t.branch_order,
    )  # the branch's closest approach lies 2 m above the top of row 0
    assert sink_branches(far).n_plugs == 0


@pytest.mark.parametrize("facets", [8, 32])
def test_branch_tubes_close_the_junction(facets):
    """Two closed tubes; the mesh's volume is the table's prisms plus the plug; the
    plug's base disc lies inside the trunk and every sample on it is hidden."""
    table = t_table(60.0)
    tubes, sunk = branch_tubes(table, facets=facets)
    v, f = tubes.vertices, tubes.faces
    parts = mesh_parts(v, f)
    assert tubes.n_tubes == parts.n_parts == parts.n_closed == 2
    prisms = float(table.prism_volume_m3(facets).sum())
    assert mesh_volume(v, f) == pytest.approx(prisms + sunk.plug_volume_m3(facets), rel=1e-12)
    assert sunk.plug_volume_m3(facets) == pytest.approx(
        float(sunk.table.prism_volume_m3(facets)[3]), rel=1e-15
    )
    # the plug's base cap: the branch tube's first cap, centred on the trunk's axis
    cap = (tubes.face_cylinder == 3) & (tubes.face_tube == tubes.tube_of_row[3])
    tri = v[f[cap]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    base = cap.copy()
    base[cap] = np.abs(normal @ table.axis[2]) > 0.999 * np.linalg.norm(normal, axis=1)
    assert base.sum() == facets
    pts, face = sample_surface(v, f, 20_000, seed=2)
    hidden = inside_other_parts(pts, face, v, f, parts)
    on_base = base[face]
    assert on_base.any() and hidden[on_base].all()
    # the trunk is seen everywhere but inside the branch's footprint, an ellipse of
    # area pi r^2 / sin(60 deg) on a flat wall (less on the curved one, more for a polygon)
    trunk = tubes.face_tube == tubes.tube_of_row[0]
    trunk_area = triangle_areas(v, f[trunk]).sum()
    footprint = math.pi * R_BRANCH**2 / math.sin(math.radians(60.0))
    on_trunk = trunk[face]
    assert 0 < hidden[on_trunk].mean() < 1.5 * footprint / trunk_area


def test_per_row_facets_follow_the_branch_start():
    table = t_table(90.0)
    tubes, sunk = branch_tubes(table, facets=np.array([24, 24, 8]))
    assert sorted(tubes.tube_facets.tolist()) == [8, 24]
    assert tubes.tube_facets[tubes.tube_of_row[3]] == 8
