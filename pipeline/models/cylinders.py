"""Cylinder tables: quantitative structure models (QSMs) as flat arrays.

A QSM describes a tree as a set of cylinders (or frusta) linked parent -> child. This
module holds them as one :class:`CylinderTable` of numpy arrays, checks them
(:meth:`CylinderTable.validate`), measures them (volumes, DBH, height, branch counts) and
reads / writes the table formats treesim meets:

* ``"treeqsm"``: TreeQSM's flat cylinder table (``radius,length,start_x,...,parent,...``),
  ``parent`` a 1-based row index with 0 for none;
* ``"simpleforest"``: SimpleForest's table (``ID, parentID, startX, ..., endZ, radius, ...``),
  cylinders given by their end points and linked by ``ID``;
* ``"treesim"``: treesim's own table, TreeQSM's column order plus ``end_radius`` and
  ``tag`` (written by :func:`write_cylinders`, exact on round-trip);
* ``"treeqsm-txt"``: TreeQSM's text export (``save_model_text``): tab-separated
  ``cylinder_NAME.txt`` of TreeQSM 2.4 (a 13-name header over 17 columns: radius,
  length, start (3), axis (3), parent, extension, branch, branch order, position in
  branch, mad, SurfCov, added, UnmodRadius) or the headerless ``cyl_data_NAME.txt`` of
  TreeQSM 2.3 (15 columns: the same without mad and SurfCov), values rounded to 0.1 mm;
  a headerless 15-column table with added and UnmodRadius before branch (the order of
  TreeQSM's ``cylinder`` structure, as aRchi ships its tables) is told apart by which
  columns hold whole numbers.

Rows are numbered from 1 in messages, counting data rows after the header: the row a
TreeQSM ``parent`` entry refers to, and the line number minus one in a file without blank
lines.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from ..errors import EmptyInputError, InputFormatError, InvalidParameterError, ModelError

#: Allowed values of :attr:`CylinderTable.tag`: where a cylinder's geometry came from.
CYLINDER_TAGS: tuple[str, ...] = ("measured", "interpolated", "modelled")

#: Largest accepted deviation of an axis vector's length from 1. Tables written with six
#: significant figures (TreeQSM's CSV export) deviate by up to about 1e-6.
AXIS_NORM_TOLERANCE: float = 1e-4

#: Table formats :func:`read_cylinders` understands.
FORMATS: tuple[str, ...] = ("treeqsm", "treeqsm-txt", "simpleforest", "treesim")

#: Columns of TreeQSM's text export by column count (``save_model_text`` 1.1.0 of TreeQSM
#: 2.4 writes 17, version 1.0.0 of TreeQSM 2.3 wrote 15); parent and extension 1-based.
TREEQSM_TEXT_COLUMNS: dict[int, tuple[str, ...]] = {
    17: (
        "radius",
        "length",
        "start_x",
        "start_y",
        "start_z",
        "axis_x",
        "axis_y",
        "axis_z",
        "parent",
        "extension",
        "branch",
        "branch_order",
        "position_in_branch",
        "mad",
        "surf_cov",
        "added",
        "unmod_radius",
    ),
    15: (
        "radius",
        "length",
        "start_x",
        "start_y",
        "start_z",
        "axis_x",
        "axis_y",
        "axis_z",
        "parent",
        "extension",
        "branch",
        "branch_order",
        "position_in_branch",
        "added",
        "unmod_radius",
    ),
}
#: Other column orders a headerless export of that width is found in: the 15 columns in
#: the order of TreeQSM's ``cylinder`` structure (parent, extension, added, UnmodRadius,
#: then branch, branch order, position in branch), as aRchi's ``Tree_1_TreeQSM.txt`` has
#: them. A file is read in the first order whose whole-number columns hold whole numbers
#: in every row (:func:`_text_layout`).
TREEQSM_TEXT_ORDERS: dict[int, tuple[tuple[str, ...], ...]] = {
    15: (
        TREEQSM_TEXT_COLUMNS[15],
        TREEQSM_TEXT_COLUMNS[15][:10]
        + ("added", "unmod_radius", "branch", "branch_order", "position_in_branch"),
    ),
}
#: TreeQSM's columns that hold whole numbers.
_TREEQSM_WHOLE = ("parent", "extension", "branch", "branch_order", "position_in_branch", "added")

#: treesim's CSV columns, in order (TreeQSM's order, then ``end_radius`` and ``tag``).
TREESIM_COLUMNS: tuple[str, ...] = (
    "radius",
    "length",
    "start_x",
    "start_y",
    "start_z",
    "axis_x",
    "axis_y",
    "axis_z",
    "parent",
    "extension",
    "added",
    "unmod_radius",
    "branch",
    "branch_order",
    "position_in_branch",
    "end_radius",
    "tag",
)

_TREEQSM_REQUIRED: tuple[str, ...] = (
    "radius",
    "length",
    "start_x",
    "start_y",
    "start_z",
    "axis_x",
    "axis_y",
    "axis_z",
    "parent",
    "branch",
    "branch_order",
)

_SIMPLEFOREST_REQUIRED: tuple[str, ...] = (
    "ID",
    "parentID",
    "startX",
    "startY",
    "startZ",
    "endX",
    "endY",
    "endZ",
    "radius",
    "branchOrder",
)


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, copy=True)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, kw_only=True, eq=False)
class CylinderTable:
    """A tree as a table of cylinders (or frusta), one row per cylinder.

    Construction converts and shape-checks the arrays (raising :class:`ModelError` on a
    shape mismatch) and stores read-only copies; :meth:`validate` checks the content.
    The readers validate what they read.

    Parameters
    ----------
    start : (n, 3) float64
        Centre of each cylinder's base disc, in metres, in the input's coordinates.
    axis : (n, 3) float64
        Unit direction from the base disc to the top disc (norm 1 within
        :data:`AXIS_NORM_TOLERANCE`; stored as given, normalised where geometry is built).
    length_m : (n,) float64
        Length along the axis, metres, > 0.
    radius_m : (n,) float64
        Radius at the base disc, metres, > 0.
    parent : (n,) int64
        0-based row of the parent cylinder, -1 for none (a root).
    branch : (n,) int64
        Branch identifier (as in the source table; only distinctness matters).
    branch_order : (n,) int64
        0 for the stem, 1 for branches off the stem, and so on; >= 0.
    position_in_branch : (n,) int64
        1-based position of the cylinder along its branch.
    end_radius_m : (n,) float64, optional
        Radius at the top disc, metres, > 0; defaults to ``radius_m`` (a cylinder).
    tag : (n,) str, optional
        Provenance of each cylinder, one of :data:`CYLINDER_TAGS`; default ``"measured"``.
    extension : (n,) int64, optional
        0-based row of the cylinder continuing this one's branch, -1 for none (TreeQSM's
        ``extension``); default all -1.
    added : (n,) bool, optional
        TreeQSM's ``added`` flag (cylinder added to fill a gap); default all False.
    unmod_radius_m : (n,) float64, optional
        TreeQSM's radius before its corrections; defaults to ``radius_m``.
    """

    start: np.ndarray
    axis: np.ndarray
    length_m: np.ndarray
    radius_m: np.ndarray
    parent: np.ndarray
    branch: np.ndarray
    branch_order: np.ndarray
    position_in_branch: np.ndarray
    end_radius_m: np.ndarray | None = None
    tag: np.ndarray | None = None
    extension: np.ndarray | None = None
    added: np.ndarray | None = None
    unmod_radius_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        try:
            start = np.asarray(self.start, dtype=np.float64)
            axis = np.asarray(self.axis, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ModelError(f"start and axis must be numeric (n, 3) arrays: {exc}") from exc
        if start.ndim != 2 or start.shape[1] != 3:
            raise ModelError(f"start must have shape (n, 3), got {start.shape}")
        n = start.shape[0]
        if axis.shape != (n, 3):
            raise ModelError(f"axis must have shape ({n}, 3) like start, got {axis.shape}")
        values: dict[str, Any] = {"start": start, "axis": axis}
        defaults: dict[str, Any] = {
            "end_radius_m": self.radius_m,
            "tag": np.full(n, CYLINDER_TAGS[0]),
            "extension": np.full(n, -1),
            "added": np.zeros(n, dtype=bool),
            "unmod_radius_m": self.radius_m,
        }
        kinds = {
            "length_m": np.float64,
            "radius_m": np.float64,
            "end_radius_m": np.float64,
            "unmod_radius_m": np.float64,
            "parent": np.int64,
            "branch": np.int64,
            "branch_order": np.int64,
            "position_in_branch": np.int64,
            "extension": np.int64,
            "added": bool,
            "tag": str,
        }
        for name, dtype in kinds.items():
            raw = getattr(self, name)
            if raw is None:
                raw = defaults[name]
            try:
                arr = np.asarray(raw)
                if dtype is np.int64 and arr.dtype.kind == "f":
                    bad = ~np.isfinite(arr) | (arr != np.round(arr))
                    if bad.any():
                        row = int(np.flatnonzero(bad)[0]) + 1
                        raise ModelError(
                            f"row {row}: {name} is {float(arr[row - 1])!r}, not a whole number; "
                            f"{name} must hold integers"
                        )
                arr = arr.astype(dtype)
            except (TypeError, ValueError) as exc:
                raise ModelError(f"{name} cannot be converted to {dtype}: {exc}") from exc
            if arr.shape != (n,):
                raise ModelError(
                    f"{name} must have shape ({n},) like start, got {arr.shape}; give one "
                    "value per cylinder"
                )
            values[name] = arr
        for name, arr in values.items():
            object.__setattr__(self, name, _readonly(arr))

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_endpoints(
        cls,
        start: np.ndarray,
        end: np.ndarray,
        radius_m: np.ndarray,
        *,
        parent: np.ndarray,
        branch: np.ndarray,
        branch_order: np.ndarray,
        position_in_branch: np.ndarray | None = None,
        **optional: Any,
    ) -> CylinderTable:
        """A table from cylinder end points instead of axis and length.

        Parameters
        ----------
        start, end : (n, 3) float64
            Centres of the base and top discs, metres.
        radius_m : (n,) float64
            Base radii, metres.
        parent, branch, branch_order : (n,) int
            As in :class:`CylinderTable` (``parent`` 0-based, -1 for none).
        position_in_branch : (n,) int, optional
            Derived from the parent links and ``branch`` when not given.
        **optional
            ``end_radius_m``, ``tag``, ``extension``, ``added``, ``unmod_radius_m``.

        Returns
        -------
        CylinderTable
            Not validated; a zero-length cylinder gets a zero axis, which
            :meth:`validate` reports.
        """
        start = np.asarray(start, dtype=np.float64)
        end = np.asarray(end, dtype=np.float64)
        if start.shape != end.shape or start.ndim != 2 or start.shape[1:] != (3,):
            raise ModelError(
                f"start and end must both have shape (n, 3), got {start.shape} and {end.shape}"
            )
        delta = end - start
        length = np.linalg.norm(delta, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            axis = np.where(length[:, None] > 0, delta / length[:, None], 0.0)
        parent = np.asarray(parent)
        if position_in_branch is None:
            position_in_branch = _positions_in_branch(
                np.asarray(parent, dtype=np.int64), np.asarray(branch, dtype=np.int64)
            )
        return cls(
            start=start,
            axis=axis,
            length_m=length,
            radius_m=radius_m,
            parent=parent,
            branch=branch,
            branch_order=branch_order,
            position_in_branch=position_in_branch,
            **optional,
        )

    # ------------------------------------------------------------------ checking

    def validate(self, *, source: str | None = None) -> CylinderTable:
        """Check the content; raise :class:`ModelError` naming the first bad row.

        Checks, in order: at least one cylinder; finite values; radii (base, end and
        unmodified) > 0; length > 0; axis of norm 1 (within :data:`AXIS_NORM_TOLERANCE`);
        parent and extension rows in range; no cycles in the parent links;
        ``branch_order`` >= 0; tags from :data:`CYLINDER_TAGS`.

        Parameters
        ----------
        source : str, optional
            Where the table came from (a path), prefixed to messages.

        Returns
        -------
        CylinderTable
            ``self``, so that ``table = CylinderTable(...).validate()`` reads well.

        Raises
        ------
        ModelError
            On the first failed check; the message names the 1-based row.
        EmptyInputError
            If the table has no rows.
        """
        where = f"{source}: " if source else ""
        n = self.n_cylinders
        if n == 0:
            raise EmptyInputError(f"{where}the cylinder table has no rows")

        def fail(row0: int, what: str, fix: str) -> NoReturn:
            raise ModelError(f"{where}row {row0 + 1}: {what}; {fix}")

        float_cols = {
            "start": self.start,
            "axis": self.axis,
            "length_m": self.length_m,
            "radius_m": self.radius_m,
            "end_radius_m": self.end_radius_m,
            "unmod_radius_m": self.unmod_radius_m,
        }
        first_bad = n
        bad_name = ""
        for name, arr in float_cols.items():
            bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
            if bad.any() and int(np.flatnonzero(bad)[0]) < first_bad:
                first_bad, bad_name = int(np.flatnonzero(bad)[0]), name
        if first_bad < n:
            value = float_cols[bad_name][first_bad]
            fail(
                first_bad,
                f"{bad_name} is {np.array2string(np.asarray(value))}, not a finite number",
                "fill in the missing value or drop the row (and re-link its children)",
            )

        for name in ("radius_m", "end_radius_m", "unmod_radius_m"):
            arr = getattr(self, name)
            bad = np.flatnonzero(arr <= 0)
            if bad.size:
                fail(
                    int(bad[0]),
                    f"{name} is {float(arr[bad[0]])!r}; radii must be > 0",
                    "fix the radius or drop the row",
                )
        bad = np.flatnonzero(self.length_m <= 0)
        if bad.size:
            fail(
                int(bad[0]),
                f"length_m is {float(self.length_m[bad[0]])!r}; lengths must be > 0",
                "drop the zero-length cylinder and link its children to its parent",
            )
        norm = np.linalg.norm(self.axis, axis=1)
        bad = np.flatnonzero(np.abs(norm - 1.0) > AXIS_NORM_TOLERANCE)
        if bad.size:
            i = int(bad[0])
            fail(
                i,
                f"axis {self.axis[i].tolist()} has length {norm[i]:.6g}, not 1",
                "give a unit direction vector (axis / |axis|)",
            )

        for name in ("parent", "extension"):
            arr = getattr(self, name)
            bad = np.flatnonzero((arr < -1) | (arr >= n))
            if bad.size:
                i = int(bad[0])
                fail(
                    i,
                    f"{name} points to row {arr[i] + 1}, outside the table's rows 1..{n}",
                    f"use a row between 1 and {n} (0 in 1-based files, -1 in the 0-based "
                    "table, for none)",
                )
        _raise_if_cycle(self.parent, source)

        bad = np.flatnonzero(self.branch_order < 0)
        if bad.size:
            fail(
                int(bad[0]),
                f"branch_order is {self.branch_order[bad[0]]}; orders start at 0 (the stem)",
                "fix the branch order",
            )
        bad = np.flatnonzero(~np.isin(self.tag, CYLINDER_TAGS))
        if bad.size:
            fail(
                int(bad[0]),
                f"tag is {str(self.tag[bad[0]])!r}",
                f"use one of {', '.join(CYLINDER_TAGS)}",
            )
        return self

    # ------------------------------------------------------------------ geometry

    def __len__(self) -> int:
        return self.n_cylinders

    @property
    def n_cylinders(self) -> int:
        """Number of cylinders (rows)."""
        return int(self.start.shape[0])

    @property
    def unit_axis(self) -> np.ndarray:
        """(n, 3) float64: the axes normalised to length 1 exactly (zero axes stay zero)."""
        norm = np.linalg.norm(self.axis, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(norm > 0, self.axis / norm, 0.0)

    @property
    def end(self) -> np.ndarray:
        """(n, 3) float64: centres of the top discs, ``start + length_m * unit_axis``."""
        return self.start + self.length_m[:, None] * self.unit_axis

    @property
    def volume_m3(self) -> np.ndarray:
        """(n,) float64: volume of each frustum, pi l (r0^2 + r0 r1 + r1^2) / 3, m^3."""
        r0, r1 = self.radius_m, self.end_radius_m
        return math.pi * self.length_m * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0

    def prism_volume_m3(self, facets: int | Sequence[int] | np.ndarray) -> np.ndarray:
        """(n,) float64: volume of each cylinder as meshed with ``facets`` sides, m^3.

        The mesh inscribes a regular polygon of ``facets`` sides in each disc, whose area
        is ``facets / 2 * r^2 * sin(2 pi / facets)``; this is :attr:`volume_m3` scaled by
        that area over pi r^2. ``facets`` is one count (>= 3) or one per row ((n,) int,
        as :func:`~treesim.models.mesh.cylinders_to_mesh` accepts).
        """
        if np.ndim(facets) == 0:
            f = _check_facets(facets)  # type: ignore[arg-type]
            return self.volume_m3 * (f * math.sin(2.0 * math.pi / f) / (2.0 * math.pi))
        arr = np.asarray(facets)
        if arr.shape != (self.n_cylinders,) or arr.dtype.kind not in "iu" or arr.min() < 3:
            raise InvalidParameterError(
                f"facets must be an integer >= 3 or one per row ({self.n_cylinders}), got a "
                f"{arr.dtype} array of shape {arr.shape}"
            )
        f_arr = arr.astype(np.float64)
        return self.volume_m3 * (f_arr * np.sin(2.0 * np.pi / f_arr) / (2.0 * np.pi))

    @property
    def total_volume_m3(self) -> float:
        """Sum of all cylinder volumes, m^3."""
        return float(self.volume_m3.sum())

    @property
    def stem_volume_m3(self) -> float:
        """Volume of the stem (``branch_order == 0``), m^3."""
        return float(self.volume_m3[self.branch_order == 0].sum())

    @property
    def branch_volume_m3(self) -> float:
        """Volume of everything but the stem (``branch_order > 0``), m^3."""
        return float(self.volume_m3[self.branch_order > 0].sum())

    @property
    def total_length_m(self) -> float:
        """Sum of all cylinder lengths, m."""
        return float(self.length_m.sum())

    @property
    def height_m(self) -> float:
        """Highest minus lowest z over all cylinder start and end centres, m."""
        z = np.concatenate([self.start[:, 2], self.end[:, 2]])
        return float(z.max() - z.min())

    def dbh_m(self, height_m: float = 1.3) -> float:
        """Stem diameter ``height_m`` above the stem base, m.

        The base is the lowest start z of the stem (``branch_order == 0``). The stem
        cylinder whose z range contains ``base + height_m`` is used (the first such row
        if several do); if none does, the stem cylinder whose z range is nearest. For a
        frustum the radius is interpolated along its axis at that height (clamped to the
        cylinder's ends).

        Raises
        ------
        ModelError
            If the table has no stem cylinders.
        """
        stem = np.flatnonzero(self.branch_order == 0)
        if stem.size == 0:
            raise ModelError(
                "the table has no stem cylinders (branch_order 0), so it has no DBH; "
                "check the branch_order column"
            )
        z0 = self.start[stem, 2]
        z1 = self.end[stem, 2]
        target = float(z0.min()) + float(height_m)
        lo, hi = np.minimum(z0, z1), np.maximum(z0, z1)
        gap = np.maximum(lo - target, 0.0) + np.maximum(target - hi, 0.0)
        k = int(np.argmin(gap))  # first of the zero gaps when several cylinders cross
        dz = z1[k] - z0[k]
        t = 0.0 if dz == 0 else float(np.clip((target - z0[k]) / dz, 0.0, 1.0))
        i = stem[k]
        radius = self.radius_m[i] + t * (self.end_radius_m[i] - self.radius_m[i])
        return float(2.0 * radius)

    def branches_per_order(self) -> dict[int, int]:
        """Number of distinct ``branch`` values per ``branch_order``, by ascending order."""
        pairs = np.unique(np.stack([self.branch_order, self.branch], axis=1), axis=0)
        orders, counts = np.unique(pairs[:, 0], return_counts=True)
        return {int(o): int(c) for o, c in zip(orders, counts, strict=True)}

    def summary(self) -> dict[str, Any]:
        """Headline figures of the tree.

        Returns
        -------
        dict
            ``dbh_m``, ``height_m``, ``volume_total_m3``, ``volume_stem_m3``,
            ``volume_branch_m3`` (floats), ``n_cylinders`` (int), ``branches_per_order``
            (dict int -> int). ``dbh_m`` is None when the table has no stem.
        """
        try:
            dbh: float | None = self.dbh_m()
        except ModelError:
            dbh = None
        return {
            "dbh_m": dbh,
            "height_m": self.height_m,
            "volume_total_m3": self.total_volume_m3,
            "volume_stem_m3": self.stem_volume_m3,
            "volume_branch_m3": self.branch_volume_m3,
            "n_cylinders": self.n_cylinders,
            "branches_per_order": self.branches_per_order(),
        }

    def identical(self, other: CylinderTable) -> bool:
        """True if every array of ``other`` equals this table's exactly (bit for bit)."""
        return all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name)) for f in fields(self)
        )


