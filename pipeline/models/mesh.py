"""Triangle meshes of cylinder tables: closed prisms per cylinder, or mitred tubes per branch.

Two ways to mesh a :class:`~treesim.models.cylinders.CylinderTable`, both with
``facets`` vertices per ring (a regular polygon inscribed in each circle; the speed /
accuracy knob) and both closed, outward-oriented and watertight:

* ``joints="separate"`` (:func:`cylinders_to_mesh`'s default, the historic behaviour): each
  cylinder (or frustum) becomes its own closed prism. Cylinders do not share vertices, so
  at a bend the prisms overlap on the inside and leave a notch (a crack) on the outside.
* ``joints="miter"`` (:func:`tubes_to_mesh`): each chain of connected cylinders of one
  branch becomes one continuous tube. The ring at an inner joint lies in the plane that
  bisects the two axes (the mitre plane), and both cylinders end on it, so the tube has
  no notch and no internal faces. A cylinder cut by a plane through a point of its axis
  keeps the volume ``area * axial length`` (the oblique cut adds on one side what it
  removes on the other), so the mitred tube encloses the same volume as the separate
  prisms. Where two joined cylinders' radii differ, the joint gets a flat annulus in the
  mitre plane. A chain starts and ends with flat caps; a branch's first cap is wherever
  the table starts it (inside its parent for :mod:`treesim.models.procedural` trees).

``facets`` may also be one count per table row (level of detail, see
:mod:`treesim.models.lod`). Separate prisms take each row's count. A tube's rings must
all have the same count (its side quads and annuli join ring vertex ``k`` to ring vertex
``k``), so a tube takes the largest count of its rows: no row gets fewer facets than it
asked for, tubes of different counts share no vertices, and every guarantee above holds
per tube at its own count (closed, outward, the prisms' volume; a procedural child's base
disc stays inside its parent's tube whenever the parent has at least
:data:`~treesim.models.procedural.MIN_JUNCTION_FACETS`). One count, or an array of equal
counts, gives the same mesh bit for bit as before per-row counts existed.

A regular ``facets``-gon inscribed in a circle holds ``(facets / 2 pi) sin(2 pi / facets)``
of the circle's area: -0.64 % at 32 facets, -2.6 % at 16, -10 % at 8. Enclosed volumes
are summed by :func:`mesh_volume`; where pieces overlap (a branch starting inside its
parent) the overlap counts twice, as it does in the table's volume.

Vertices stay float64 in the table's coordinates; nothing here shifts or casts them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidGeometryError, InvalidParameterError
from ..params.models import JOINTS
from .cylinders import CylinderTable, _check_facets, _walk_to_roots

#: Default largest bend (degrees) between two cylinders that :func:`tubes_to_mesh` mitres;
#: sharper joints end one tube and start another (the mitre ellipse grows as
#: 1 / cos(bend / 2): 1.41 times the radius at 90 degrees).
MAX_MITER_BEND_DEG: float = 90.0

#: Default largest gap between a cylinder's end and its continuation's start, as a
#: fraction of the smaller radius there, that :func:`tubes_to_mesh` closes by meeting at
#: the midpoint (QSM tables written with few digits leave millimetre gaps).
MAX_JOINT_GAP_RATIO: float = 0.5

#: Radii of two joined cylinders closer than this (relative) share one ring.
_SAME_RADIUS_RTOL = 1e-9

#: Each ring's vertices move along the axis by up to r tan(bend / 2); both ends of a
#: cylinder together may use at most this fraction of its length, so its rings never cross.
_MITER_LENGTH_FRACTION = 0.9

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


def _facets_arg(facets: object) -> int | np.ndarray:
    """``facets`` checked: an int >= 3, or a 1-D int64 array of them (length not checked)."""
    if isinstance(facets, np.ndarray) and facets.ndim == 0 and facets.dtype.kind in "iu":
        facets = facets.item()
    if np.ndim(facets) == 0:
        return _check_facets(facets)  # type: ignore[arg-type]
    arr = np.asarray(facets)
    if arr.ndim != 1 or arr.dtype.kind not in "iu" or (arr.size and int(arr.min()) < 3):
        low = f", smallest {arr.min()}" if arr.size and arr.dtype.kind in "iuf" else ""
        raise InvalidParameterError(
            "facets must be an integer >= 3 (sides of the polygon around each cylinder) or "
            f"a 1-D integer array of them, one per cylinder; got a {arr.dtype} array of "
            f"shape {arr.shape}{low}"
        )
    return arr.astype(np.int64)


def _facets_per_row(facets: object, n: int) -> int | np.ndarray:
    """``facets`` as an int when uniform, else as an (n,) int64 array (checked)."""
    checked = _facets_arg(facets)
    if isinstance(checked, int):
        return checked
    if checked.shape != (n,):
        raise InvalidParameterError(
            f"facets per cylinder must have one value per table row ({n}), got {checked.shape[0]}"
        )
    if n and (checked == checked[0]).all():
        return int(checked[0])
    return checked


def _prism_vertices(
    axis: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    radius: np.ndarray,
    end_radius: np.ndarray,
    facets: int,
    caps: bool,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (m, vertices_per_cylinder, 3) with m prisms' vertices (local numbering
    of :func:`_template_faces`)."""
    f = facets
    m = axis.shape[0]
    angle = 2.0 * np.pi * np.arange(f) / f
    cos, sin = np.cos(angle)[None, :, None], np.sin(angle)[None, :, None]
    # In blocks of cylinders, so that the (block, f, 3) temporaries stay in cache.
    for lo in range(0, m, _MESH_BLOCK):
        hi = min(lo + _MESH_BLOCK, m)
        u, v = _ring_basis(axis[lo:hi])
        ring = cos * u[:, None, :]  # unit offsets from the axis to the ring vertices
        ring += sin * v[:, None, :]
        block = out[lo:hi]
        np.multiply(ring, radius[lo:hi, None, None], out=block[:, :f])
        block[:, :f] += start[lo:hi, None, :]
        np.multiply(ring, end_radius[lo:hi, None, None], out=block[:, f : 2 * f])
        block[:, f : 2 * f] += end[lo:hi, None, :]
    if caps:
        out[:, 2 * f] = start
        out[:, 2 * f + 1] = end


