"""Hidden surface: mesh area inside another closed part of the same mesh, known exactly.

The shapes are regular prisms (``cylinder_mesh``: closed, convex), so "strictly inside
another part" has an exact answer for any point (on the inner side of every face plane of
that part), and so do the areas: a regular ``f``-gon of circumradius ``r`` has area
``(f / 2) r² sin(2π / f)`` and perimeter ``2 f r sin(π / f)``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.compare.shapes import UTM, open_cylinder
from treesim.cloud import Cloud
from treesim.compare import HIDDEN_WHY, CompareParams, compare
from treesim.geometry import inside_other_parts, mesh_parts, sample_surface
from treesim.models import cylinder_mesh
from treesim.models.cylinders import CylinderTable
from treesim.models.mesh import cylinders_to_mesh

FACETS = 16


def polygon_area(r: float, f: int = FACETS) -> float:
    return 0.5 * f * r * r * math.sin(2 * math.pi / f)


def polygon_perimeter(r: float, f: int = FACETS) -> float:
    return 2 * f * r * math.sin(math.pi / f)


def merged(*meshes):
    """One (vertices, faces) mesh of several, and the part (input order) of each face."""
    verts, faces, part = [], [], []
    offset = 0
    for k, (v, f) in enumerate(meshes):
        verts.append(v)
        faces.append(f + offset)
        part.append(np.full(len(f), k))
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(part)


def strictly_inside_convex(points, v, f, margin=1e-9):
    """(n,) bool: inside a closed convex mesh with outward faces, farther than margin."""
    a = v[f[:, 0]]
    n = np.cross(v[f[:, 1]] - a, v[f[:, 2]] - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    side = np.einsum("pfj,fj->pf", points[:, None, :] - a[None, :, :], n)
    return (side < -margin).all(axis=1)


def tilted_prism(radius, length, start, axis, f=FACETS):
    """A closed prism of ``f`` facets from ``start`` along ``axis`` (a one-row table)."""
    table = CylinderTable(
        start=[start],
        axis=[np.asarray(axis, float) / np.linalg.norm(axis)],
        length_m=[length],
        radius_m=[radius],
        parent=[-1],
        branch=[1],
        branch_order=[0],
        position_in_branch=[1],
    )
    return cylinders_to_mesh(table, facets=f)


# Coaxial: A (R = 0.2 m, z 0..2) holds the lower half of B (r = 0.1 m, z 1..3); B's
# polygon lies inside A's (r < R cos(π / f)), so hidden: B's side below z = 2, B's base,
# and the part of A's top cap inside B's polygon.
R_A, R_B = 0.2, 0.1
COAXIAL = (cylinder_mesh(R_A, 2.0, FACETS), cylinder_mesh(R_B, 2.0, FACETS, base=(0, 0, 1.0)))
COAXIAL_AREA = 2 * polygon_area(R_A) + 2 * polygon_perimeter(R_A)
COAXIAL_AREA += 2 * polygon_area(R_B) + 2 * polygon_perimeter(R_B)
COAXIAL_HIDDEN = polygon_perimeter(R_B) * 1.0 + 2 * polygon_area(R_B)

# A T junction and a cross: a branch starting inside a trunk at right angles, and one
# crossing it obliquely; plus a prism touching the trunk's top at one point only.
TRUNK = tilted_prism(0.15, 2.0, (0, 0, 0), (0, 0, 1))
T_BRANCH = tilted_prism(0.08, 1.0, (0.0, 0.0, 1.0), (1, 0, 0))
CROSSING = tilted_prism(0.05, 1.2, (-0.5, -0.3, 0.4), (1.0, 0.6, 0.5))
TOUCHING = tilted_prism(0.1, 0.5, (0.0, 0.0, 2.0), (0.3, 0.2, 1.0))


def test_mesh_parts_finds_closed_pieces_and_open_ones():
    (va, fa), (vb, fb) = COAXIAL
    v, f, truth = merged((va, fa), (vb, fb), open_cylinder(0.3, 1.0, 12, (2.0, 0, 0)))
    parts = mesh_parts(v, f)
    assert parts.n_parts == 3 and parts.n_closed == 2
    assert list(parts.closed[parts.part_of_face[[0, len(fa), len(f) - 1]]]) == [
        True,
        True,
        False,
    ]
    # triangles of a part stay together, whatever the numbering
    for k in range(3):
        assert len(np.unique(parts.part_of_face[truth == k])) == 1
    # a triangle soup (no shared vertices) has the same pieces
    soup_v = v[f].reshape(-1, 3)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    soup = mesh_parts(soup_v, soup_f)
    assert soup.n_parts == 3 and soup.n_closed == 2


def test_prisms_touching_at_one_point_are_two_parts():
    """Separate cylinders share their cap centres: a point, not an edge, so two parts."""
    v, f, _ = merged(TRUNK, TOUCHING)
    parts = mesh_parts(v, f)
    assert parts.n_parts == 2 and parts.n_closed == 2


@pytest.mark.parametrize(
    "shapes",
    [COAXIAL, (TRUNK, T_BRANCH, CROSSING, TOUCHING)],
    ids=["coaxial", "junctions"],
)
def test_inside_other_parts_is_exact_per_sample(shapes):
    """Every sample's verdict equals the half-space truth of the convex parts."""
    v, f, part = merged(*shapes)
    pts, face = sample_surface(v, f, 40_000, seed=3)
    truth = np.zeros(len(pts), dtype=bool)
    for k, (vk, fk) in enumerate(shapes):
        other = part[face] != k
        truth[other] |= strictly_inside_convex(pts[other], vk, fk)
    got = inside_other_parts(pts, face, v, f)
    assert truth.any() and (~truth).any()
    assert np.array_equal(got, truth), f"{int((got != truth).sum())} samples misjudged"


