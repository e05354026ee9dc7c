"""Triangle meshes of cylinder tables: closed prisms, one per cylinder.

Each cylinder (or frustum) of a :class:`~pipeline.models.cylinders.CylinderTable` becomes
a closed, outward-oriented, watertight prism: a ring of ``facets`` vertices on each end
disc (a regular polygon inscribed in the circle), the side quads split into two triangles
each, and, with ``caps``, each end closed by a fan around the disc's centre. Cylinders do
not share vertices, so the mesh of a tree is the union of its cylinders' prisms (they
overlap at the joints; its enclosed volume counts overlaps twice, like the table does).

Vertices stay float64 in the table's coordinates; nothing here shifts or casts them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InvalidGeometryError, InvalidParameterError
from .cylinders import CylinderTable, _check_facets

#: Triangles summed at a time by :func:`mesh_volume` (bounds its temporary memory).
_VOLUME_CHUNK = 1 << 20

#: Cylinders whose vertices :func:`cylinders_to_mesh` computes at a time.
_MESH_BLOCK = 2048


def vertices_per_cylinder(facets: int, caps: bool = True) -> int:
    """Vertices each cylinder contributes to :func:`cylinders_to_mesh`'s output."""
    return 2 * _check_facets(facets) + (2 if caps else 0)


def faces_per_cylinder(facets: int, caps: bool = True) -> int:
    """Triangles each cylinder contributes to :func:`cylinders_to_mesh`'s output.

    Faces are grouped by cylinder in table order, so ``face_index // faces_per_cylinder``
    is the row of the cylinder a face belongs to.
    """
    return (4 if caps else 2) * _check_facets(facets)


def _template_faces(facets: int, caps: bool) -> np.ndarray:
    """(faces_per_cylinder, 3) int64: one cylinder's triangles in local vertex numbers.

    Local vertices: 0..f-1 the base ring, f..2f-1 the top ring (same angles), 2f the base
    centre, 2f+1 the top centre. Rings run counter-clockwise seen from the top (around
    +axis), so these windings give outward normals.
    """
    f = facets
    k = np.arange(f, dtype=np.int64)
    k1 = (k + 1) % f
    parts = [
        np.stack([k, k1, f + k1], axis=1),  # side, lower-right triangle
        np.stack([k, f + k1, f + k], axis=1),  # side, upper-left triangle
    ]
    if caps:
        parts.append(np.stack([np.full(f, 2 * f), k1, k], axis=1))  # base, normal -axis
        parts.append(np.stack([np.full(f, 2 * f + 1), f + k, f + k1], axis=1))  # top, +axis
    return np.concatenate(parts, axis=0)


def _ring_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``u, v`` (each (n, 3)) with ``u x v = axis`` for unit axes (n, 3).

    ``u`` is the cross product of the axis with the world axis least aligned with it, so
    it is never near zero (that world axis is at least ~54.7 degrees from the axis).
    """
    n = axis.shape[0]
    least = np.argmin(np.abs(axis), axis=1)
    world = np.zeros((n, 3))
    world[np.arange(n), least] = 1.0
    u = np.cross(axis, world)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(axis, u)
    return u, v


def cylinders_to_mesh(
    table: CylinderTable, *, facets: int = 32, caps: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate every cylinder of a table as a closed prism.

    Parameters
    ----------
    table : CylinderTable
        Validated first (radii and lengths > 0, unit axes), so no triangle is degenerate.
    facets : int
        Sides of the polygon around each cylinder, >= 3.
    caps : bool
        Close the end discs with fans around their centres. Without caps each cylinder
        is an open tube (not watertight).

    Returns
    -------
    vertices : (n * vertices_per_cylinder, 3) float64
        Per cylinder: the base ring, the top ring, then (with caps) the base and top
        centres; in the table's coordinates.
    faces : (n * faces_per_cylinder, 3) int64
        Triangles, counter-clockwise seen from outside (outward normals), grouped by
        cylinder in table order (see :func:`faces_per_cylinder`).
    """
    facets = _check_facets(facets)
    table.validate()
    n = table.n_cylinders
    f = facets
    vpc = vertices_per_cylinder(f, caps)

    angle = 2.0 * np.pi * np.arange(f) / f
    cos, sin = np.cos(angle)[None, :, None], np.sin(angle)[None, :, None]
    axis = table.unit_axis
    start = table.start
    end = start + table.length_m[:, None] * axis
    vertices = np.empty((n, vpc, 3), dtype=np.float64)
    # In blocks of cylinders, so that the (block, f, 3) temporaries stay in cache.
    for lo in range(0, n, _MESH_BLOCK):
        hi = min(lo + _MESH_BLOCK, n)
        u, v = _ring_basis(axis[lo:hi])
        ring = cos * u[:, None, :]  # unit offsets from the axis to the ring vertices
        ring += sin * v[:, None, :]
        block = vertices[lo:hi]
        np.multiply(ring, table.radius_m[lo:hi, None, None], out=block[:, :f])
        block[:, :f] += start[lo:hi, None, :]
        np.multiply(ring, table.end_radius_m[lo:hi, None, None], out=block[:, f : 2 * f])
        block[:, f : 2 * f] += end[lo:hi, None, :]
    if caps:
        vertices[:, 2 * f] = start
        vertices[:, 2 * f + 1] = end

    template = _template_faces(f, caps)
    offsets = np.arange(n, dtype=np.int64) * vpc
    faces = template[None, :, :] + offsets[:, None, None]
    return vertices.reshape(-1, 3), faces.reshape(-1, 3)