def cylinders_to_mesh(
    table: CylinderTable,
    *,
    facets: int | Sequence[int] | np.ndarray = 32,
    caps: bool = True,
    joints: str = "separate",
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate a table: a closed prism per cylinder, or a mitred tube per branch.

    Parameters
    ----------
    table : CylinderTable
        Validated first (radii and lengths > 0, unit axes), so no triangle is degenerate.
    facets : int or (n,) int array
        Sides of the polygon around each cylinder, >= 3: one count for all, or one per
        table row (e.g. from :func:`treesim.models.lod.lod_facets`). Separate prisms
        honour each row's count; mitred tubes use, per tube, the largest count of its rows
        (a tube's rings must match, see :func:`tubes_to_mesh`). An array whose values are
        all equal gives exactly the mesh of that single count.
    caps : bool
        Close the end discs with fans around their centres. Without caps each cylinder
        is an open tube (not watertight). Only for ``joints="separate"``: tubes always
        have caps.
    joints : {"separate", "miter"}
        ``"separate"``: one closed prism per cylinder (overlapping at bends, with a notch
        on the outside). ``"miter"``: one closed tube per chain of connected cylinders,
        without notches (see :func:`tubes_to_mesh`, which also says which face belongs to
        which cylinder).

    Returns
    -------
    vertices : (v, 3) float64
        In the table's coordinates. Separate: per cylinder the base ring, the top ring,
        then (with caps) the base and top centres (``vertices_per_cylinder`` rows each,
        at that cylinder's facet count).
    faces : (f, 3) int64
        Triangles, counter-clockwise seen from outside (outward normals). Separate:
        grouped by cylinder in table order, ``faces_per_cylinder`` each (with per-row
        facets, row ``i``'s faces start at ``faces_per_cylinder(facets[:i]).sum()``).
    """
    if joints not in JOINTS:
        raise InvalidParameterError(f"joints must be one of {', '.join(JOINTS)}, got {joints!r}")
    checked = _facets_arg(facets)
    if joints == "miter":
        if not caps:
            raise InvalidParameterError(
                "joints='miter' builds closed tubes; caps=False is only for joints='separate'"
            )
        tubes = tubes_to_mesh(table, facets=checked)
        return tubes.vertices, tubes.faces
    table.validate()
    n = table.n_cylinders
    per_row = _facets_per_row(checked, n)
    axis = table.unit_axis
    start = table.start
    end = start + table.length_m[:, None] * axis
    if not isinstance(per_row, int):
        return _varied_prisms(table, axis, start, end, per_row, caps)
    f = per_row
    vpc = vertices_per_cylinder(f, caps)
    vertices = np.empty((n, vpc, 3), dtype=np.float64)
    _prism_vertices(axis, start, end, table.radius_m, table.end_radius_m, f, caps, vertices)
    template = _template_faces(f, caps)
    offsets = np.arange(n, dtype=np.int64) * vpc
    faces = template[None, :, :] + offsets[:, None, None]
    return vertices.reshape(-1, 3), faces.reshape(-1, 3)


def _varied_prisms(
    table: CylinderTable,
    axis: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    facets: np.ndarray,
    caps: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Separate prisms with one facet count per row, in table order (vertices and faces)."""
    vpc = 2 * facets + (2 if caps else 0)
    fpc = (4 if caps else 2) * facets
    v_off = np.cumsum(vpc) - vpc
    f_off = np.cumsum(fpc) - fpc
    vertices = np.empty((int(vpc.sum()), 3), dtype=np.float64)
    faces = np.empty((int(fpc.sum()), 3), dtype=np.int64)
    for f in np.unique(facets).tolist():
        rows = np.flatnonzero(facets == f)
        nv, nf = vertices_per_cylinder(f, caps), faces_per_cylinder(f, caps)
        block = np.empty((len(rows), nv, 3), dtype=np.float64)
        _prism_vertices(
            axis[rows],
            start[rows],
            end[rows],
            table.radius_m[rows],
            table.end_radius_m[rows],
            f,
            caps,
            block,
        )
        vertices[v_off[rows][:, None] + np.arange(nv)] = block
        faces[f_off[rows][:, None] + np.arange(nf)] = (
            _template_faces(f, caps)[None, :, :] + v_off[rows][:, None, None]
        )
    return vertices, faces


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


# ---------------------------------------------------------------------- mitred tubes


@dataclass(frozen=True, eq=False)
class TubeMesh:
    """A cylinder table meshed as closed tubes, one per chain of connected cylinders.

    Attributes
    ----------
    vertices : (v, 3) float64
        In the table's coordinates.
    faces : (f, 3) int64
        Triangles, counter-clockwise seen from outside (outward normals).
    face_cylinder : (f,) int64
        Table row of each triangle: side triangles belong to their cylinder, a chain's
        caps to its first and last rows, a joint's annulus to the row after the joint.
    face_tube : (f,) int64
        Tube (closed piece) of each triangle, ``0 .. n_tubes - 1``.
    tube_of_row : (n,) int64
        Tube of each table row.
    joined : (n,) bool
        Whether each row is mitred to the row before it in its tube (False for the
        first row of a tube).
    tube_facets : (n_tubes,) int64
        Vertices per ring of each tube (all equal for a single ``facets``; with per-row
        facets, the largest of the tube's rows).
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_cylinder: np.ndarray
    face_tube: np.ndarray
    tube_of_row: np.ndarray
    joined: np.ndarray
    tube_facets: np.ndarray

    @property
    def n_tubes(self) -> int:
        """Number of closed tubes."""
        return int(self.tube_of_row.max()) + 1 if self.tube_of_row.size else 0

    @property
    def n_triangles(self) -> int:
        """Number of triangles."""
        return int(self.faces.shape[0])


def _chain_links(
    table: CylinderTable,
    axis: np.ndarray,
    end: np.ndarray,
    max_bend_deg: float,
    max_gap_ratio: float,
) -> np.ndarray:
    """(n,) int64: the row each row continues in its tube, -1 where a tube starts.

    A row continues its parent when both are on the same branch, the row is the parent's
    continuation (its ``extension``, else its lowest-numbered same-branch child), the
    bend is at most ``max_bend_deg``, the gap between the parent's end and the row's
    start is at most ``max_gap_ratio`` times the smaller radius there, and the mitred
    rings of every cylinder stay apart (see ``_MITER_LENGTH_FRACTION``).
    """
    n = table.n_cylinders
    parent, branch = table.parent, table.branch
    row = np.flatnonzero(parent >= 0)
    row = row[branch[parent[row]] == branch[row]]
    par = parent[row]
    is_ext = table.extension[par] == row
    order = np.lexsort((row, ~is_ext, par))
    row, par = row[order], par[order]
    first = np.unique(par, return_index=True)[1]
    row, par = row[first], par[first]

    r_a, r_b = table.end_radius_m[par], table.radius_m[row]
    gap = np.linalg.norm(table.start[row] - end[par], axis=1)
    cos_bend = np.clip(np.einsum("ij,ij->i", axis[par], axis[row]), -1.0, 1.0)
    ok = (gap <= max_gap_ratio * np.minimum(r_a, r_b)) & (
        cos_bend >= math.cos(math.radians(max_bend_deg))
    )
    row, par, cos_bend, gap = row[ok], par[ok], cos_bend[ok], gap[ok]
    # Axial reach of the joint's ring vertices: r tan(bend / 2), plus half the gap closed.
    tan_half = np.sqrt((1.0 - cos_bend) / (1.0 + cos_bend))
    reach = np.maximum(r_a[ok], r_b[ok]) * tan_half + 0.5 * gap

    pred = np.full(n, -1, dtype=np.int64)
    pred[row] = par
    reach_at_start = np.zeros(n)
    reach_at_start[row] = reach
    limit = _MITER_LENGTH_FRACTION * table.length_m
    while True:
        has = pred >= 0
        start_reach = np.where(has, reach_at_start, 0.0)
        end_reach = np.zeros(n)
        end_reach[pred[has]] = reach_at_start[has]
        succ = np.full(n, -1, dtype=np.int64)
        succ[pred[has]] = np.flatnonzero(has)
        bad = np.flatnonzero(start_reach + end_reach > limit)
        if bad.size == 0:
            return pred
        # Break the joint that reaches further; the other may then fit.
        drop_end = bad[end_reach[bad] >= start_reach[bad]]
        drop_start = bad[end_reach[bad] < start_reach[bad]]
        pred[succ[drop_end]] = -1
        pred[drop_start] = -1


@dataclass(frozen=True, eq=False)
class _Tubes:
    """How :func:`tubes_to_mesh` chains a table's rows into tubes (facet-independent)."""

    pred: np.ndarray  # (n,) row each row continues, -1 at a tube's first row
    row_j: np.ndarray  # rows joined to their predecessor ...
    par_j: np.ndarray  # ... and those predecessors
    succ: np.ndarray  # (n,) row continuing each row, -1 at a tube's last row
    depth: np.ndarray  # (n,) rows before each row in its tube
    head: np.ndarray  # (n,) first row of each row's tube
    n_tubes: int
    tube_of_row: np.ndarray  # (n,) tube of each row, 0 .. n_tubes - 1
    same: np.ndarray  # per joint (row_j): the two radii are equal (one shared ring)


def _tube_structure(
    table: CylinderTable,
    axis: np.ndarray,
    end: np.ndarray,
    max_bend_deg: float,
    max_gap_ratio: float,
) -> _Tubes:
    n = table.n_cylinders
    pred = _chain_links(table, axis, end, max_bend_deg, max_gap_ratio)
    row_j = np.flatnonzero(pred >= 0)
    par_j = pred[row_j]
    succ = np.full(n, -1, dtype=np.int64)
    succ[par_j] = row_j
    depth, head, _ = _walk_to_roots(pred)
    heads, tube_of_row = np.unique(head, return_inverse=True)
    r_a, r_b = table.end_radius_m[par_j], table.radius_m[row_j]
    return _Tubes(
        pred=pred,
        row_j=row_j,
        par_j=par_j,
        succ=succ,
        depth=depth,
        head=head,
        n_tubes=len(heads),
        tube_of_row=tube_of_row.reshape(-1).astype(np.int64),
        same=np.abs(r_a - r_b) <= _SAME_RADIUS_RTOL * np.maximum(r_a, r_b),
    )


def _check_tube_options(max_bend_deg: float, max_gap_ratio: float) -> None:
    if not (math.isfinite(max_bend_deg) and 0.0 < max_bend_deg < 180.0):
        raise InvalidParameterError(
            f"max_bend_deg must be a number in (0, 180), got {max_bend_deg!r}"
        )
    if not (math.isfinite(max_gap_ratio) and max_gap_ratio >= 0.0):
        raise InvalidParameterError(f"max_gap_ratio must be >= 0, got {max_gap_ratio!r}")


def _tube_facets(facets: int | np.ndarray, tubes: _Tubes) -> np.ndarray:
    """(n_tubes,) int64: one facet count per tube, the largest of its rows'."""
    if isinstance(facets, int):
        return np.full(tubes.n_tubes, facets, dtype=np.int64)
    out = np.zeros(tubes.n_tubes, dtype=np.int64)
    np.maximum.at(out, tubes.tube_of_row, facets)
    return out


def _rows_facets(
    table: CylinderTable, facets: int | Sequence[int] | np.ndarray, joints: str
) -> tuple[int | np.ndarray, int]:
    """Check ``joints``, ``facets`` and ``table``; the facets per row (or one int) and
    the number of rows."""
    if joints not in JOINTS:
        raise InvalidParameterError(f"joints must be one of {', '.join(JOINTS)}, got {joints!r}")
    checked = _facets_arg(facets)
    table.validate()
    n = table.n_cylinders
    return _facets_per_row(checked, n), n


def meshed_facets(
    table: CylinderTable,
    *,
    facets: int | Sequence[int] | np.ndarray = 32,
    joints: str = "separate",
    max_bend_deg: float = MAX_MITER_BEND_DEG,
    max_gap_ratio: float = MAX_JOINT_GAP_RATIO,
) -> np.ndarray:
    """(n,) int64: the facet count each row gets in :func:`cylinders_to_mesh`'s mesh.

    Separate prisms: ``facets`` itself (broadcast). Mitred tubes: per row, the largest
    count of the rows of its tube (see :func:`tubes_to_mesh`). Parameters as there.
    """
    per_row, n = _rows_facets(table, facets, joints)
    if joints == "separate":
        return np.broadcast_to(np.asarray(per_row, dtype=np.int64), n).copy()
    _check_tube_options(max_bend_deg, max_gap_ratio)
    tubes = _tube_structure(table, table.unit_axis, table.end, max_bend_deg, max_gap_ratio)
    return _tube_facets(per_row, tubes)[tubes.tube_of_row]


def mesh_triangle_count(
    table: CylinderTable,
    *,
    facets: int | Sequence[int] | np.ndarray = 32,
    caps: bool = True,
    joints: str = "separate",
    max_bend_deg: float = MAX_MITER_BEND_DEG,
    max_gap_ratio: float = MAX_JOINT_GAP_RATIO,
) -> int:
    """Triangles :func:`cylinders_to_mesh` (or :func:`tubes_to_mesh`) would make, without
    meshing.

    Parameters are those of :func:`cylinders_to_mesh` and, for ``joints="miter"``,
    :func:`tubes_to_mesh`. Separate prisms: ``(4 if caps else 2) * facets`` per row.
    Tubes: per tube of ``f`` facets, ``2 f`` per row, ``f`` per end cap and ``2 f`` per
    radius step.
    """
    per_row, n = _rows_facets(table, facets, joints)
    if joints == "separate":
        return int(np.sum(np.broadcast_to(per_row, n))) * (4 if caps else 2)
    if not caps:
        raise InvalidParameterError(
            "joints='miter' builds closed tubes; caps=False is only for joints='separate'"
        )
    _check_tube_options(max_bend_deg, max_gap_ratio)
    tubes = _tube_structure(table, table.unit_axis, table.end, max_bend_deg, max_gap_ratio)
    row_f = _tube_facets(per_row, tubes)[tubes.tube_of_row]
    steps = tubes.row_j[~tubes.same]
    return int(
        2 * row_f.sum()
        + row_f[tubes.pred < 0].sum()
        + row_f[tubes.succ < 0].sum()
        + 2 * row_f[steps].sum()
    )


def tubes_to_mesh(
    table: CylinderTable,
    *,
    facets: int | Sequence[int] | np.ndarray = 32,
    max_bend_deg: float = MAX_MITER_BEND_DEG,
    max_gap_ratio: float = MAX_JOINT_GAP_RATIO,
) -> TubeMesh:
    """Mesh a table as closed tubes with mitred joints: no notches at bends.

    Cylinders are chained along their branches (see :class:`TubeMesh` and the module
    notes). At each inner joint both cylinders are cut by the plane through the joint
    that bisects their axes; the ring there is shared (equal radii) or the two rings are
    joined by a flat annulus in that plane (a radius step). Ring vertices are placed with
    frames parallel-transported along the chain, so tubes do not twist. Where cylinders
    meet at their end points, the enclosed volume of each tube equals the sum of its
    cylinders' inscribed-prism volumes (:meth:`CylinderTable.prism_volume_m3`), for
    frusta as for cylinders, up to rounding (the tests check 1e-12 at 3 to 97 facets);
    closing a gap moves the joint to the gap's midpoint and the volume with it.

    Parameters
    ----------
    table : CylinderTable
        Validated first.
    facets : int or (n,) int array
        Vertices per ring, >= 3: one count for all tubes, or one per table row (e.g.
        from :func:`treesim.models.lod.lod_facets`). All rings of a tube share one count
        (side quads and annuli join ring vertex ``k`` to ring vertex ``k``), so each tube
        gets the largest count of its rows (:attr:`TubeMesh.tube_facets`): a row never
        gets fewer facets than asked. Tubes of different counts share no vertices, so
        every tube stays closed and its volume is that of its rows' inscribed prisms at
        the tube's count. An array whose values are all equal gives exactly the mesh of
        that single count.
    max_bend_deg : float
        Largest bend that is mitred, in (0, 180); sharper joints start a new tube.
    max_gap_ratio : float
        Largest gap between a cylinder's end and its continuation's start, relative to
        the smaller radius, that is closed (both meet at the gap's midpoint); larger
        gaps start a new tube. 0 joins only cylinders that meet exactly.

    Returns
    -------
    TubeMesh
        ``(2 * rows + 2 * tubes) * facets`` triangles (plus ``2 * facets`` per radius
        step), summed per tube at its own count (:func:`mesh_triangle_count`); every tube
        is closed and outward. Faces come in groups of tubes of equal facet count
        (increasing), in row order within each group.
    """
    checked = _facets_arg(facets)
    _check_tube_options(max_bend_deg, max_gap_ratio)
    table.validate()
    n = table.n_cylinders
    per_row = _facets_per_row(checked, n)
    axis = table.unit_axis
    tubes = _tube_structure(table, axis, table.end, max_bend_deg, max_gap_ratio)
    tube_facets = _tube_facets(per_row, tubes)
    rings = _ring_geometry(table, axis, tubes)
    vertices, faces, face_cylinder = _mesh_tubes(table, tubes, tube_facets, rings)

    # Drop the start rings that were merged into their predecessors' end rings.
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    return TubeMesh(
        vertices=vertices[used],
        faces=remap[faces],
        face_cylinder=face_cylinder,
        face_tube=tubes.tube_of_row[face_cylinder],
        tube_of_row=tubes.tube_of_row,
        joined=tubes.pred >= 0,
        tube_facets=tube_facets,
    )


@dataclass(frozen=True, eq=False)
class _Rings:
    """Where each row's two rings lie (per row, (n, 3) unless noted): the circle's frame
    ``e1, e2`` around the unit ``axis``, and each ring's plane (a point and a normal) and
    radius, for the start ring (``_s``) and the end ring (``_e``)."""

    axis: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    centre_s: np.ndarray
    normal_s: np.ndarray
    radius_s: np.ndarray  # (n,)
    centre_e: np.ndarray
    normal_e: np.ndarray
    radius_e: np.ndarray  # (n,)


def _ring_geometry(table: CylinderTable, axis: np.ndarray, tubes: _Tubes) -> _Rings:
    """The rings of :func:`tubes_to_mesh`: frames parallel-transported along each tube
    (so tubes do not twist) and planes perpendicular at tube ends, bisecting at joints."""
    n = table.n_cylinders
    start, end = table.start, table.end
    row_j, par_j = tubes.row_j, tubes.par_j

    # Parallel-transported ring frames: psi is each row's frame angle relative to the
    # reference basis of its axis, summed along the chain from its first row.
    u, v = _ring_basis(axis)
    delta = np.zeros(n)
    a_p, a_i = axis[par_j], axis[row_j]
    c = np.einsum("ij,ij->i", a_p, a_i)
    w = np.cross(a_p, a_i)
    u_p = u[par_j]
    moved = c[:, None] * u_p + np.cross(w, u_p)
    moved += w * (np.einsum("ij,ij->i", w, u_p) / (1.0 + c))[:, None]
    delta[row_j] = np.arctan2(
        np.einsum("ij,ij->i", moved, v[row_j]), np.einsum("ij,ij->i", moved, u[row_j])
    )
    depth, head = tubes.depth, tubes.head
    order = np.lexsort((depth, head))
    position = np.empty(n, dtype=np.int64)
    position[order] = np.arange(n)
    summed = np.cumsum(delta[order])
    psi = summed[position] - summed[position[head]]
    e1 = np.cos(psi)[:, None] * u + np.sin(psi)[:, None] * v
    e2 = np.cross(axis, e1)

    # Ring planes: perpendicular at tube ends, the bisecting plane at joints.
    centre_s, normal_s = start.copy(), axis.copy()
    centre_e, normal_e = end.copy(), axis.copy()
    joint = 0.5 * (end[par_j] + start[row_j])
    bisector = a_p + a_i
    bisector /= np.linalg.norm(bisector, axis=1, keepdims=True)
    centre_s[row_j], normal_s[row_j] = joint, bisector
    centre_e[par_j], normal_e[par_j] = joint, bisector
    return _Rings(
        axis=axis,
        e1=e1,
        e2=e2,
        centre_s=centre_s,
        normal_s=normal_s,
        radius_s=table.radius_m,
        centre_e=centre_e,
        normal_e=normal_e,
        radius_e=table.end_radius_m,
    )


@dataclass(frozen=True, eq=False)
class _Ends:
    """Each tube's two caps: whether a row starts (``is_head``) or ends (``is_tail``)
    its tube, and the index of the cap's centre vertex by row (valid where it does)."""

    is_head: np.ndarray
    is_tail: np.ndarray
    head_vertex: np.ndarray
    tail_vertex: np.ndarray


def _mesh_tubes(
    table: CylinderTable, tubes: _Tubes, tube_facets: np.ndarray, rings: _Rings
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, faces and each face's row, before unused vertices are dropped.

    Vertices: per facet count (increasing), its rows' start rings then their end rings;
    then the centres of the first caps, then those of the last caps."""
    n = table.n_cylinders
    start, end = table.start, table.end
    row_facets = tube_facets[tubes.tube_of_row]
    is_head = tubes.pred < 0
    is_tail = tubes.succ < 0
    n_heads, n_tails = int(is_head.sum()), int(is_tail.sum())
    n_ring = int(row_facets.sum())
    vertices = np.empty((2 * n_ring + n_heads + n_tails, 3), dtype=np.float64)
    vertices[2 * n_ring : 2 * n_ring + n_heads] = start[is_head]
    vertices[2 * n_ring + n_heads :] = end[is_tail]
    ends = _Ends(
        is_head=is_head,
        is_tail=is_tail,
        head_vertex=2 * n_ring + np.cumsum(is_head) - 1,
        tail_vertex=2 * n_ring + n_heads + np.cumsum(is_tail) - 1,
    )
    local = np.empty(n, dtype=np.int64)  # position of each row within its facet group
    parts: list[tuple[np.ndarray, np.ndarray, int]] = []
    first = 0
    for f in np.unique(tube_facets).tolist():
        rows = np.flatnonzero(row_facets == f)
        m = len(rows)
        local[rows] = np.arange(m)
        ring_s = vertices[first : first + m * f].reshape(m, f, 3)
        ring_e = vertices[first + m * f : first + 2 * m * f].reshape(m, f, 3)
        _place_rings(ring_s, ring_e, rows, f, m == n, rings)
        parts += _group_faces(f, rows, first, local, row_facets, tubes, ends)
        first += 2 * m * f
    faces = np.concatenate([p.reshape(-1, 3) for p, _, _ in parts])
    face_cylinder = np.concatenate([np.repeat(r, f) for _, r, f in parts])
    return vertices, faces, face_cylinder


def _place_rings(
    ring_s: np.ndarray,
    ring_e: np.ndarray,
    rows: np.ndarray,
    f: int,
    every_row: bool,
    rings: _Rings,
) -> None:
    """Write the start and end rings (``(m, f, 3)`` views into the vertices) of ``rows``,
    a block of rows at a time; ``every_row``: ``rows`` is every row, in order."""
    m = len(rows)
    angle = 2.0 * np.pi * np.arange(f) / f
    cos, sin = np.cos(angle)[None, :, None], np.sin(angle)[None, :, None]
    for lo in range(0, m, _MESH_BLOCK):
        hi = min(lo + _MESH_BLOCK, m)
        sel = slice(lo, hi) if every_row else rows[lo:hi]
        a = rings.axis[sel]
        # unit, perpendicular to a
        d = cos * rings.e1[sel][:, None, :] + sin * rings.e2[sel][:, None, :]
        for out, centre, normal, radius in (
            (ring_s, rings.centre_s, rings.normal_s, rings.radius_s),
            (ring_e, rings.centre_e, rings.normal_e, rings.radius_e),
        ):
            nrm = normal[sel]
            # Slide each circle point along the axis onto the ring's plane.
            lam = np.einsum("kfj,kj->kf", d, nrm) / np.einsum("kj,kj->k", nrm, a)[:, None]
            offset = d - lam[:, :, None] * a[:, None, :]
            np.multiply(offset, radius[sel][:, None, None], out=out[lo:hi])
            out[lo:hi] += centre[sel][:, None, :]


def _group_faces(
    f: int,
    rows: np.ndarray,
    first: int,
    local: np.ndarray,
    row_facets: np.ndarray,
    tubes: _Tubes,
    ends: _Ends,
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """The triangles of the rows of one facet count ``f``, whose rings start at vertex
    ``first``: sides, caps and radius-step annuli, each as (faces, their rows, f). A start
    ring shared with its predecessor's end ring (equal radii) is that end ring."""
    m = len(rows)
    idx_s = first + np.arange(m * f, dtype=np.int64).reshape(m, f)
    idx_e = idx_s + m * f
    in_group = row_facets[tubes.row_j] == f
    g_row, g_par, g_same = tubes.row_j[in_group], tubes.par_j[in_group], tubes.same[in_group]
    idx_s[local[g_row[g_same]]] = idx_e[local[g_par[g_same]]]
    step_rows, step_pars = g_row[~g_same], g_par[~g_same]

    k = np.arange(f, dtype=np.int64)
    k1 = (k + 1) % f
    s, e = idx_s, idx_e
    head_local = np.flatnonzero(ends.is_head[rows])
    tail_local = np.flatnonzero(ends.is_tail[rows])
    c_s = ends.head_vertex[rows[head_local]][:, None]
    c_e = ends.tail_vertex[rows[tail_local]][:, None]
    n_h, n_t = len(head_local), len(tail_local)
    sa, sb = e[local[step_pars]], s[local[step_rows]]  # ring before and after a step
    return [
        (np.stack([s[:, k], s[:, k1], e[:, k1]], axis=2), rows, f),
        (np.stack([s[:, k], e[:, k1], e[:, k]], axis=2), rows, f),
        (
            np.stack(
                [np.broadcast_to(c_s, (n_h, f)), s[head_local][:, k1], s[head_local][:, k]],
                axis=2,
            ),
            rows[head_local],
            f,
        ),
        (
            np.stack(
                [np.broadcast_to(c_e, (n_t, f)), e[tail_local][:, k], e[tail_local][:, k1]],
                axis=2,
            ),
            rows[tail_local],
            f,
        ),
        (np.stack([sa[:, k], sa[:, k1], sb[:, k1]], axis=2), step_rows, f),
        (np.stack([sa[:, k], sb[:, k1], sb[:, k]], axis=2), step_rows, f),
    ]