# ---------------------------------------------------------------------- topology helpers


def _walk_to_roots(parent: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int] | None]:
    """Depth and root of every row by pointer doubling, or a cycle.

    Parameters
    ----------
    parent : (n,) int64
        0-based parent rows, -1 for none, all in ``[-1, n)``.

    Returns
    -------
    depth : (n,) int64
        Number of ancestors (0 for a root). Meaningless when a cycle is returned.
    root : (n,) int64
        Row of each row's root.
    cycle : list of int or None
        0-based rows of one cycle (the one reached from the lowest row that does not
        lead to a root), in parent order, or None.
    """
    n = parent.shape[0]
    anc = parent.astype(np.int64, copy=True)
    depth = (anc >= 0).astype(np.int64)
    root = np.where(anc >= 0, anc, np.arange(n))
    # After k rounds anc is the 2**k-th ancestor; 2**k >= n means every chain has ended.
    for _ in range(max(1, int(n).bit_length()) + 1):
        live = anc >= 0
        if not live.any():
            break
        nxt = anc[live]
        depth[live] += depth[nxt]
        root[live] = root[nxt]
        anc[live] = anc[nxt]
    stuck = np.flatnonzero(anc >= 0)
    if stuck.size == 0:
        return depth, root, None
    seen: dict[int, int] = {}
    row = int(stuck[0])
    path: list[int] = []
    while row not in seen:
        seen[row] = len(path)
        path.append(row)
        row = int(parent[row])
    return depth, root, path[seen[row] :]