def cylinder_mesh(
    radius_m: float,
    height_m: float,
    facets: int = 32,
    base: Sequence[float] = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """A closed vertical cylinder (a regular prism) standing on ``base``.

    Parameters
    ----------
    radius_m : float
        Circumradius of the polygon (the vertices lie on the circle), m, > 0.
    height_m : float
        Height along +z, m, > 0.
    facets : int
        Sides of the polygon, >= 3.
    base : (3,) float
        Centre of the bottom disc, m.

    Returns
    -------
    vertices : (2 * facets + 2, 3) float64
    faces : (4 * facets, 3) int64
        As :func:`cylinders_to_mesh` for a one-row table.
    """
    for name, value in (("radius_m", radius_m), ("height_m", height_m)):
        if not np.isfinite(value) or value <= 0:
            raise InvalidParameterError(f"{name} must be a finite number > 0, got {value!r}")
    base_arr = np.asarray(base, dtype=np.float64)
    if base_arr.shape != (3,) or not np.isfinite(base_arr).all():
        raise InvalidParameterError(f"base must be 3 finite coordinates, got {base!r}")
    table = CylinderTable(
        start=base_arr[None, :],
        axis=[[0.0, 0.0, 1.0]],
        length_m=[float(height_m)],
        radius_m=[float(radius_m)],
        parent=[-1],
        branch=[1],
        branch_order=[0],
        position_in_branch=[1],
    )
    return cylinders_to_mesh(table, facets=facets, caps=True)


def mesh_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed enclosed volume of a triangle mesh by the divergence theorem, m^3.

    Sums ``det(v0, v1, v2) / 6`` over the triangles, in float64, after moving the
    vertices so that their mean is the origin (which loses no precision and leaves the
    volume of a closed mesh unchanged, but keeps georeferenced coordinates from
    swamping it). Positive for a closed mesh with outward normals; for an open mesh the
    value depends on that origin.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
        Vertex indices of each triangle.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(faces)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise InvalidGeometryError(f"vertices must have shape (v, 3), got {verts.shape}")
    if tris.ndim != 2 or tris.shape[1] != 3 or (tris.size and tris.dtype.kind not in "iu"):
        raise InvalidGeometryError(
            f"faces must be an integer array of shape (f, 3), got {tris.dtype} {tris.shape}"
        )
    if tris.size == 0:
        return 0.0
    if tris.min() < 0 or tris.max() >= len(verts):
        raise InvalidGeometryError(
            f"faces refer to vertex indices outside 0..{len(verts) - 1}; check the mesh"
        )
    local = verts - verts.mean(axis=0)
    x, y, z = (np.ascontiguousarray(local[:, k]) for k in range(3))
    total = 0.0
    for lo in range(0, len(tris), _VOLUME_CHUNK):
        t = tris[lo : lo + _VOLUME_CHUNK]
        i, j, k = t[:, 0], t[:, 1], t[:, 2]
        yj, zj, yk, zk = y[j], z[j], y[k], z[k]
        det = x[i] * (yj * zk - zj * yk)
        det += y[i] * (zj * x[k] - x[j] * zk)
        det += z[i] * (x[j] * yk - yj * x[k])
        total += float(det.sum())
    return total / 6.0
