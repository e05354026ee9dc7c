"""Procedural trees after Weber & Penn (1995): exact cylinder tables and labelled meshes.

Weber & Penn ("Creation and rendering of realistic trees", SIGGRAPH 1995) describe a
tree by a handful of global parameters and a set per branching level: the trunk, then
recursive levels of stems with their number, length, down angle and rotation, curvature,
taper and splitting, and leaves on the last level. The same model is behind Arbaro and
Blender's Sapling add-on. :func:`generate_tree` implements it for measurement rather
than rendering:

* The wood is built as a :class:`~treesim.models.cylinders.CylinderTable` of frusta
  (one row per stem segment, ``end_radius_m`` for the taper, parent links, ``branch``
  per stem, ``branch_order`` by topology as QSM tools count it) and that table **is**
  the truth: DBH, height, stem and branch volume and branches per order are its figures,
  and the mesh is made from it (:meth:`ProceduralTree.wood_mesh`, one mitred tube per
  stem, see :func:`~treesim.models.mesh.tubes_to_mesh`).
* Every stem starts inside its parent: its base disc lies inside the parent's tube (for
  meshes of at least :data:`MIN_JUNCTION_FACETS` facets), so junctions have no cracks.
  This bounds a child's radius by :data:`CHILD_RADIUS_LIMIT` times the parent's.
* Leaves are flat polygons (2-4 triangles each) held off their stem by a petiole gap, so
  no leaf touches the stem it grows on.
* Deterministic: everything is drawn from ``numpy.random.default_rng(seed)`` in a fixed
  order; the leaves from a second stream spawned from it, so a tree with and without
  leaves has the same wood.

Differences from the paper, on purpose: stems taper linearly to a tip radius
(``tip_radius_m``) instead of to a point; a split's clone gets ``split_radius_ratio`` of
the stem's radius (so it fits inside) and counts as a branch one order up (as TreeQSM
counts forks); lobes, pruning and the exact curve-back and attraction formulas are
simplified; the trunk's base is subdivided where the flare changes the radius fastest.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from ..cloud import LABEL_CODES
from ..errors import InvalidParameterError
from .cylinders import CylinderTable
from .mesh import TubeMesh, mesh_volume, tubes_to_mesh

#: Crown shape envelopes of Weber & Penn (their ``Shape`` 0-7), by name.
SHAPES: tuple[str, ...] = (
    "conical",
    "spherical",
    "hemispherical",
    "cylindrical",
    "tapered_cylindrical",
    "flame",
    "inverse_conical",
    "tend_flame",
)

#: Leaf outlines: points (along the leaf from 0 at the stalk to 1 at the tip, across
#: from -0.5 to 0.5 of the width) and their fan triangulation.
LEAF_SHAPES: dict[str, tuple[tuple[tuple[float, float], ...], tuple[tuple[int, int, int], ...]]] = {
    "diamond": (((0.0, 0.0), (0.5, -0.5), (1.0, 0.0), (0.5, 0.5)), ((0, 1, 2), (0, 2, 3))),
    "ovate": (
        ((0.0, 0.0), (0.25, -0.42), (0.6, -0.5), (1.0, 0.0), (0.6, 0.5), (0.25, 0.42)),
        ((0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)),
    ),
    "rectangle": (((0.0, -0.5), (1.0, -0.5), (1.0, 0.5), (0.0, 0.5)), ((0, 1, 2), (0, 2, 3))),
}

#: A child stem's base radius is at most this fraction of the smaller end radius of the
#: parent cylinder it starts on, so that its base disc fits inside the parent.
CHILD_RADIUS_LIMIT: float = 0.85

#: Junctions are crack-free in meshes with at least this many facets per ring (a child's
#: base disc lies inside the parent's inscribed polygon, radius r cos(pi / facets)).
MIN_JUNCTION_FACETS: int = 8

#: Sub-segments of the trunk's lowest eighth, where the flare changes the radius fastest.
_FLARE_SUBSEGMENTS = 4

_UP = np.array([0.0, 0.0, 1.0])


def shape_ratio(shape: str, ratio: float) -> float:
    """Weber & Penn's crown envelope: relative length of a branch at relative position.

    Parameters
    ----------
    shape : str
        One of :data:`SHAPES`.
    ratio : float
        Position in [0, 1]: 0 at the top of the crown, 1 at its base.

    Returns
    -------
    float
        Relative length in [0, 1] (0.2 - 1 for most shapes).
    """
    r = min(max(float(ratio), 0.0), 1.0)
    if shape == "conical":
        return 0.2 + 0.8 * r
    if shape == "spherical":
        return 0.2 + 0.8 * math.sin(math.pi * r)
    if shape == "hemispherical":
        return 0.2 + 0.8 * math.sin(0.5 * math.pi * r)
    if shape == "cylindrical":
        return 1.0
    if shape == "tapered_cylindrical":
        return 0.5 + 0.5 * r
    if shape == "flame":
        return r / 0.7 if r <= 0.7 else (1.0 - r) / 0.3
    if shape == "inverse_conical":
        return 1.0 - 0.8 * r
    if shape == "tend_flame":
        return 0.5 + 0.5 * r / 0.7 if r <= 0.7 else 0.5 + 0.5 * (1.0 - r) / 0.3
    raise InvalidParameterError(f"shape must be one of {', '.join(SHAPES)}, got {shape!r}")


def _check(
    name: str, value: float, lo: float, hi: float = math.inf, *, open_lo: bool = False
) -> None:
    ok = math.isfinite(value) and (value > lo if open_lo else value >= lo) and value <= hi
    if not ok:
        low = f"> {lo:g}" if open_lo else f">= {lo:g}"
        rng = low if hi == math.inf else f"{low} and <= {hi:g}"
        raise InvalidParameterError(f"{name} must be a number {rng}, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class StemLevel:
    """Parameters of one branching level (Weber & Penn's ``n``-prefixed parameters).

    Level 0 is the trunk (of its parameters only the curvature, ``segments``, splitting
    and ``taper`` are used); level 1 stems grow on the trunk, level 2 on level 1, ...

    Parameters
    ----------
    branches : int
        ``nBranches``: children a parent of the previous level carries (the trunk carries
        exactly this many level-1 stems; deeper parents fewer, by W&P's rules).
    length_ratio : float
        ``nLength``: length relative to the parent (level 1: times the crown envelope).
    length_ratio_var : float
        ``nLengthV``: uniform +- variation of ``length_ratio``.
    down_angle_deg : float
        ``nDownAngle``: angle between the parent's axis and the child, degrees.
    down_angle_var_deg : float
        ``nDownAngleV``: uniform +- variation; negative values make the angle vary with
        the position along the parent instead (steeper at the top), as in W&P.
    rotate_deg : float
        ``nRotate``: azimuth step between successive children around the parent (137.5
        is the golden angle); negative values alternate sides, W&P's opposite branching.
    rotate_var_deg : float
        ``nRotateV``: uniform +- variation of the step.
    segments : int
        ``nCurveRes``: straight segments (cylinder rows) per stem, >= 1.
    curve_deg : float
        ``nCurve``: total bend along the stem; negative bends toward the parent's
        direction (upward for branches of an upright trunk).
    curve_back_deg : float
        ``nCurveBack``: with a value other than 0, the first half bends by ``curve_deg``
        and the second half by this (S-shaped stems).
    curve_var_deg : float
        ``nCurveV``: random bend per stem (spread over its segments, in random planes).
    seg_splits : float
        ``nSegSplits``: clones per segment joint (fractions accumulate, W&P's error
        diffusion); each clone forks off at ``split_angle_deg``.
    split_angle_deg, split_angle_var_deg : float
        ``nSplitAngle`` and its variation: angle between a clone and its stem.
    taper : float
        ``nTaper`` in [0, 1]: 0 a cylinder, 1 a cone down to the tip radius.
    """

    branches: int = 0
    length_ratio: float = 1.0
    length_ratio_var: float = 0.0
    down_angle_deg: float = 0.0
    down_angle_var_deg: float = 0.0
    rotate_deg: float = 137.5
    rotate_var_deg: float = 0.0
    segments: int = 5
    curve_deg: float = 0.0
    curve_back_deg: float = 0.0
    curve_var_deg: float = 0.0
    seg_splits: float = 0.0
    split_angle_deg: float = 0.0
    split_angle_var_deg: float = 0.0
    taper: float = 1.0

    def __post_init__(self) -> None:
        if isinstance(self.branches, bool) or int(self.branches) != self.branches:
            raise InvalidParameterError(f"branches must be an integer, got {self.branches!r}")
        _check("branches", self.branches, 0)
        if isinstance(self.segments, bool) or int(self.segments) != self.segments:
            raise InvalidParameterError(f"segments must be an integer, got {self.segments!r}")
        _check("segments", self.segments, 1, 1000)
        _check("length_ratio", self.length_ratio, 0.0, 10.0, open_lo=True)
        _check("length_ratio_var", self.length_ratio_var, 0.0, 10.0)
        for name in ("down_angle_deg", "rotate_deg", "curve_deg", "curve_back_deg"):
            _check(name, getattr(self, name), -360.0, 360.0)
        _check("down_angle_var_deg", self.down_angle_var_deg, -180.0, 180.0)
        for name in ("rotate_var_deg", "curve_var_deg", "split_angle_var_deg"):
            _check(name, getattr(self, name), 0.0, 360.0)
        _check("seg_splits", self.seg_splits, 0.0, 2.0)
        _check("split_angle_deg", self.split_angle_deg, 0.0, 90.0)
        _check("taper", self.taper, 0.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class LeafParams:
    """Leaves: flat polygons on the stems of the last level.

    Parameters
    ----------
    leaves_per_stem : int
        W&P's ``Leaves``: leaves on a stem of the last level (fewer on stems near their
        parent's base, by W&P's tapered-cylinder rule).
    length_m : float
        W&P's ``LeafScale``: leaf blade length, metres, > 0.
    width_ratio : float
        W&P's ``LeafScaleX``: blade width over length, > 0.
    size_var : float
        Uniform +- relative variation of the size, in [0, 0.9].
    shape : {"ovate", "diamond", "rectangle"}
        Outline (4, 2 and 2 triangles); ``rectangle`` suits conifer shoots.
    down_angle_deg, down_angle_var_deg : float
        Angle between the stem and the leaf's midrib, and its +- variation; in [10, 170]
        together, so that the leaf points away from its stem.
    rotate_deg : float
        Azimuth step between successive leaves around the stem.
    bend : float
        W&P's ``LeafBend`` in [0, 1]: how far each blade turns about its midrib to face
        up (toward the light).
    petiole_m : float
        Gap between the stem's surface and the blade's base, metres, > 0 (the leaf stalk,
        not modelled): blades never touch the wood.
    """

    leaves_per_stem: int = 20
    length_m: float = 0.07
    width_ratio: float = 0.8
    size_var: float = 0.15
    shape: str = "ovate"
    down_angle_deg: float = 50.0
    down_angle_var_deg: float = 15.0
    rotate_deg: float = 137.5
    bend: float = 0.5
    petiole_m: float = 0.01

    def __post_init__(self) -> None:
        if isinstance(self.leaves_per_stem, bool) or int(self.leaves_per_stem) != (
            self.leaves_per_stem
        ):
            raise InvalidParameterError(
                f"leaves_per_stem must be an integer, got {self.leaves_per_stem!r}"
            )
        _check("leaves_per_stem", self.leaves_per_stem, 0, 10_000)
        _check("length_m", self.length_m, 0.0, 5.0, open_lo=True)
        _check("width_ratio", self.width_ratio, 0.0, 10.0, open_lo=True)
        _check("size_var", self.size_var, 0.0, 0.9)
        if self.shape not in LEAF_SHAPES:
            raise InvalidParameterError(
                f"leaf shape must be one of {', '.join(LEAF_SHAPES)}, got {self.shape!r}"
            )
        _check("down_angle_var_deg", self.down_angle_var_deg, 0.0, 80.0)
        lo = self.down_angle_deg - self.down_angle_var_deg
        hi = self.down_angle_deg + self.down_angle_var_deg
        if not (math.isfinite(lo) and math.isfinite(hi) and lo >= 10.0 and hi <= 170.0):
            raise InvalidParameterError(
                "leaf down_angle_deg +- down_angle_var_deg must stay within [10, 170] degrees "
                f"so that leaves point away from their stem, got {self.down_angle_deg!r} +- "
                f"{self.down_angle_var_deg!r}"
            )
        _check("rotate_deg", self.rotate_deg, -360.0, 360.0)
        _check("bend", self.bend, 0.0, 1.0)
        _check("petiole_m", self.petiole_m, 0.0, 1.0, open_lo=True)


@dataclass(frozen=True, kw_only=True)
class TreeParams:
    """A species: Weber & Penn's global parameters, the levels and the leaves.

    Parameters
    ----------
    name : str
        Preset name (what ``--species`` takes).
    description : str
        One line: what the tree is, with its typical size.
    source : str
        Where the parameters come from, and what was changed.
    levels : tuple of StemLevel
        ``levels[0]`` the trunk, then one entry per branching level.
    shape : str
        W&P's ``Shape``, one of :data:`SHAPES`: the crown envelope of level-1 lengths.
    trunk_length_m : float
        W&P's ``Scale`` (times ``0Length``): length of the trunk, metres, > 0. Branches
        curving up may reach higher: the tree's height is the table's.
    trunk_length_var_m : float
        W&P's ``ScaleV``: uniform +- variation of the trunk length, <= 0.9 times it.
    radius_ratio : float
        W&P's ``Ratio``: trunk base radius over trunk length (before the flare).
    ratio_power : float
        W&P's ``RatioPower``: a child's radius is its parent's times (length ratio) to
        this power.
    flare : float
        W&P's ``Flare``: extra radius at the trunk's base (1 doubles it), fading out over
        the lowest eighth of the trunk.
    base_size : float
        W&P's ``BaseSize``: fraction of the trunk without branches, in [0, 1).
    attraction_up : float
        W&P's ``AttractionUp``: how strongly stems of level 2 and deeper turn upward.
    tip_radius_m : float
        Radius stems taper to at their tips (if thinner at their base, they stay
        cylinders), metres, > 0.
    split_radius_ratio : float
        A clone's radius relative to its stem's at the split, in (0, CHILD_RADIUS_LIMIT].
    leaves : LeafParams or None
        Leaves on the stems of the last level; None for a leafless species.
    leaves_on : bool
        Whether :func:`generate_tree` adds the leaves by default.
    """

    name: str
    description: str
    source: str
    levels: tuple[StemLevel, ...]
    shape: str = "conical"
    trunk_length_m: float = 10.0
    trunk_length_var_m: float = 0.0
    radius_ratio: float = 0.015
    ratio_power: float = 1.2
    flare: float = 0.5
    base_size: float = 0.3
    attraction_up: float = 0.0
    tip_radius_m: float = 0.002
    split_radius_ratio: float = 0.8
    leaves: LeafParams | None = None
    leaves_on: bool = False

    def __post_init__(self) -> None:
        if not self.levels:
            raise InvalidParameterError("levels must hold at least the trunk (levels[0])")
        object.__setattr__(self, "levels", tuple(self.levels))
        for lev in self.levels:
            if not isinstance(lev, StemLevel):
                raise InvalidParameterError(f"levels must be StemLevel objects, got {lev!r}")
        if self.shape not in SHAPES:
            raise InvalidParameterError(
                f"shape must be one of {', '.join(SHAPES)}, got {self.shape!r}"
            )
        _check("trunk_length_m", self.trunk_length_m, 0.0, 200.0, open_lo=True)
        _check("trunk_length_var_m", self.trunk_length_var_m, 0.0, 0.9 * self.trunk_length_m)
        _check("radius_ratio", self.radius_ratio, 0.0, 0.2, open_lo=True)
        _check("ratio_power", self.ratio_power, 0.0, 5.0)
        _check("flare", self.flare, 0.0, 3.0)
        _check("base_size", self.base_size, 0.0, 0.95)
        _check("attraction_up", self.attraction_up, -5.0, 5.0)
        _check("tip_radius_m", self.tip_radius_m, 0.0, 1.0, open_lo=True)
        _check("split_radius_ratio", self.split_radius_ratio, 0.0, CHILD_RADIUS_LIMIT, open_lo=True)
        if self.leaves is not None and not isinstance(self.leaves, LeafParams):
            raise InvalidParameterError(f"leaves must be LeafParams or None, got {self.leaves!r}")
        if self.leaves_on and self.leaves is None:
            raise InvalidParameterError(f"{self.name}: leaves_on needs leaf parameters")

    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data (JSON-ready)."""
        return asdict(self)


# ---------------------------------------------------------------------- vector helpers


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotate ``v`` about the unit ``axis`` by ``angle`` radians (Rodrigues)."""
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * (float(axis @ v) * (1.0 - c))


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to the unit ``d``."""
    world = np.zeros(3)
    world[int(np.argmin(np.abs(d)))] = 1.0
    return _unit(np.cross(d, world))


def _tilt_toward(d: np.ndarray, target: np.ndarray, angle: float) -> np.ndarray:
    """Turn the unit ``d`` toward the unit ``target`` by ``angle`` (never past it)."""
    axis = np.cross(d, target)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return d
    between = math.atan2(s, float(d @ target))
    return _unit(_rotate(d, axis / s, min(angle, between)))


# ---------------------------------------------------------------------- the tree


@dataclass(frozen=True, eq=False)
class ProceduralTree:
    """A generated tree: its exact cylinder table (the truth) and its leaves.

    Attributes
    ----------
    params : TreeParams
        The species it was generated from.
    seed : int
        The seed of ``numpy.random.default_rng``.
    cylinders : CylinderTable
        The wood: frusta with parent links, one ``branch`` per stem, tag ``modelled``.
    leaf_vertices : (m, 3) float64
        Leaf polygon corners, metres (empty without leaves).
    leaf_faces : (k, 3) int64
        Leaf triangles, indices into ``leaf_vertices``.
    n_leaves : int
        Number of leaves.
    """

    params: TreeParams
    seed: int
    cylinders: CylinderTable
    leaf_vertices: np.ndarray
    leaf_faces: np.ndarray
    n_leaves: int
    _wood: dict[int, TubeMesh] = field(default_factory=dict, repr=False)

    @property
    def name(self) -> str:
        """The species' name."""
        return self.params.name

    @property
    def has_leaves(self) -> bool:
        """Whether the tree has leaves."""
        return self.n_leaves > 0

    @property
    def leaf_area_m2(self) -> float:
        """One-sided area of all leaves, m^2."""
        if len(self.leaf_faces) == 0:
            return 0.0
        t = self.leaf_vertices[self.leaf_faces]
        return 0.5 * float(
            np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
        )

    def wood_mesh(self, facets: int = 32) -> TubeMesh:
        """The wood as one closed, mitred tube per stem (cached per facet count).

        Parameters
        ----------
        facets : int
            Vertices per ring, >= 3; junctions are crack-free from
            :data:`MIN_JUNCTION_FACETS` on.
        """
        if facets not in self._wood:
            self._wood[facets] = tubes_to_mesh(self.cylinders, facets=facets)
        return self._wood[facets]

    def mesh(self, facets: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Wood and leaves as one labelled triangle mesh.

        Returns
        -------
        vertices : (v, 3) float64
            Wood vertices first, then leaf vertices.
        faces : (f, 3) int64
            Wood triangles first, then leaf triangles.
        face_label : (f,) uint8
            ``LABEL_CODES["wood"]`` or ``LABEL_CODES["leaf"]`` per triangle (for
            :func:`treesim.io.mesh.write_mesh`).
        """
        wood = self.wood_mesh(facets)
        vertices = np.concatenate([wood.vertices, self.leaf_vertices])
        faces = np.concatenate([wood.faces, self.leaf_faces + len(wood.vertices)])
        label = np.concatenate(
            [
                np.full(len(wood.faces), LABEL_CODES["wood"], dtype=np.uint8),
                np.full(len(self.leaf_faces), LABEL_CODES["leaf"], dtype=np.uint8),
            ]
        )
        return vertices, faces, label

    def truth(self, facets: int = 32) -> dict[str, Any]:
        """The reference figures of the tree, for scoring reconstructions against it.

        Returns
        -------
        dict
            The table's :meth:`~CylinderTable.summary` (``dbh_m``, ``height_m``,
            ``volume_total_m3``, ``volume_stem_m3``, ``volume_branch_m3``,
            ``n_cylinders``, ``branches_per_order``), then ``species``, ``seed``,
            ``leaves``, ``n_leaves``, ``leaf_area_m2``, ``facets``, ``n_tubes``,
            ``n_triangles_wood``, ``n_triangles_leaf``, ``n_triangles``,
            ``mesh_volume_wood_m3`` (the wood mesh's enclosed volume),
            ``mesh_volume_error`` (its relative difference from ``volume_total_m3``),
            ``prism_factor`` (the part of that difference the polygon explains) and
            ``params`` (the species' parameters).
        """
        wood = self.wood_mesh(facets)
        summary = self.cylinders.summary()
        volume = mesh_volume(wood.vertices, wood.faces)
        return {
            **summary,
            "species": self.params.name,
            "description": self.params.description,
            "seed": self.seed,
            "leaves": self.has_leaves,
            "n_leaves": self.n_leaves,
            "leaf_area_m2": self.leaf_area_m2,
            "facets": facets,
            "n_tubes": wood.n_tubes,
            "n_triangles_wood": wood.n_triangles,
            "n_triangles_leaf": int(len(self.leaf_faces)),
            "n_triangles": wood.n_triangles + int(len(self.leaf_faces)),
            "mesh_volume_wood_m3": volume,
            "mesh_volume_error": volume / summary["volume_total_m3"] - 1.0,
            "prism_factor": facets * math.sin(2.0 * math.pi / facets) / (2.0 * math.pi),
            "params": self.params.to_dict(),
        }


@dataclass
class _Stem:
    """A stem waiting to be grown."""

    level: int  # index into params.levels
    order: int  # branch order in the table (topological)
    start: np.ndarray
    direction: np.ndarray
    right: np.ndarray  # unit, perpendicular to direction: the plane of the systematic curve
    length: float
    radius: Callable[[float], float]  # radius at a fraction of the stem's length
    parent_row: int  # -1 for the trunk
    parent_length: float  # length of the parent stem (0 for the trunk)
    offset: float  # where on the parent it starts, metres from the parent's base
    split_error: float = 0.0
    segments: int = 0  # W&P segments; 0: the level's (a clone gets its stem's remaining ones)


@dataclass
class _Grown:
    """A grown stem's centre line, for placing its children and leaves."""

    stem: _Stem
    nodes: np.ndarray  # (m + 1, 3)
    radii: np.ndarray  # (m + 1,)
    arc: np.ndarray  # (m + 1,) cumulative length
    rows: np.ndarray  # (m,) table rows
    right: np.ndarray  # its curve plane's normal at the base


class _Builder:
    def __init__(self, params: TreeParams, rng: np.random.Generator) -> None:
        self.p = params
        self.rng = rng
        self.start: list[np.ndarray] = []
        self.end: list[np.ndarray] = []
        self.r0: list[float] = []
        self.r1: list[float] = []
        self.parent: list[int] = []
        self.branch: list[int] = []
        self.order: list[int] = []
        self.position: list[int] = []
        self.n_stems = 0
        self.trunk_length = params.trunk_length_m  # drawn in build()
        self.leaf_stems: list[_Grown] = []
        self.queue: deque[_Stem] = deque()

    def u(self) -> float:
        """Uniform in [-1, 1)."""
        return 2.0 * float(self.rng.random()) - 1.0

    def profile(self, base_radius: float, taper: float, flare: float) -> Callable[[float], float]:
        tip = min(base_radius, self.p.tip_radius_m)

        def radius(z: float) -> float:
            r = base_radius - (base_radius - tip) * taper * z
            if flare > 0.0:
                y = max(0.0, 1.0 - 8.0 * z)
                r *= 1.0 + flare * (100.0**y - 1.0) / 100.0
            return r

        return radius

    # ------------------------------------------------------------------ growing

    def grow(self, stem: _Stem) -> _Grown:
        p, lev = self.p, self.p.levels[stem.level]
        segs = stem.segments or lev.segments
        trunk = stem.parent_row < 0
        # Node fractions: W&P's segments, the trunk's lowest eighth subdivided.
        fracs = [k / segs for k in range(segs + 1)]
        if trunk and p.flare > 0.0:
            extra = [j / (8.0 * _FLARE_SUBSEGMENTS) for j in range(1, _FLARE_SUBSEGMENTS + 1)]
            # (none within a fifth of a segment of a W&P joint: no sliver segments)
            extra = [z for z in extra if min(abs(z - f) for f in fracs) > 0.2 / segs]
            fracs = sorted(set(fracs) | set(extra))
        bends = {k / segs for k in range(1, segs)}

        d = stem.direction.copy()
        right = stem.right.copy()
        pos = stem.start.copy()
        nodes = [pos.copy()]
        rows: list[int] = []
        self.n_stems += 1
        branch = self.n_stems
        parent_row = stem.parent_row
        split_error = stem.split_error
        for j in range(len(fracs) - 1):
            z0, z1 = fracs[j], fracs[j + 1]
            nxt = pos + d * (stem.length * (z1 - z0))
            row = len(self.start)
            self.start.append(pos)
            self.end.append(nxt)
            self.r0.append(stem.radius(z0))
            self.r1.append(stem.radius(z1))
            self.parent.append(parent_row)
            self.branch.append(branch)
            self.order.append(stem.order)
            self.position.append(j + 1)
            rows.append(row)
            parent_row = row
            pos = nxt
            nodes.append(pos.copy())
            if z1 not in bends:
                continue
            # Curvature at a W&P joint.
            k = round(z1 * segs) - 1  # the segment that just ended
            if lev.curve_back_deg == 0.0:
                bend = lev.curve_deg / segs
            else:
                half = max(segs / 2.0, 1.0)
                bend = (lev.curve_deg if k < segs / 2.0 else lev.curve_back_deg) / half
            d = _unit(_rotate(d, right, math.radians(bend)))
            if lev.curve_var_deg > 0.0:
                wobble_axis = _rotate(right, d, math.pi * self.u())
                angle = math.radians(lev.curve_var_deg / segs * self.u())
                d = _unit(_rotate(d, wobble_axis, angle))
                right = _rotate(right, wobble_axis, angle)
            if stem.level >= 2 and p.attraction_up != 0.0:
                declination = math.acos(max(-1.0, min(1.0, float(d[2]))))
                pull = p.attraction_up * declination / segs
                d = _tilt_toward(d, _UP if pull > 0 else -_UP, abs(pull))
            right = _unit(right - d * float(right @ d))
            # Splits (W&P's error diffusion), never in the trunk's bare base.
            if lev.seg_splits > 0.0 and not (trunk and z1 < p.base_size):
                want = lev.seg_splits + split_error
                clones = int(want)
                split_error = want - clones
                for _ in range(clones):
                    d = self.split(stem, d, right, z1, row, segs - k - 1)
                    right = _unit(right - d * float(right @ d))
        grown = _Grown(
            stem=stem,
            nodes=np.array(nodes),
            radii=np.array([stem.radius(z) for z in fracs]),
            arc=np.array(fracs) * stem.length,
            rows=np.array(rows, dtype=np.int64),
            right=stem.right,
        )
        return grown

    def split(
        self, stem: _Stem, d: np.ndarray, right: np.ndarray, z: float, row: int, segments: int
    ) -> np.ndarray:
        """Queue a clone forking off at fraction ``z``; return the stem's new direction.

        The clone grows the stem's remaining ``segments`` (so splitting always ends).
        """
        p, lev = self.p, self.p.levels[stem.level]
        angle = math.radians(lev.split_angle_deg + lev.split_angle_var_deg * self.u())
        plane = _rotate(right, d, 2.0 * math.pi * float(self.rng.random()))  # fork axis
        clone_dir = _unit(_rotate(d, plane, 2.0 * angle / 3.0))
        stem_dir = _unit(_rotate(d, plane, -angle / 3.0))
        ratio = p.split_radius_ratio
        mother = stem.radius

        def radius(zc: float, z=z) -> float:
            return ratio * mother(z + zc * (1.0 - z))

        # Start on the incoming segment's axis, back far enough that the clone's base
        # disc (radius ratio * r, tilted by 2/3 of the angle) stays inside the stem.
        seg_axis = _unit(self.end[row] - self.start[row])
        seg_len = float(np.linalg.norm(self.end[row] - self.start[row]))
        r_clone = radius(0.0)
        tilt = math.sqrt(max(0.0, 1.0 - float(clone_dir @ seg_axis) ** 2))
        back = min(1.05 * r_clone * tilt + 1e-6, 0.5 * seg_len)
        self.queue.append(
            _Stem(
                level=stem.level,
                order=stem.order + 1,
                start=self.end[row] - back * seg_axis,
                direction=clone_dir,
                right=_unit(np.cross(plane, clone_dir)),
                length=stem.length * (1.0 - z) + back,
                radius=radius,
                parent_row=row,
                parent_length=stem.parent_length,  # a sibling of its stem, for W&P's rules
                offset=stem.offset,
                split_error=0.0,
                segments=segments,
            )
        )
        return stem_dir

    # ------------------------------------------------------------------ children

    def children(self, g: _Grown) -> None:
        p = self.p
        stem = g.stem
        level = stem.level + 1
        if level >= len(p.levels):
            self.leaf_stems.append(g)
            return
        lev = p.levels[level]
        trunk = stem.level == 0  # the trunk or a clone of it
        length = stem.length
        base = p.base_size * length if stem.parent_row < 0 else 0.0
        if trunk:  # the trunk carries nBranches; its clones their share by length
            count = lev.branches * min(1.0, length / self.trunk_length)
        elif stem.level == 1:
            ratio_max = max(p.levels[1].length_ratio + p.levels[1].length_ratio_var, 1e-9)
            rel = stem.length / max(stem.parent_length, 1e-9)
            count = lev.branches * (0.2 + 0.8 * min(rel / ratio_max, 1.0))
        else:
            count = lev.branches * (1.0 - 0.5 * stem.offset / max(stem.parent_length, 1e-9))
        n = int(round(count))
        if n <= 0 or length - base <= 0:
            return
        spacing = (length - base) / n
        phi = 2.0 * math.pi * float(self.rng.random())
        r_base = stem.radius(0.0)
        for i in range(n):
            offset = base + (i + 0.5 + 0.4 * self.u()) * spacing
            offset = min(max(offset, base), length)
            lmax = lev.length_ratio + lev.length_ratio_var * self.u()
            if trunk:
                env = shape_ratio(p.shape, (length - offset) / max(length - base, 1e-9))
                child_len = length * lmax * env
            else:
                child_len = lmax * (length - 0.6 * offset)
            if lev.down_angle_var_deg >= 0.0:
                down = lev.down_angle_deg + lev.down_angle_var_deg * self.u()
            else:
                env = shape_ratio("conical", (length - offset) / max(length - base, 1e-9))
                down = lev.down_angle_deg + lev.down_angle_var_deg * (1.0 - 2.0 * env)
            if lev.rotate_deg >= 0.0:
                phi += math.radians(lev.rotate_deg + lev.rotate_var_deg * self.u())
            else:
                side = 1.0 if i % 2 == 0 else -1.0
                phi = side * math.radians(180.0 + lev.rotate_deg + lev.rotate_var_deg * self.u())
            if child_len <= 1e-3:
                continue
            self.attach(g, lev, level, offset, child_len, down, phi, r_base)

    def attach(
        self,
        g: _Grown,
        lev: StemLevel,
        level: int,
        offset: float,
        child_len: float,
        down_deg: float,
        phi: float,
        r_base: float,
    ) -> None:
        """Queue a child stem of ``g`` at ``offset`` metres along it."""
        p = self.p
        k = int(np.clip(np.searchsorted(g.arc, offset, side="right") - 1, 0, len(g.rows) - 1))
        a = _unit(g.nodes[k + 1] - g.nodes[k])
        seg_len = float(g.arc[k + 1] - g.arc[k])
        # Azimuth reference: the parent's curve-plane normal, made perpendicular to a.
        ref = g.right - a * float(g.right @ a)
        ref = _unit(ref) if np.linalg.norm(ref) > 1e-9 else _perpendicular(a)
        radial = _rotate(ref, a, phi)
        down = math.radians(down_deg)
        d = _unit(math.cos(down) * a + math.sin(down) * radial)
        r_parent = float(min(g.radii[k], g.radii[k + 1]))
        r_child = min(
            r_base * (child_len / g.stem.length) ** p.ratio_power, CHILD_RADIUS_LIMIT * r_parent
        )
        # Keep the base disc inside the parent: within this segment along the axis, and
        # radially inside the parent's inscribed polygon at MIN_JUNCTION_FACETS facets.
        sin_a = math.sqrt(max(0.0, 1.0 - float(d @ a) ** 2))
        reach = r_child * sin_a
        t = offset - float(g.arc[k])
        t = min(max(t, reach), seg_len - reach) if seg_len > 2.0 * reach else 0.5 * seg_len
        r_in = r_parent * math.cos(math.pi / MIN_JUNCTION_FACETS)
        inset = 0.95 * sin_a * math.sqrt(max(r_in * r_in - r_child * r_child, 0.0))
        along = d - a * float(d @ a)
        out = _unit(along) if np.linalg.norm(along) > 1e-9 else radial
        start = g.nodes[k] + t * a + inset * out
        right = np.cross(a, d)
        right = _unit(right) if np.linalg.norm(right) > 1e-9 else _perpendicular(d)
        self.queue.append(
            _Stem(
                level=level,
                order=g.stem.order + 1,
                start=start,
                direction=d,
                right=right,
                length=child_len,
                radius=self.profile(r_child, lev.taper, 0.0),
                parent_row=int(g.rows[k]),
                parent_length=g.stem.length,
                offset=offset,
            )
        )

    # ------------------------------------------------------------------ leaves

    def leaves(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
        lp = self.p.leaves
        if lp is None or lp.leaves_per_stem == 0 or not self.leaf_stems:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0
        base_pts, mids, widths, sizes = [], [], [], []
        for g in self.leaf_stems:
            stem = g.stem
            rel = stem.offset / stem.parent_length if stem.parent_length > 0 else 1.0
            count = int(round(lp.leaves_per_stem * shape_ratio("tapered_cylindrical", rel)))
            if count <= 0:
                continue
            s = stem.length * (
                0.15 + 0.85 * (np.arange(count) + 0.5 + 0.4 * rng.uniform(-1, 1, count)) / count
            )
            k = np.clip(np.searchsorted(g.arc, s, side="right") - 1, 0, len(g.rows) - 1)
            seg = g.nodes[k + 1] - g.nodes[k]
            seg_len = np.linalg.norm(seg, axis=1)
            t_axis = seg / seg_len[:, None]
            frac = np.clip((s - g.arc[k]) / seg_len, 0.0, 1.0)
            centre = g.nodes[k] + (s - g.arc[k])[:, None] * t_axis
            radius = g.radii[k] + frac * (g.radii[k + 1] - g.radii[k])
            ref = g.right[None, :] - t_axis * (t_axis @ g.right)[:, None]
            norm = np.linalg.norm(ref, axis=1)
            ref = np.where(norm[:, None] > 1e-9, ref / np.maximum(norm, 1e-300)[:, None], 0.0)
            bad = norm <= 1e-9
            for i in np.flatnonzero(bad):
                ref[i] = _perpendicular(t_axis[i])
            side = np.cross(t_axis, ref)
            phi = float(rng.random()) * 2 * math.pi + np.radians(lp.rotate_deg) * np.arange(count)
            radial = np.cos(phi)[:, None] * ref + np.sin(phi)[:, None] * side
            down = np.radians(lp.down_angle_deg + lp.down_angle_var_deg * rng.uniform(-1, 1, count))
            mid = np.cos(down)[:, None] * t_axis + np.sin(down)[:, None] * radial
            width = np.cross(t_axis, radial)
            width /= np.linalg.norm(width, axis=1, keepdims=True)
            base_pts.append(centre + (radius + lp.petiole_m)[:, None] * radial)
            mids.append(mid)
            widths.append(width)
            sizes.append(1.0 + lp.size_var * rng.uniform(-1, 1, count))
        if not base_pts:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0
        base = np.concatenate(base_pts)
        mid = np.concatenate(mids)
        width = np.concatenate(widths)
        size = np.concatenate(sizes)
        # Turn each blade about its midrib toward facing up, by the bend fraction.
        normal = np.cross(mid, width)
        up = _UP[None, :] - mid * mid[:, 2:3]
        up_norm = np.linalg.norm(up, axis=1)
        ok = up_norm > 1e-9
        target = np.where(ok[:, None], up / np.maximum(up_norm, 1e-300)[:, None], normal)
        flip = np.einsum("ij,ij->i", normal, target) < 0  # a blade has two faces
        target[flip] *= -1.0
        gamma = np.arctan2(
            np.einsum("ij,ij->i", np.cross(normal, target), mid),
            np.einsum("ij,ij->i", normal, target),
        )
        turn = lp.bend * gamma
        width = np.cos(turn)[:, None] * width + np.sin(turn)[:, None] * normal
        pts, tris = LEAF_SHAPES[lp.shape]
        xy = np.array(pts, dtype=np.float64)
        length = lp.length_m * size
        vertices = (
            base[:, None, :]
            + (length[:, None] * xy[None, :, 0])[:, :, None] * mid[:, None, :]
            + (length[:, None] * lp.width_ratio * xy[None, :, 1])[:, :, None] * width[:, None, :]
        )
        n = len(base)
        faces = (
            np.array(tris, dtype=np.int64)[None, :, :] + (np.arange(n) * len(pts))[:, None, None]
        )
        return vertices.reshape(-1, 3), faces.reshape(-1, 3), n

    # ------------------------------------------------------------------ all of it

    def build(self) -> CylinderTable:
        p = self.p
        length = p.trunk_length_m + p.trunk_length_var_m * self.u()
        self.trunk_length = length
        roll = 2.0 * math.pi * float(self.rng.random())
        self.queue.append(
            _Stem(
                level=0,
                order=0,
                start=np.zeros(3),
                direction=_UP.copy(),
                right=np.array([math.cos(roll), math.sin(roll), 0.0]),
                length=length,
                radius=self.profile(length * p.radius_ratio, p.levels[0].taper, p.flare),
                parent_row=-1,
                parent_length=0.0,
                offset=0.0,
            )
        )
        while self.queue:
            self.children(self.grow(self.queue.popleft()))
        start = np.array(self.start)
        end = np.array(self.end)
        n = len(start)
        parent = np.array(self.parent, dtype=np.int64)
        extension = np.full(n, -1, dtype=np.int64)
        cont = np.flatnonzero(parent >= 0)
        cont = cont[np.array(self.branch)[parent[cont]] == np.array(self.branch)[cont]]
        extension[parent[cont]] = cont
        table = CylinderTable.from_endpoints(
            start,
            end,
            np.array(self.r0),
            parent=parent,
            branch=np.array(self.branch, dtype=np.int64),
            branch_order=np.array(self.order, dtype=np.int64),
            position_in_branch=np.array(self.position, dtype=np.int64),
            end_radius_m=np.array(self.r1),
            tag=np.full(n, "modelled"),
            extension=extension,
        )
        return table.validate(source=f"procedural tree {p.name!r}")


def generate_tree(
    species: str | TreeParams, *, seed: int = 0, leaves: bool | None = None
) -> ProceduralTree:
    """Generate a tree: its exact cylinder table and (optionally) its leaves.

    Parameters
    ----------
    species : str or TreeParams
        A preset name (see :data:`SPECIES`) or parameters.
    seed : int
        Seed of ``numpy.random.default_rng``, >= 0. The same seed gives the same tree,
        bit for bit.
    leaves : bool, optional
        Add leaves (needs ``params.leaves``); default the species' ``leaves_on``. The
        wood does not depend on it.

    Returns
    -------
    ProceduralTree
        Stem base at the origin, trunk along +z, metres.
    """
    params = species_preset(species) if isinstance(species, str) else species
    if not isinstance(params, TreeParams):
        raise InvalidParameterError(f"species must be a preset name or TreeParams, got {species!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InvalidParameterError(f"seed must be an integer >= 0, got {seed!r}")
    want_leaves = params.leaves_on if leaves is None else bool(leaves)
    if want_leaves and params.leaves is None:
        raise InvalidParameterError(
            f"species {params.name!r} has no leaf parameters; generate it without leaves"
        )
    rng = np.random.default_rng(int(seed))
    wood_rng, leaf_rng = rng.spawn(2)
    builder = _Builder(params, wood_rng)
    table = builder.build()
    if want_leaves:
        lv, lf, n_leaves = builder.leaves(leaf_rng)
    else:
        lv, lf, n_leaves = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0
    lv.setflags(write=False)
    lf.setflags(write=False)
    return ProceduralTree(
        params=params,
        seed=int(seed),
        cylinders=table,
        leaf_vertices=lv,
        leaf_faces=lf,
        n_leaves=n_leaves,
    )


# ---------------------------------------------------------------------- presets

_ASPEN_SOURCE = (
    "Weber & Penn (1995), table of Quaking Aspen (Populus tremuloides) parameters, as "
    "shipped in Arbaro's and tree-gen's quaking_aspen species files: shape tend-flame, "
    "Ratio 0.015, RatioPower 1.2, Flare 0.6, BaseSize 0.3, 1DownAngle 60 (V -50), "
    "1Rotate 140, 1Branches 50, 1Length 0.3, 1Curve -40, 2DownAngle 60, 2Rotate 140, "
    "2Length 0.6, 2Curve -60, AttractionUp 0.5, LeafBend 0.6. Changed for measurement: "
    "trunk 14 +- 1 m (the crown reaches ~17 m), Ratio 0.011 (DBH ~30 cm, a common size for "
    "an aspen of that height; 0.015 gives ~41 cm), RatioPower 1.7 (branch wood ~25 % of "
    "the total; 1.2 gives ~55 %), 2Branches 30 -> 14 and the third level dropped (leaves "
    "sit on level 2), leaves 7 cm ovate blades (W&P's LeafScale 0.17 is a rendering size)."
)

_ASPEN = TreeParams(
    name="aspen",
    description="broadleaf, leaf-off: quaking aspen, ~17 m tall, DBH ~30 cm",
    source=_ASPEN_SOURCE,
    shape="tend_flame",
    trunk_length_m=14.0,
    trunk_length_var_m=1.0,
    radius_ratio=0.011,
    ratio_power=1.7,
    flare=0.6,
    base_size=0.3,
    attraction_up=0.5,
    tip_radius_m=0.002,
    levels=(
        StemLevel(segments=10, curve_var_deg=20.0, taper=1.0),
        StemLevel(
            branches=50,
            length_ratio=0.3,
            down_angle_deg=60.0,
            down_angle_var_deg=-50.0,
            rotate_deg=140.0,
            segments=5,
            curve_deg=-40.0,
            curve_var_deg=50.0,
        ),
        StemLevel(
            branches=14,
            length_ratio=0.6,
            length_ratio_var=0.1,
            down_angle_deg=60.0,
            down_angle_var_deg=20.0,
            rotate_deg=140.0,
            segments=3,
            curve_deg=-60.0,
            curve_var_deg=75.0,
        ),
    ),
    leaves=LeafParams(
        leaves_per_stem=25,
        length_m=0.07,
        width_ratio=0.9,
        shape="ovate",
        down_angle_deg=55.0,
        down_angle_var_deg=20.0,
        bend=0.6,
        petiole_m=0.015,
    ),
)

SPECIES: dict[str, TreeParams] = {}


def _register(params: TreeParams) -> None:
    SPECIES[params.name] = params


_register(_ASPEN)
_register(
    replace(
        _ASPEN,
        name="aspen-leafon",
        description="broadleaf, leaf-on: the aspen with ~10 000 leaves of 7 cm",
        leaves_on=True,
    )
)
_register(
    TreeParams(
        name="balsam-fir",
        description="conifer: balsam fir, ~15 m tall, DBH ~22 cm, with shoot sprays",
        source=(
            "Weber & Penn (1995), table of Balsam Fir (Abies balsamea) parameters, as shipped "
            "in Arbaro's and tree-gen's balsam_fir species files: shape conical, Ratio 0.015, "
            "RatioPower 1.7, Flare 0.2, BaseSize 0.05, 1DownAngle 50 (V -45), 1Rotate 140, "
            "1Branches 100, 1Length 0.5, 1Curve -40, 2DownAngle 60, 2Length 0.25, LeafScale "
            "0.13, LeafScaleX 0.5. Changed for measurement: trunk 13 +- 1 m, Ratio 0.009 (DBH "
            "~22 cm), RatioPower 2.0 (branch wood ~11 %), 1Branches 100 -> 70, 1Length 0.5 -> "
            "0.35, 1DownAngleV -45 -> -35, 1Curve -40 -> +10 and BaseSize 0.1 (a narrow "
            "crown of level, slightly drooping branches that stay above the ground), "
            "2Branches 75 -> 8, the third level dropped; needles are modelled as flat shoot "
            "sprays (10 x 4 cm rectangles) on the level-2 stems."
        ),
        shape="conical",
        trunk_length_m=13.0,
        trunk_length_var_m=1.0,
        radius_ratio=0.009,
        ratio_power=2.0,
        flare=0.2,
        base_size=0.1,
        attraction_up=0.0,
        tip_radius_m=0.002,
        levels=(
            StemLevel(segments=12, curve_var_deg=10.0, taper=1.0),
            StemLevel(
                branches=70,
                length_ratio=0.35,
                down_angle_deg=50.0,
                down_angle_var_deg=-35.0,
                rotate_deg=140.0,
                segments=4,
                curve_deg=10.0,
                curve_var_deg=10.0,
            ),
            StemLevel(
                branches=8,
                length_ratio=0.3,
                length_ratio_var=0.1,
                down_angle_deg=60.0,
                down_angle_var_deg=20.0,
                rotate_deg=140.0,
                rotate_var_deg=20.0,
                segments=2,
                curve_deg=0.0,
                curve_var_deg=40.0,
            ),
        ),
        leaves=LeafParams(
            leaves_per_stem=12,
            length_m=0.10,
            width_ratio=0.4,
            shape="rectangle",
            down_angle_deg=45.0,
            down_angle_var_deg=15.0,
            bend=0.0,
            petiole_m=0.025,
        ),
        leaves_on=True,
    )
)
_register(
    TreeParams(
        name="sapling",
        description="young broadleaf sapling, ~4 m tall, DBH ~3 cm, leaf-off",
        source=(
            "The Quaking Aspen structure of Weber & Penn (1995) (shape tend-flame, "
            "RatioPower 1.2, 1DownAngle 60 (V -50), 1Rotate 140, 1Curve -40, two levels as "
            "in Blender Sapling's default tree) scaled to a sapling: trunk 3.5 +- 0.3 m, "
            "Ratio 0.006 (height / DBH ~ 115, slender open-grown saplings), no flare, 20 "
            "level-1 stems with 5 twigs each."
        ),
        shape="tend_flame",
        trunk_length_m=3.5,
        trunk_length_var_m=0.3,
        radius_ratio=0.006,
        ratio_power=1.2,
        flare=0.0,
        base_size=0.25,
        attraction_up=0.5,
        tip_radius_m=0.0015,
        levels=(
            StemLevel(segments=8, curve_var_deg=15.0, taper=1.0),
            StemLevel(
                branches=20,
                length_ratio=0.35,
                down_angle_deg=55.0,
                down_angle_var_deg=-40.0,
                rotate_deg=140.0,
                segments=4,
                curve_deg=-30.0,
                curve_var_deg=40.0,
            ),
            StemLevel(
                branches=5,
                length_ratio=0.5,
                length_ratio_var=0.1,
                down_angle_deg=50.0,
                down_angle_var_deg=15.0,
                rotate_deg=140.0,
                segments=2,
                curve_var_deg=40.0,
            ),
        ),
        leaves=LeafParams(
            leaves_per_stem=10,
            length_m=0.06,
            width_ratio=0.8,
            shape="ovate",
            bend=0.6,
            petiole_m=0.01,
        ),
    )
)
_register(
    TreeParams(
        name="old-tupelo",
        description="large old broadleaf: black tupelo, ~29 m tall, DBH ~79 cm, forked limbs",
        source=(
            "Weber & Penn (1995), table of Black Tupelo (Nyssa sylvatica) parameters, as "
            "shipped in Arbaro's and tree-gen's black_tupelo species files: shape "
            "tapered-cylindrical, Ratio 0.015, RatioPower 1.3, Flare 1.0, BaseSize 0.2, "
            "1DownAngle 60 (V -40), 1Rotate 140 (V 60), 1Length 0.3 (V 0.05), 2DownAngle 40, "
            "2Length 0.6, 2Curve -10, CurveV 40/90/150. Changed for an old tree: trunk 24 +- "
            "2 m, Ratio 0.014 (DBH ~79 cm), RatioPower 1.5 (branch wood ~1/3), 1Branches "
            "75 -> 32 with 0.3 splits per segment (forked old limbs), 2Branches 25 -> 9, the "
            "fourth level dropped."
        ),
        shape="tapered_cylindrical",
        trunk_length_m=24.0,
        trunk_length_var_m=2.0,
        radius_ratio=0.014,
        ratio_power=1.5,
        flare=1.0,
        base_size=0.2,
        attraction_up=0.3,
        tip_radius_m=0.003,
        levels=(
            StemLevel(segments=12, curve_var_deg=40.0, taper=1.0),
            StemLevel(
                branches=32,
                length_ratio=0.3,
                length_ratio_var=0.05,
                down_angle_deg=60.0,
                down_angle_var_deg=-40.0,
                rotate_deg=140.0,
                rotate_var_deg=60.0,
                segments=6,
                curve_deg=0.0,
                curve_var_deg=90.0,
                seg_splits=0.3,
                split_angle_deg=30.0,
                split_angle_var_deg=10.0,
            ),
            StemLevel(
                branches=9,
                length_ratio=0.6,
                length_ratio_var=0.1,
                down_angle_deg=40.0,
                down_angle_var_deg=10.0,
                rotate_deg=140.0,
                rotate_var_deg=50.0,
                segments=4,
                curve_deg=-10.0,
                curve_var_deg=150.0,
            ),
        ),
        leaves=LeafParams(
            leaves_per_stem=20,
            length_m=0.10,
            width_ratio=0.5,
            shape="ovate",
            bend=0.3,
            petiole_m=0.015,
        ),
    )
)


def species_preset(name: str) -> TreeParams:
    """The tree species called ``name`` (see :data:`SPECIES`)."""
    try:
        return SPECIES[name]
    except (KeyError, TypeError):
        raise InvalidParameterError(
            f"unknown species {name!r}; choose one of {', '.join(SPECIES)} "
            "(see 'treesim model list')"
        ) from None