def _raise_if_cycle(parent: np.ndarray, source: str | None = None) -> None:
    """Raise :class:`ModelError` if the parent links (0-based, in range) hold a cycle."""
    _, _, cycle = _walk_to_roots(parent)
    if cycle is not None:
        where = f"{source}: " if source else ""
        rows = " -> ".join(str(r + 1) for r in [*cycle, cycle[0]])
        raise ModelError(
            f"{where}row {min(cycle) + 1}: the parent links form a cycle (rows {rows}); "
            "every chain of parents must end at a root (parent 0 in a TreeQSM file, -1 "
            "in a SimpleForest file): break the cycle"
        )


def _positions_in_branch(parent: np.ndarray, branch: np.ndarray) -> np.ndarray:
    """(n,) int64: 1-based position along the branch, following same-branch parent links."""
    n = parent.shape[0]
    if parent.shape != branch.shape or parent.ndim != 1:
        raise ModelError(
            f"parent and branch must have the same shape (n,), got {parent.shape} and "
            f"{branch.shape}"
        )
    bad = np.flatnonzero((parent < -1) | (parent >= n))
    if bad.size:
        i = int(bad[0])
        raise ModelError(
            f"row {i + 1}: parent points to row {parent[i] + 1}, outside the table's rows "
            f"1..{n}; use a row between 1 and {n}, or none"
        )
    _raise_if_cycle(parent)
    ok = parent >= 0
    same = np.full(n, -1, dtype=np.int64)
    same[ok] = np.where(branch[parent[ok]] == branch[ok], parent[ok], -1)
    depth, _, _ = _walk_to_roots(same)
    return depth + 1


