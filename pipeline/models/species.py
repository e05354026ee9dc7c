"""The parameters of a procedural tree (Weber & Penn 1995) and the species presets.

:class:`TreeParams` holds a species: Weber & Penn's global parameters, one
:class:`StemLevel` per branching level and the :class:`LeafParams`; each checks its values
when made, so a species from code, from a file or from the presets is held to the same
ranges. The presets (:data:`SPECIES`) are data, not code: the file
``pipeline/data/species.toml`` (installed as ``treesim/data/species.toml``), read once when
this module is imported. A species is numbers and the prose of where they come from; as
data it can be read, diffed and extended without reading Python, and it passes the same
checks as parameters a user gives. The builder that grows a tree from them is
:mod:`treesim.models.builder`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, replace
from functools import cached_property
from importlib import resources
from typing import Any

from ..errors import InvalidParameterError

__all__ = [
    "CHILD_RADIUS_LIMIT",
    "LEAF_SHAPES",
    "SHAPES",
    "SPECIES",
    "LeafParams",
    "StemLevel",
    "TreeParams",
    "read_species_toml",
    "shape_ratio",
    "species_preset",
]

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
    droop : float
        In [0, 1]: how far each leaf's direction around its stem turns toward the ground
        (0: as ``rotate_deg`` sets it; 1: straight down the stem's side). With
        ``rotate_deg`` 180 (two ranks) it hangs a pinnate frond's leaflets in a V, as a
        coconut palm's hang.
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
    droop: float = 0.0

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
        _check("droop", self.droop, 0.0, 1.0)


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


# ---------------------------------------------------------------------- the presets, as data

#: Where the presets live, under the installed package ``treesim``.
SPECIES_RESOURCE = "data/species.toml"


def _fields(cls: type, table: dict[str, Any], where: str) -> dict[str, Any]:
    """``table``'s values as keyword arguments of ``cls``: an unknown key is refused by
    name, and a whole number given for a float field becomes a float (TOML reads ``14``
    as an integer), so a preset reads back with the types the dataclass declares."""
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise InvalidParameterError(
            f"{where}: unknown {cls.__name__} parameter {unknown[0]!r}; known: {', '.join(known)}"
        )
    out = dict(table)
    for key, value in table.items():
        if known[key].type == "float" and isinstance(value, int) and not isinstance(value, bool):
            out[key] = float(value)
    return out


def _tree_fields(entry: dict[str, Any], where: str) -> dict[str, Any]:
    """A ``[[species]]`` table as :class:`TreeParams` keyword arguments: its
    ``[[species.levels]]`` made :class:`StemLevel` and its ``[species.leaves]``
    :class:`LeafParams`."""
    kw = _fields(TreeParams, entry, where)
    if "levels" in kw:
        levels = kw["levels"]
        if not isinstance(levels, list) or not all(isinstance(t, dict) for t in levels):
            raise InvalidParameterError(f"{where}: levels must be [[species.levels]] tables")
        kw["levels"] = tuple(
            StemLevel(**_fields(StemLevel, t, f"{where}, level {i}")) for i, t in enumerate(levels)
        )
    if isinstance(kw.get("leaves"), dict):
        kw["leaves"] = LeafParams(**_fields(LeafParams, kw["leaves"], f"{where}, leaves"))
    return kw


def read_species_toml(text: str, *, source: str = "species.toml") -> dict[str, TreeParams]:
    """Species presets from the text of a species file, by name, in the file's order.

    Each ``[[species]]`` table holds :class:`TreeParams`' fields, one
    ``[[species.levels]]`` table per :class:`StemLevel` (the trunk first) and a
    ``[species.leaves]`` table of :class:`LeafParams` (absent: no leaves); a field left
    out takes its default. ``based_on = "NAME"`` starts from a species earlier in the
    file and changes only the fields given.

    Parameters
    ----------
    text : str
        The file's text (TOML).
    source : str
        What to call the file in error messages.

    Returns
    -------
    dict of str to TreeParams

    Raises
    ------
    InvalidParameterError
        Not TOML, an unknown field, a value out of its range, a ``based_on`` naming no
        species above it, or a name given twice: the message names the species.
    """
    import tomllib  # loaded only when a species file is read

    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InvalidParameterError(f"{source}: not a valid TOML file: {exc}") from None
    entries = doc.get("species", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise InvalidParameterError(f"{source}: species must be [[species]] tables")
    out: dict[str, TreeParams] = {}
    for i, entry in enumerate(entries):
        data = dict(entry)
        name = data.get("name")
        where = f"{source}: species {name if name is not None else i + 1!r}"
        if name in out:
            raise InvalidParameterError(f"{where}: a second species of that name")
        based_on = data.pop("based_on", None)
        if based_on is not None and based_on not in out:
            raise InvalidParameterError(f"{where}: based_on {based_on!r} names no species above it")
        try:
            kw = _tree_fields(data, where)
            params = replace(out[based_on], **kw) if based_on is not None else TreeParams(**kw)
        except TypeError as exc:  # a required field missing
            raise InvalidParameterError(f"{where}: {exc}") from None
        except InvalidParameterError as exc:
            if str(exc).startswith(source):
                raise
            raise InvalidParameterError(f"{where}: {exc}") from None
        out[params.name] = params
    return out


def _load_presets() -> dict[str, TreeParams]:
    text = (resources.files("treesim") / SPECIES_RESOURCE).read_text("utf-8")
    return read_species_toml(text, source=f"treesim/{SPECIES_RESOURCE}")


class _Presets(Mapping[str, TreeParams]):
    """The species presets, read from the package's TOML file on first use (every treesim
    command imports this module; only those that build a tree need the file parsed)."""

    @cached_property
    def _presets(self) -> dict[str, TreeParams]:
        return _load_presets()

    def __getitem__(self, name: str) -> TreeParams:
        return self._presets[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._presets)

    def __len__(self) -> int:
        return len(self._presets)

    def __repr__(self) -> str:
        return f"SPECIES({', '.join(self)})"


#: The species presets by name (what ``--species`` takes), in the order of
#: ``treesim/data/species.toml``, read once, on first use (a read-only mapping).
SPECIES: Mapping[str, TreeParams] = _Presets()


def species_preset(name: str) -> TreeParams:
    """The tree species called ``name`` (see :data:`SPECIES`)."""
    try:
        return SPECIES[name]
    except (KeyError, TypeError):
        raise InvalidParameterError(
            f"unknown species {name!r}; choose one of {', '.join(SPECIES)} "
            "(see 'treesim model list')"
        ) from None
