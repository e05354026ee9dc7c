"""Closed junctions for QSM tables: each branch's tube starts inside its parent.

A QSM (treesim's, TreeQSM's) starts a branch at its parent's *surface*: the branch's base
disc, perpendicular to the branch, touches the parent at its centre and leaves a wedge
between the disc and the parent's curved side (a notch a scanner sees into), or a flat
disc standing out of the parent where the branch leaves it obliquely. Procedural trees
(:mod:`treesim.models.procedural`) avoid this by construction: their branches start
inside their parents.

:func:`sink_branches` does the same to any table, for meshing only: before every row
that starts a branch (its parent is on another branch) it puts a *plug*, a cylinder of
the branch's base radius along the branch's axis, reaching back from the branch's start
to where the branch's axis passes closest to its parent's axis. The plug joins the
branch's tube (same axis and radius: one shared ring), so the tube runs into its parent
and the junction is closed. The plug lies inside the parent: its base disc is centred on
(or next to) the parent's axis, within the parent's circle wherever the branch is no
thicker than its parent; so it adds no visible surface, only surface that
:func:`treesim.compare.compare` leaves out as hidden, and volume inside the parent,
which :attr:`SunkTable.plug_volume_m3` reports (the table's volumes do not change: they
come from the input table).

A plug is left out where the closest approach falls outside the parent cylinder (more
than the branch's radius beyond either end: the branch does not start on the parent it
names), where the two axes are parallel, or where the branch already starts at or past
the parent's axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from .cylinders import CylinderTable
from .mesh import TubeMesh, cylinders_to_mesh, tubes_to_mesh

__all__ = ["SunkTable", "branch_tubes", "qsm_mesh", "sink_branches"]

#: A plug reaches back at most this many parent radii (the larger of its two ends).
MAX_PLUG_PARENT_RADII = 2.0

#: Branch axes closer to parallel with their parent's than this (|cos|) get no plug.
_PARALLEL_COS = 1.0 - 1e-9


@dataclass(frozen=True, eq=False)
class SunkTable:
    """A table with a plug before each branch start (see the module notes).

    Attributes
    ----------
    table : CylinderTable
        The input's rows in their order, then one row per plug. A plug has the branch's
        base radius, branch, order and tag, ``added`` True, and the branch's first row
        as its ``extension``; that row's parent becomes the plug.
    source_row : (n + k,) int64
        Row of the input table each row stands for (a plug: the branch start it extends).
    n_input : int
        Rows of the input table.
    branch_starts : int
        Rows of the input that start a branch (parent on another branch).
    """

    table: CylinderTable
    source_row: np.ndarray
    n_input: int
    branch_starts: int

    @property
    def n_plugs(self) -> int:
        """Number of plugs (branch starts sunk into their parents)."""
        return int(self.table.n_cylinders - self.n_input)

    def plug_volume_m3(self, facets: int | Sequence[int] | np.ndarray = 32) -> float:
        """Volume of the plugs as meshed with ``facets`` (one count, or one per row of
        :attr:`table`), m³: inside the parents, in the mesh's volume, not in the table's."""
        vol = self.table.prism_volume_m3(facets)
        return float(vol[self.n_input :].sum())


def sink_branches(
    table: CylinderTable, *, max_parent_radii: float = MAX_PLUG_PARENT_RADII
) -> SunkTable:
    """Put a plug before every branch start so that its tube starts inside its parent.

    Parameters
    ----------
    table : CylinderTable
        Validated first.
    max_parent_radii : float
        Longest plug, in radii of the parent (the larger of its two ends).

    Returns
    -------
    SunkTable
    """
    table.validate()
    n = table.n_cylinders
    parent, branch = table.parent, table.branch
    rows = np.flatnonzero(parent >= 0)
    rows = rows[branch[parent[rows]] != branch[rows]]
    starts = len(rows)
    par = parent[rows]
    axis = table.unit_axis
    d, a = axis[rows], axis[par]
    s, q0 = table.start[rows], table.start[par]
    w = s - q0
    b = np.einsum("ij,ij->i", d, a)
    denom = 1.0 - b * b
    ok = np.abs(b) < _PARALLEL_COS
    safe = np.where(ok, denom, 1.0)
    wd = np.einsum("ij,ij->i", w, d)
    wa = np.einsum("ij,ij->i", w, a)
    # closest approach of the branch's line (s + u d) to the parent's (q0 + t a)
    u = (b * wa - wd) / safe
    t = (wa - b * wd) / safe
    r_par = np.maximum(table.radius_m[par], table.end_radius_m[par])
    r_child = table.radius_m[rows]
    length = np.minimum(-u, max_parent_radii * r_par)
    ok &= (u < 0.0) & (length > 1e-9 * np.maximum(r_child, 1e-300))
    ok &= (t >= -r_child) & (t <= table.length_m[par] + r_child)
    rows, par, length, d, r_child = rows[ok], par[ok], length[ok], d[ok], r_child[ok]
    k = len(rows)
    if k == 0:
        return SunkTable(table, np.arange(n, dtype=np.int64), n, starts)

    plug = n + np.arange(k, dtype=np.int64)
    new_parent = np.concatenate([parent, par])
    new_parent[rows] = plug
    extension = np.concatenate([table.extension, rows])

    def stack(values: np.ndarray, extra: np.ndarray) -> np.ndarray:
        return np.concatenate([values, extra])

    sunk = CylinderTable.from_endpoints(
        stack(table.start, table.start[rows] - length[:, None] * d),
        stack(table.end, table.start[rows]),
        stack(table.radius_m, r_child),
        end_radius_m=stack(table.end_radius_m, r_child),
        parent=new_parent,
        branch=stack(branch, branch[rows]),
        branch_order=stack(table.branch_order, table.branch_order[rows]),
        tag=stack(np.asarray(table.tag), np.asarray(table.tag)[rows]),
        extension=extension,
        added=stack(table.added, np.ones(k, dtype=bool)),
        unmod_radius_m=stack(table.unmod_radius_m, r_child),
    )
    # from_endpoints recomputes the input rows' axes and lengths from their end points;
    # keep the input's own values bit for bit
    sunk = replace(
        sunk,
        axis=stack(table.axis, sunk.axis[n:]),
        length_m=stack(table.length_m, sunk.length_m[n:]),
    ).validate()
    source = np.concatenate([np.arange(n, dtype=np.int64), rows])
    return SunkTable(sunk, source, n, starts)


def branch_tubes(
    table: CylinderTable, *, facets: int | Sequence[int] | np.ndarray = 32
) -> tuple[TubeMesh, SunkTable]:
    """A QSM table meshed as one closed tube per branch with closed junctions.

    :func:`sink_branches`, then :func:`~treesim.models.mesh.tubes_to_mesh` (mitred
    joints, no notches at bends, no buried caps between a branch's cylinders).

    Parameters
    ----------
    table : CylinderTable
    facets : int or (n,) int array
        Vertices per ring: one count, or one per row of ``table`` (each plug takes the
        count of the branch start it extends).

    Returns
    -------
    tubes : TubeMesh
        Of the sunk table: ``tubes.face_cylinder`` are its rows; ``sunk.source_row``
        maps them to ``table``'s.
    sunk : SunkTable
    """
    sunk = sink_branches(table)
    per_row = facets
    if np.ndim(facets) != 0:
        per_row = np.asarray(facets)[sunk.source_row]
    return tubes_to_mesh(sunk.table, facets=per_row), sunk


def qsm_mesh(
    table: CylinderTable, *, facets: int = 32, joints: str = "miter"
) -> tuple[np.ndarray, np.ndarray, SunkTable | None]:
    """A QSM table as a mesh, the one rule for every table treesim meshes (``treesim
    model from-qsm``, plot trees from tables or clouds): ``joints="miter"`` gives
    :func:`branch_tubes` (closed tubes, each branch's start sunk into its parent),
    ``"separate"`` a closed prism per cylinder
    (:func:`~treesim.models.mesh.cylinders_to_mesh`).

    Returns
    -------
    vertices : (v, 3) float64
    faces : (f, 3) int64
    sunk : SunkTable or None
        The plugs (``miter``), for their count and volume; None for ``separate``.
    """
    if joints == "miter":
        tubes, sunk = branch_tubes(table, facets=facets)
        return tubes.vertices, tubes.faces, sunk
    v, f = cylinders_to_mesh(table, facets=facets, joints=joints)
    return v, f, None