def _extensions(parent: np.ndarray, branch: np.ndarray) -> np.ndarray:
    """(n,) int64: for each row, the last-listed child on the same branch, -1 if none."""
    n = parent.shape[0]
    ext = np.full(n, -1, dtype=np.int64)
    child = np.flatnonzero((parent >= 0) & (parent < n))
    child = child[branch[parent[child]] == branch[child]]
    ext[parent[child]] = child
    return ext


def _check_facets(facets: int) -> int:
    if isinstance(facets, bool) or not isinstance(facets, int | np.integer) or facets < 3:
        raise InvalidParameterError(
            f"facets must be an integer >= 3 (sides of the polygon around each cylinder), "
            f"got {facets!r}"
        )
    return int(facets)


# ---------------------------------------------------------------------- CSV reading


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    """Header (stripped names) and non-blank data rows of a CSV file."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            first = fh.readline()
            delimiter = ","
            for cand in (",", ";", "\t"):
                if cand in first:
                    delimiter = cand
                    break
            fh.seek(0)
            rows = [r for r in csv.reader(fh, delimiter=delimiter) if any(c.strip() for c in r)]
    except FileNotFoundError as exc:
        raise InputFormatError(f"cylinder table not found: {path}; check the path") from exc
    except UnicodeDecodeError as exc:
        raise InputFormatError(
            f"{path}: not a text CSV file ({exc.reason}); give a CSV cylinder table"
        ) from exc
    except (OSError, csv.Error) as exc:
        raise InputFormatError(f"{path}: cannot read the cylinder table: {exc}") from exc
    if not rows:
        raise InputFormatError(f"{path}: the file is empty; expected a CSV cylinder table")
    header = [c.strip() for c in rows[0]]
    data = rows[1:]
    width = len(header)
    for i, r in enumerate(data):
        if len(r) != width:
            raise InputFormatError(
                f"{path}: row {i + 1} has {len(r)} fields but the header has {width}; "
                "fix the row (a missing or extra comma?)"
            )
    return header, data


def _detect_format(header: Sequence[str]) -> str | None:
    names = set(header)
    if {"ID", "parentID", "startX"} & names:
        return "simpleforest"
    if "end_radius" in names or "tag" in names:
        return "treesim"
    if {"radius", "start_x", "axis_x"} & names:
        return "treeqsm"
    return None


class _Columns:
    """Column access by name, with row-naming conversion errors."""

    def __init__(self, path: Path, header: list[str], rows: list[list[str]]) -> None:
        self.path = path
        self.index = {name: j for j, name in enumerate(header)}
        self.cols = list(zip(*rows, strict=True)) if rows else [() for _ in header]
        self.n = len(rows)

    def require(self, names: Sequence[str], fmt: str) -> None:
        missing = [c for c in names if c not in self.index]
        if missing:
            raise ModelError(
                f"{self.path}: missing required column(s) {', '.join(missing)} in this "
                f"{fmt} table; a {fmt} table needs {', '.join(names)}"
            )

    def has(self, name: str) -> bool:
        return name in self.index

    def texts(self, name: str) -> np.ndarray:
        return np.array([c.strip() for c in self.cols[self.index[name]]], dtype=str)

    def floats(self, name: str) -> np.ndarray:
        col = self.cols[self.index[name]]
        try:
            return np.array(col, dtype=np.float64)
        except ValueError:
            for i, cell in enumerate(col):
                try:
                    float(cell)
                except ValueError:
                    raise InputFormatError(
                        f"{self.path}: row {i + 1}: column {name} holds {cell!r}, not a "
                        "number; fix the cell (use nan for a missing value)"
                    ) from None
            raise  # pragma: no cover - numpy and float() disagree

    def ints(self, name: str) -> np.ndarray:
        arr = self.floats(name)
        bad = np.flatnonzero(~np.isfinite(arr) | (arr != np.round(arr)))
        if bad.size:
            i = int(bad[0])
            raise ModelError(
                f"{self.path}: row {i + 1}: column {name} holds {float(arr[i])!r}, not a whole "
                "number; fix the cell"
            )
        return arr.astype(np.int64)


def _read_treeqsm(cols: _Columns, fmt: str) -> CylinderTable:
    required = _TREEQSM_REQUIRED + (("end_radius", "tag") if fmt == "treesim" else ())
    cols.require(required, fmt)
    n = cols.n
    radius = cols.floats("radius")

    def optional_int(name: str, default: np.ndarray) -> np.ndarray:
        return cols.ints(name) if cols.has(name) else default

    parent = cols.ints("parent") - 1
    branch = cols.ints("branch")
    position = (
        cols.ints("position_in_branch")
        if cols.has("position_in_branch")
        else _positions_in_branch(parent, branch)
    )
    return CylinderTable(
        start=np.stack([cols.floats(f"start_{c}") for c in "xyz"], axis=1),
        axis=np.stack([cols.floats(f"axis_{c}") for c in "xyz"], axis=1),
        length_m=cols.floats("length"),
        radius_m=radius,
        parent=parent,
        branch=branch,
        branch_order=cols.ints("branch_order"),
        position_in_branch=position,
        end_radius_m=cols.floats("end_radius") if cols.has("end_radius") else None,
        tag=cols.texts("tag") if cols.has("tag") else None,
        extension=optional_int("extension", np.zeros(n, dtype=np.int64)) - 1,
        added=optional_int("added", np.zeros(n, dtype=np.int64)) != 0,
        unmod_radius_m=cols.floats("unmod_radius") if cols.has("unmod_radius") else None,
    )


def _read_simpleforest(cols: _Columns) -> CylinderTable:
    cols.require(_SIMPLEFOREST_REQUIRED, "simpleforest")
    ids = cols.ints("ID")
    parent_ids = cols.ints("parentID")
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    dup = np.flatnonzero(sorted_ids[1:] == sorted_ids[:-1])
    if dup.size:
        rows = sorted(order[dup[0] : dup[0] + 2] + 1)
        raise ModelError(
            f"{cols.path}: row {rows[1]}: ID {sorted_ids[dup[0]]} already used by row "
            f"{rows[0]}; IDs must be unique"
        )
    pos = np.clip(np.searchsorted(sorted_ids, parent_ids), 0, max(cols.n - 1, 0))
    found = sorted_ids[pos] == parent_ids if cols.n else np.zeros(0, dtype=bool)
    bad = np.flatnonzero(~found & (parent_ids != -1))
    if bad.size:
        i = int(bad[0])
        raise ModelError(
            f"{cols.path}: row {i + 1}: parentID {parent_ids[i]} is not the ID of any "
            "cylinder in the table; use an existing ID, or -1 for none"
        )
    parent = np.where(found, order[pos], -1).astype(np.int64)
    _raise_if_cycle(parent, str(cols.path))
    branch_order = cols.ints("branchOrder")
    # A TreeQSM-style branch is a chain of cylinders of one order; SimpleForest's
    # segmentID splits chains at every fork, so branches are rebuilt from the links: a
    # branch starts at a root or where the order changes, and gets the number (from 1)
    # of its first row among the branch starts.
    cont = (parent >= 0) & (branch_order[np.maximum(parent, 0)] == branch_order)
    _, first_row, _ = _walk_to_roots(np.where(cont, parent, -1))
    branch = np.unique(first_row, return_inverse=True)[1].reshape(-1) + 1
    return CylinderTable.from_endpoints(
        np.stack([cols.floats(f"start{c}") for c in "XYZ"], axis=1),
        np.stack([cols.floats(f"end{c}") for c in "XYZ"], axis=1),
        cols.floats("radius"),
        parent=parent,
        branch=branch,
        branch_order=branch_order,
        extension=_extensions(parent, branch),
    )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _sniff_treeqsm_text(path: Path) -> bool:
    """Whether the file looks like TreeQSM's text export (see :data:`TREEQSM_TEXT_COLUMNS`)."""
    try:
        with path.open(encoding="utf-8-sig", errors="replace") as fh:
            first = fh.readline().strip()
    except OSError:
        return False  # reported by the reader
    if first.lower().startswith("radius (m)"):
        return True
    fields = first.split()
    return (
        "," not in first
        and ";" not in first
        and len(fields) in TREEQSM_TEXT_COLUMNS
        and all(_is_number(x) for x in fields)
    )


