"""Level of detail for cylinder meshes: no more facets than the scanner can resolve.

A virtual scanner with angular step ``Δ`` (radians) samples a surface at distance ``d``
with points about ``s = d Δ`` apart (further apart at oblique incidence). A cylinder of
radius ``r`` meshed as an inscribed regular ``n``-gon prism departs from its circle by at
most the sagitta ``h(n) = r (1 - cos(pi / n))``, halfway between two ring vertices.
:func:`lod_facets` gives each cylinder of a table the fewest facets whose sagitta is at
most a fraction ``tolerance`` of the point spacing at that cylinder::

    n = min{n in [min_facets, max_facets] : r (1 - cos(pi / n)) <= tolerance * d * Δ}

where ``r`` is the cylinder's larger end radius and ``d`` the distance from the NEAREST
station to its surface (a lower bound: the distance from the station to the axis segment
minus ``r``), so the spacing used is the finest any station gets on it. ``max_facets`` is
the user's ``facets``: level of detail only removes detail, it never adds any.

**Why half the spacing** (:data:`LOD_TOLERANCE`). The scan describes a surface by samples
``s`` apart, so where the surface lies between two samples is known to within half a cell
(the bound for rounding positions to a grid of step ``s``), and the measures made on the
cloud downstream (point-to-mesh distances, cylinders fitted to the re-scanned cloud) work
at that resolution. Capping the faceting error at ``s / 2`` keeps the model's own error
within that half cell. Where ``r`` is below about ``s``, the facets (chords about
``2 sqrt(r s)`` long at the limit) are shorter than two sample spacings, so the scan cannot
resolve them laterally either. The deviation is not invisible, though: the polygon is
inscribed, so it is one-sided (the mean radial offset of a chord is about two thirds of
its sagitta, so about ``s / 3`` at the limit: 2.3 mm at 10 m and 0.04 degrees), a
noise-free scanner samples it exactly, and a cylinder fitted to the scan comes out smaller
by about that offset; the mesh's volume is ``(n / 2 pi) sin(2 pi / n)`` of the cylinder's, as for
any facet count (:meth:`LodPlan.describe` reports the ratio to the uniform mesh's). Pass
a smaller ``tolerance`` where such biases matter.

**What holds.** Each cylinder's sagitta at its count is at most ``tolerance * s`` (by
construction; ``LodPlan.wanted`` shows where ``max_facets`` caps it instead). For separate
prisms every point of the level-of-detail mesh is then within that distance of the uniform
``max_facets`` mesh, and the other way round (the tests measure it, sampled, on whole
trees). Mitred tubes keep it on their sides and caps; where a joint steps the radius (as
TreeQSM tables do at nearly every joint) the two meshes' rings and annuli in the mitre
plane are polygons of different counts, and there the distance can exceed the bound by a
few percent (measured: up to 8 % over, on 0.001 % of the surface, for the coffee tree
from 1 m; none over from 3 m and 10 m, nor for procedural trees, whose joints keep the
radius).

**Why at least 8 facets** (:data:`LOD_MIN_FACETS`). Procedural trees put every child's
base disc inside the parent's inscribed polygon at
:data:`~treesim.models.builder.MIN_JUNCTION_FACETS` (8) facets, so their junctions
stay closed at any level of detail; an octagon also keeps 90 % of the disc's area and its
width stays within 92.4 % (cos 22.5 degrees) of the diameter, where a triangle keeps 41 %
and 75 %: thin twigs still occlude about as much as the cylinders they stand for.

Meshing (:func:`~treesim.models.mesh.cylinders_to_mesh`): separate prisms take each row's
count; mitred tubes take the largest count of their rows, so a tube is never coarser than
any of its cylinders asked for (see :mod:`treesim.models.mesh`). Usage::

    facets = lod_facets(table, stations_xyz, spacing_rad=math.radians(min(h_res, v_res)),
                        max_facets=params.facets)
    vertices, faces = cylinders_to_mesh(table, facets=facets, joints=joints)

and, for the run's report, ``plan_lod(...).describe(joints=joints)``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from .builder import MIN_JUNCTION_FACETS
from .cylinders import CylinderTable, _check_facets
from .mesh import (
    MAX_JOINT_GAP_RATIO,
    MAX_MITER_BEND_DEG,
    mesh_triangle_count,
    meshed_facets,
)

__all__ = [
    "LOD_MIN_FACETS",
    "LOD_TOLERANCE",
    "LodPlan",
    "facets_for_sagitta",
    "lod_facets",
    "nearest_station_distance_m",
    "plan_lod",
    "sagitta_m",
]

#: Default largest sagitta, as a fraction of the point spacing at the cylinder (see the
#: module notes: half a sample cell).
LOD_TOLERANCE: float = 0.5

#: Default fewest facets per cylinder: procedural junctions stay closed (see the notes).
LOD_MIN_FACETS: int = MIN_JUNCTION_FACETS

#: Cylinders whose station distances are computed at a time (bounds the temporaries).
_DISTANCE_BLOCK = 8192


def sagitta_m(radius_m: np.ndarray | float, facets: np.ndarray | int) -> np.ndarray:
    """Largest distance from a circle to its inscribed regular polygon, m.

    ``r (1 - cos(pi / n))``, computed as ``2 r sin^2(pi / 2n)`` (no cancellation at large
    ``n``).

    Parameters
    ----------
    radius_m : float or (n,) float
        Circle radii, m.
    facets : int or (n,) int
        Polygon sides.

    Returns
    -------
    (n,) float64 (or a 0-d array for scalars)
    """
    r = np.asarray(radius_m, dtype=np.float64)
    n = np.asarray(facets, dtype=np.float64)
    return 2.0 * r * np.sin(np.pi / (2.0 * n)) ** 2


def facets_for_sagitta(
    radius_m: np.ndarray,
    max_sagitta_m: np.ndarray,
    *,
    max_facets: int,
    min_facets: int = LOD_MIN_FACETS,
) -> np.ndarray:
    """(n,) int64: the fewest facets in ``[min_facets, max_facets]`` with sagitta <= a limit.

    Parameters
    ----------
    radius_m : (n,) float
        Circle radii, m, > 0.
    max_sagitta_m : (n,) float
        Largest allowed sagitta per circle, m, >= 0 (0 asks for ``max_facets``).
    max_facets : int
        Most facets (>= 3); returned where even that many leave a larger sagitta.
    min_facets : int
        Fewest facets (>= 3); above ``max_facets`` it is lowered to ``max_facets``.

    Returns
    -------
    (n,) int64
        ``clip(n*, min(min_facets, max_facets), max_facets)`` with ``n*`` the smallest
        ``n >= 3`` for which ``sagitta_m(r, n) <= max_sagitta_m``.
    """
    hi = _check_facets(max_facets)
    lo = min(_check_facets(min_facets), hi)
    return np.clip(_wanted_facets(radius_m, max_sagitta_m, hi), lo, hi)


def _wanted_facets(radius_m: np.ndarray, limit_m: np.ndarray, cap: int) -> np.ndarray:
    """(n,) int64: the smallest n >= 3 with sagitta <= limit, or ``cap + 1`` if above cap."""
    r = np.asarray(radius_m, dtype=np.float64)
    limit = np.asarray(limit_m, dtype=np.float64)
    # sin(pi / 2n) <= sqrt(limit / 2r)  <=>  n >= pi / (2 asin(sqrt(limit / 2r))).
    half = np.sqrt(np.clip(limit / (2.0 * r), 0.0, 1.0))
    angle = np.arcsin(half)
    with np.errstate(divide="ignore"):
        real = np.pi / (2.0 * angle)
    n = np.ceil(np.minimum(real, cap + 1.0)).astype(np.int64)
    n = np.maximum(n, 3)
    # The closed form is exact up to rounding: settle the boundary cases on the sagitta.
    down = (n > 3) & (n <= cap + 1) & (sagitta_m(r, n - 1) <= limit)
    n[down] -= 1
    up = (n <= cap) & (sagitta_m(r, n) > limit)
    n[up] += 1
    return n


def nearest_station_distance_m(
    table: CylinderTable, station_positions_m: np.ndarray | Sequence[Sequence[float]]
) -> np.ndarray:
    """(n,) float64: distance from the nearest station to each cylinder's surface, m.

    A lower bound: the distance from the station to the cylinder's axis segment minus its
    larger end radius (exact for the side of a cylinder that faces the station), 0 where
    a station stands inside a cylinder's bounding radius.

    Parameters
    ----------
    table : CylinderTable
        Validated first.
    station_positions_m : (k, 3) float
        Scanner positions in the table's coordinates (e.g. ``[s.position_m for s in
        stations]``), k >= 1; a single (3,) position is accepted.
    """
    table.validate()
    stations = np.asarray(station_positions_m, dtype=np.float64)
    if stations.ndim == 1:
        stations = stations[None, :]
    if stations.ndim != 2 or stations.shape[1] != 3 or len(stations) == 0:
        raise InvalidParameterError(
            f"station positions must be a (k, 3) array with k >= 1, got shape {stations.shape}"
        )
    if not np.isfinite(stations).all():
        raise InvalidParameterError("station positions must be finite")
    # Relative to the table's first start, so that georeferenced coordinates stay exact.
    origin = table.start[0]
    start = table.start - origin
    axis = table.unit_axis
    length = table.length_m
    radius = np.maximum(table.radius_m, table.end_radius_m)
    stations = stations - origin
    out = np.empty(table.n_cylinders)
    for lo in range(0, table.n_cylinders, _DISTANCE_BLOCK):
        hi = min(lo + _DISTANCE_BLOCK, table.n_cylinders)
        rel = stations[None, :, :] - start[lo:hi, None, :]  # (m, k, 3)
        t = np.clip(np.einsum("mkj,mj->mk", rel, axis[lo:hi]), 0.0, length[lo:hi, None])
        foot = rel - t[:, :, None] * axis[lo:hi, None, :]
        out[lo:hi] = np.linalg.norm(foot, axis=2).min(axis=1)
    return np.maximum(out - radius, 0.0)


@dataclass(frozen=True, eq=False)
class LodPlan:
    """Facets per cylinder chosen by :func:`plan_lod`, and what they were chosen from.

    Attributes
    ----------
    table : CylinderTable
        The table planned for.
    facets : (n,) int64
        Facets per row, to pass as ``cylinders_to_mesh(table, facets=...)``.
    wanted : (n,) int64
        The rule's count before clipping to ``[min_facets, max_facets]`` (``max_facets +
        1`` where it wants more than ``max_facets``).
    distance_m : (n,) float64
        Distance from the nearest station to each cylinder's surface, m.
    spacing_m : (n,) float64
        Point spacing there, ``distance_m * spacing_rad``, m.
    spacing_rad : float
        The scanner's angular step, radians.
    tolerance : float
        Largest sagitta as a fraction of ``spacing_m``.
    min_facets, max_facets : int
        The bounds (``min_facets`` as given; the effective floor is the smaller of both).
    n_stations : int
        Stations the distances were measured from.
    """

    table: CylinderTable
    facets: np.ndarray
    wanted: np.ndarray
    distance_m: np.ndarray
    spacing_m: np.ndarray
    spacing_rad: float
    tolerance: float
    min_facets: int
    max_facets: int
    n_stations: int

    @property
    def rule(self) -> str:
        """The rule in words."""
        return (
            f"per cylinder, the fewest facets n in [{min(self.min_facets, self.max_facets)}, "
            f"{self.max_facets}] with sagitta r (1 - cos(pi / n)) <= {self.tolerance:g} x the "
            f"point spacing d x {self.spacing_rad:.6g} rad (r: the larger end radius; d: "
            "distance from the nearest station to the cylinder)"
        )

    def describe(
        self,
        *,
        joints: str = "separate",
        max_bend_deg: float = MAX_MITER_BEND_DEG,
        max_gap_ratio: float = MAX_JOINT_GAP_RATIO,
    ) -> dict[str, Any]:
        """A JSON-ready summary: the rule, the facets chosen and what they save.

        Parameters
        ----------
        joints : {"separate", "miter"}
            How the table will be meshed (tubes take the largest count of their rows).
        max_bend_deg, max_gap_ratio : float
            As for :func:`~treesim.models.mesh.tubes_to_mesh`.

        Returns
        -------
        dict
            ``rule`` (in words), ``tolerance``, ``spacing_rad``, ``spacing_deg``,
            ``min_facets``, ``max_facets``, ``n_stations``, ``joints``;
            ``distance_m`` and ``spacing_m`` (``min``, ``median``, ``max`` over rows);
            ``facets_histogram`` (rows per chosen count, keys as strings),
            ``meshed_facets_histogram`` (rows per count as meshed: tubes raise rows to
            their largest count), ``n_capped`` (rows whose rule asked for more than
            ``max_facets``); ``n_triangles``, ``n_triangles_uniform`` (at ``max_facets``),
            ``triangles_saved``, ``triangles_saved_fraction``;
            ``max_sagitta_over_spacing`` (largest sagitta as meshed over the spacing: at
            most ``tolerance`` unless rows are capped) and ``prism_volume_ratio`` (the
            mesh's inscribed-prism volume over the uniform mesh's).
        """
        table = self.table
        kw = {"joints": joints, "max_bend_deg": max_bend_deg, "max_gap_ratio": max_gap_ratio}
        row_f = meshed_facets(table, facets=self.facets, **kw)
        lod_tris = mesh_triangle_count(table, facets=self.facets, **kw)
        uniform_tris = mesh_triangle_count(table, facets=self.max_facets, **kw)
        radius = np.maximum(table.radius_m, table.end_radius_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = sagitta_m(radius, row_f) / self.spacing_m
        ratio = np.where(self.spacing_m > 0, ratio, np.inf)
        volume = float(table.prism_volume_m3(row_f).sum())
        uniform_volume = float(table.prism_volume_m3(self.max_facets).sum())

        def spread(x: np.ndarray) -> dict[str, float]:
            return {
                "min": float(x.min()),
                "median": float(np.median(x)),
                "max": float(x.max()),
            }

        def histogram(f: np.ndarray) -> dict[str, int]:
            values, counts = np.unique(f, return_counts=True)
            return {str(int(v)): int(c) for v, c in zip(values, counts, strict=True)}

        worst = float(ratio.max())
        return {
            "rule": self.rule,
            "tolerance": self.tolerance,
            "spacing_rad": self.spacing_rad,
            "spacing_deg": math.degrees(self.spacing_rad),
            "min_facets": self.min_facets,
            "max_facets": self.max_facets,
            "n_stations": self.n_stations,
            "joints": joints,
            "distance_m": spread(self.distance_m),
            "spacing_m": spread(self.spacing_m),
            "facets_histogram": histogram(self.facets),
            "meshed_facets_histogram": histogram(row_f),
            "n_capped": int((self.wanted > self.max_facets).sum()),
            "n_triangles": lod_tris,
            "n_triangles_uniform": uniform_tris,
            "triangles_saved": uniform_tris - lod_tris,
            "triangles_saved_fraction": (uniform_tris - lod_tris) / uniform_tris,
            "max_sagitta_over_spacing": worst if math.isfinite(worst) else None,
            "prism_volume_ratio": volume / uniform_volume,
        }


def _number(value: object) -> float | None:
    """``value`` as a finite float, or None (bools, strings and non-numbers too)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    x = float(value)
    return x if math.isfinite(x) else None