def test_open_parts_hide_nothing_and_one_part_hides_nothing():
    (va, fa), _ = COAXIAL
    v, f, _ = merged((va, fa), open_cylinder(0.3, 3.0, 24, (0.0, 0.0, -0.5)))
    pts, face = sample_surface(v, f, 5_000, seed=1)
    assert not inside_other_parts(pts, face, v, f).any()  # the open sleeve is no solid
    pts, face = sample_surface(va, fa, 2_000, seed=1)
    assert not inside_other_parts(pts, face, va, fa).any()


@pytest.fixture(scope="module")
def coaxial_cloud():
    """Points on the visible surface of the coaxial pair only (the truth decides)."""
    (va, fa), (vb, fb) = COAXIAL
    v, f, part = merged((va, fa), (vb, fb))
    pts, face = sample_surface(v, f, 120_000, seed=11)
    hidden = np.zeros(len(pts), dtype=bool)
    for k, (vk, fk) in enumerate(COAXIAL):
        other = part[face] != k
        hidden[other] |= strictly_inside_convex(pts[other], vk, fk)
    return v, f, pts[~hidden]


@pytest.mark.parametrize("base", [(0.0, 0.0, 0.0), UTM], ids=["local", "utm"])
def test_compare_drops_the_hidden_area_of_two_overlapping_cylinders(coaxial_cloud, base):
    """The dropped area is the exact hidden area within the sampling's binomial error,
    and a cloud on the whole visible surface covers all of what is left."""
    v, f, pts = coaxial_cloud
    shift = np.asarray(base)
    res = compare(Cloud(pts + shift), (v + shift, f), sample_spacing_m=0.006, tolerance_m=0.01)
    ref = res.reference_info
    hid = ref["hidden_surface"]
    assert ref["area_m2"] == pytest.approx(COAXIAL_AREA, rel=1e-9)
    n = hid["samples_drawn"]
    p = COAXIAL_HIDDEN / COAXIAL_AREA
    se = COAXIAL_AREA * math.sqrt(p * (1 - p) / n)
    assert abs(hid["area_m2"] - COAXIAL_HIDDEN) <= 4 * se
    assert hid["area_se_m2"] == pytest.approx(se, rel=0.05)
    assert hid["visible_area_m2"] == pytest.approx(ref["area_m2"] - hid["area_m2"], rel=1e-12)
    assert (hid["parts"], hid["closed_parts"], hid["why"]) == (2, 2, HIDDEN_WHY)
    assert ref["samples"] == n - hid["samples_dropped"] == res.completeness.n
    assert res.coverage > 0.999


def test_keep_measures_the_hidden_area_as_uncovered(coaxial_cloud):
    """With ``keep`` the buried surface is sampled and, unseen, uncovered: all of it but
    the strips within τ of the visible surface (B's side just under A's top, A's cap just
    inside B's polygon: two strips of B's perimeter by τ)."""
    v, f, pts = coaxial_cloud
    tau = 0.01
    params = CompareParams(sample_spacing_m=0.006, tolerance_m=tau, hidden_surface="keep")
    res = compare(Cloud(pts), (v, f), params=params)
    assert "hidden_surface" not in res.reference_info
    assert res.reference_info["samples"] == res.completeness.n
    p = COAXIAL_HIDDEN / COAXIAL_AREA
    strips = 2 * polygon_perimeter(R_B) * tau / COAXIAL_AREA
    slack = 4 * math.sqrt(p * (1 - p) / res.completeness.n)
    assert p - strips - slack <= 1 - res.coverage <= p + slack


def test_the_cli_says_what_it_left_out(coaxial_cloud, tmp_path, capsys):
    from treesim.cli import main
    from treesim.io import write_cloud
    from treesim.io.mesh import write_mesh

    v, f, pts = coaxial_cloud
    mesh = write_mesh(tmp_path / "pair.ply", v, f)
    cloud = write_cloud(tmp_path / "cloud.ply", Cloud(pts[::20]))
    args = ["compare", str(cloud), str(mesh), "-o", str(tmp_path / "out")]
    assert main([*args, "--sample-spacing-m", "0.02", "--min-samples", "1000"]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("hidden"))
    assert "inside other closed parts of the mesh (2 closed of 2)" in line
    share = float(line.split("(")[1].split(" %")[0]) / 100
    assert share == pytest.approx(COAXIAL_HIDDEN / COAXIAL_AREA, abs=0.03)  # ~10k samples