def _read_treeqsm_text(path: Path) -> CylinderTable:
    """TreeQSM's ``save_model_text`` output as a table (not yet validated)."""
    try:
        with path.open(encoding="utf-8-sig") as fh:
            lines = [line.split() for line in fh if line.strip()]
    except FileNotFoundError as exc:
        raise InputFormatError(f"cylinder table not found: {path}; check the path") from exc
    except UnicodeDecodeError as exc:
        raise InputFormatError(
            f"{path}: not a text file ({exc.reason}); give a TreeQSM text export"
        ) from exc
    except OSError as exc:
        raise InputFormatError(f"{path}: cannot read the cylinder table: {exc}") from exc
    if not lines:
        raise InputFormatError(f"{path}: the file is empty; expected a TreeQSM text export")
    if not all(_is_number(x) for x in lines[0]):
        lines = lines[1:]  # the header: names with units, fewer than the columns
    if not lines:
        raise EmptyInputError(f"{path}: the TreeQSM text export has a header but no rows")
    width = len(lines[0])
    if width not in TREEQSM_TEXT_COLUMNS:
        counts = " or ".join(str(k) for k in TREEQSM_TEXT_COLUMNS)
        raise InputFormatError(
            f"{path}: row 1 has {width} columns; TreeQSM's text export has {counts}"
        )
    for i, r in enumerate(lines):
        if len(r) != width:
            raise InputFormatError(
                f"{path}: row {i + 1} has {len(r)} columns but row 1 has {width}; fix the row"
            )
    cols = _Columns(path, list(_text_layout(width, lines)), lines)
    return _read_treeqsm(cols, "treeqsm")