def plan_lod(
    table: CylinderTable,
    station_positions_m: np.ndarray | Sequence[Sequence[float]],
    spacing_rad: float,
    *,
    max_facets: int,
    min_facets: int = LOD_MIN_FACETS,
    tolerance: float = LOD_TOLERANCE,
) -> LodPlan:
    """Choose facets per cylinder from the point spacing at the nearest station.

    The rule is in the module notes; :func:`lod_facets` returns only the counts.

    Parameters
    ----------
    table : CylinderTable
        Validated first.
    station_positions_m : (k, 3) float
        Scanner positions in the table's coordinates, m (k >= 1).
    spacing_rad : float
        The scanner's angular step, radians, > 0: the finer of the horizontal and
        vertical steps, ``math.radians(min(h_res_deg, v_res_deg))``.
    max_facets : int
        The user's facet count (>= 3): no cylinder gets more.
    min_facets : int
        Fewest facets per cylinder (>= 3, default :data:`LOD_MIN_FACETS`); lowered to
        ``max_facets`` if above it.
    tolerance : float
        Largest sagitta as a fraction of the point spacing, > 0 (default
        :data:`LOD_TOLERANCE`, half the spacing).

    Returns
    -------
    LodPlan
    """
    hi = _check_facets(max_facets)
    lo = _check_facets(min_facets)
    step = _number(spacing_rad)
    if not (step is not None and 0.0 < step < math.pi):
        raise InvalidParameterError(
            f"spacing_rad must be an angle in (0, pi) radians, got {spacing_rad!r}"
        )
    tol = _number(tolerance)
    if not (tol is not None and tol > 0.0):
        raise InvalidParameterError(f"tolerance must be a number > 0, got {tolerance!r}")
    distance = nearest_station_distance_m(table, station_positions_m)
    spacing = distance * step
    radius = np.maximum(table.radius_m, table.end_radius_m)
    wanted = _wanted_facets(radius, tol * spacing, hi)
    return LodPlan(
        table=table,
        facets=np.clip(wanted, min(lo, hi), hi),
        wanted=wanted,
        distance_m=distance,
        spacing_m=spacing,
        spacing_rad=step,
        tolerance=tol,
        min_facets=lo,
        max_facets=hi,
        n_stations=int(np.asarray(station_positions_m, dtype=np.float64).reshape(-1, 3).shape[0]),
    )


def lod_facets(
    table: CylinderTable,
    station_positions_m: np.ndarray | Sequence[Sequence[float]],
    spacing_rad: float,
    *,
    max_facets: int,
    min_facets: int = LOD_MIN_FACETS,
    tolerance: float = LOD_TOLERANCE,
) -> np.ndarray:
    """(n,) int64: facets per cylinder for a scan from ``station_positions_m``.

    The fewest facets ``n`` in ``[min(min_facets, max_facets), max_facets]`` whose
    sagitta ``r (1 - cos(pi / n))`` is at most ``tolerance`` times the point spacing
    ``d * spacing_rad`` at the cylinder (``r`` its larger end radius, ``d`` the distance
    from the nearest station to its surface); see the module notes for why.
    Parameters as for :func:`plan_lod` (which also keeps the distances and describes the
    choice). Pass the result as ``cylinders_to_mesh(table, facets=...)``.
    """
    return plan_lod(
        table,
        station_positions_m,
        spacing_rad,
        max_facets=max_facets,
        min_facets=min_facets,
        tolerance=tolerance,
    ).facets