def _text_layout(width: int, lines: list[list[str]]) -> tuple[str, ...]:
    """The column names of a TreeQSM text export ``width`` columns wide: the first of
    :data:`TREEQSM_TEXT_ORDERS` whose whole-number columns hold whole numbers in every row
    (TreeQSM's own order where none does: its reader names the bad cell)."""
    orders = TREEQSM_TEXT_ORDERS.get(width, (TREEQSM_TEXT_COLUMNS[width],))
    for names in orders:
        try:
            values = np.array(
                [[r[names.index(c)] for c in _TREEQSM_WHOLE] for r in lines], dtype=np.float64
            )
        except ValueError:
            break  # a cell that is no number: the reader says which
        if np.all(np.isfinite(values) & (values == np.round(values))):
            return names
    return orders[0]


def read_cylinders(path: str | Path, format: str | None = None) -> CylinderTable:
    """Read and validate a cylinder table from a CSV (or TreeQSM text) file.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    format : {"treeqsm", "treeqsm-txt", "simpleforest", "treesim"}, optional
        The table's format; detected from the header when not given: SimpleForest's
        header has ``ID, parentID, startX, ...``; treesim's is TreeQSM's with
        ``end_radius`` and ``tag``; TreeQSM's has ``radius, length, start_x, ...``;
        TreeQSM's text export starts with ``radius (m)`` or has no header and 15 or 17
        whitespace-separated numbers per row.
        Extra columns (TreeQSM's ``surf_cov``, ``mad``; SimpleForest's
        ``growthLength``, ...) are ignored.

    Returns
    -------
    CylinderTable
        Validated. From SimpleForest: ``axis`` and ``length_m`` are derived from the end
        points, ``parentID`` is mapped to rows; ``branch`` numbers (from 1) the chains of
        cylinders of one ``branchOrder`` (a new branch starts at a root or where the
        order changes; SimpleForest's ``segmentID``, which also splits at forks, is not
        used); ``position_in_branch`` and ``extension`` are derived from the links.

    Raises
    ------
    InputFormatError
        The file is missing, not text, empty, ragged, has a non-numeric cell, or its
        header matches no known format.
    EmptyInputError
        The file has a header but no rows.
    ModelError
        A required column is missing or a row is invalid (see
        :meth:`CylinderTable.validate`); the message names the 1-based data row.
    """
    path = Path(path)
    if format is not None and format not in FORMATS:
        raise InvalidParameterError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    if format == "treeqsm-txt" or (format is None and _sniff_treeqsm_text(path)):
        return _read_treeqsm_text(path).validate(source=str(path))
    header, rows = _read_csv(path)
    detected = _detect_format(header)
    if format is None:
        if detected is None:
            raise InputFormatError(
                f"{path}: the header ({', '.join(header[:6])}, ...) matches no known "
                "cylinder table; expected TreeQSM (radius,length,start_x,...), SimpleForest "
                "(ID, parentID, startX, ...) or treesim's own CSV, or pass format="
            )
        format = detected
    cols = _Columns(path, header, rows)
    if format == "simpleforest":
        table = _read_simpleforest(cols)
    else:
        table = _read_treeqsm(cols, format)
    return table.validate(source=str(path))


def write_cylinders(path: str | Path, table: CylinderTable) -> Path:
    """Write a table as treesim's CSV (exact on reading back with :func:`read_cylinders`).

    Columns are :data:`TREESIM_COLUMNS`: TreeQSM's order with 1-based ``parent`` and
    ``extension`` (0 for none) and ``added`` as 0/1, then ``end_radius`` and ``tag``.
    Floats are written as the shortest decimal that reads back to the same float64.

    Parameters
    ----------
    path : str or Path
        Destination; its folder must exist.
    table : CylinderTable
        Validated before writing.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    table.validate()
    columns: list[list[Any]] = [
        table.radius_m.tolist(),
        table.length_m.tolist(),
        *(table.start[:, k].tolist() for k in range(3)),
        *(table.axis[:, k].tolist() for k in range(3)),
        (table.parent + 1).tolist(),
        (table.extension + 1).tolist(),
        table.added.astype(np.int64).tolist(),
        table.unmod_radius_m.tolist(),
        table.branch.tolist(),
        table.branch_order.tolist(),
        table.position_in_branch.tolist(),
        table.end_radius_m.tolist(),
        table.tag.tolist(),
    ]
    try:
        with path.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(TREESIM_COLUMNS)
            # str of a Python float is the shortest string that reads back to the same float.
            writer.writerows(zip(*[[str(v) for v in c] for c in columns], strict=True))
    except OSError as exc:
        raise InputFormatError(f"cannot write the cylinder table to {path}: {exc}") from exc
    return path
