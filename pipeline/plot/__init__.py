"""Forest plots: trees with positions and ids on a terrain, as one scannable scene.

A :class:`Plot` is a set of :class:`PlotTree` (each a procedural species, a mesh file, a
QSM table or a field cloud to reconstruct, placed at ``(x_m, y_m)`` on the terrain and
turned by ``rotation_deg`` about its stem base) and a :class:`Terrain` (flat, a plane
sloping down towards an aspect, a DTM raster or a ground cloud). Every tree's triangles
carry its ``tree_id`` (>= 1; the terrain 0), so a scan of the plot labels each point with
the tree it hit (:func:`pipeline.scan.scan_fields`).

Coordinates are metres in the plot's frame: x east, y north, z up; the terrain's height
at the plot centre is its ``z0_m``. A tree's stem base stands on the terrain's lowest
point under its stem (on a slope, the uphill side of the stem is buried, none of it
floats).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InvalidParameterError
from ..params._fields import finite
from ..scene import MAX_TREE_ID, MeshPart, Scene, labelled_parts

__all__ = [
    "TERRAIN_KINDS",
    "TREE_SOURCES",
    "Plot",
    "PlotTree",
    "Terrain",
]

#: How a plot tree is given: a procedural species, a mesh file, a QSM cylinder table, or
#: a field cloud reconstructed into a QSM.
TREE_SOURCES = ("species", "mesh", "qsm", "cloud")
#: Terrain kinds: flat, a plane, a DTM raster (GeoTIFF or ASCII grid), a ground cloud.
TERRAIN_KINDS = ("flat", "slope", "dtm", "cloud")


@dataclass(frozen=True, kw_only=True)
class Terrain:
    """The ground of a plot.

    Parameters
    ----------
    kind : {"flat", "slope", "dtm", "cloud"}
        ``flat``: z = ``z0_m``; ``slope``: a plane through ``(0, 0, z0_m)`` falling by
        ``slope_deg`` towards ``aspect_deg`` (compass degrees, 0 north = +y, 90 east =
        +x); ``dtm`` and ``cloud``: a surface read from ``path``.
    z0_m : float
        Height at the plot centre (flat and slope).
    slope_deg : float
        Slope in [0, 60) degrees.
    aspect_deg : float
        Direction the slope faces (downhill), compass degrees.
    path : str, optional
        The DTM raster or ground cloud (``dtm``, ``cloud``).
    """

    kind: str = "flat"
    z0_m: float = 0.0
    slope_deg: float = 0.0
    aspect_deg: float = 0.0
    path: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in TERRAIN_KINDS:
            raise InvalidParameterError(
                f"terrain kind must be one of {', '.join(TERRAIN_KINDS)}, got {self.kind!r}"
            )
        finite("z0_m", self.z0_m)
        finite("aspect_deg", self.aspect_deg)
        if not (0.0 <= float(self.slope_deg) < 60.0):
            raise InvalidParameterError(
                f"terrain slope_deg must be in [0, 60), got {self.slope_deg!r}"
            )
        if self.kind in ("dtm", "cloud") and not self.path:
            raise InvalidParameterError(f"a {self.kind} terrain needs a path")

    def gradient(self) -> tuple[float, float]:
        """(dz/dx, dz/dy) of a plane terrain (0, 0 when flat)."""
        if self.kind == "flat" or self.slope_deg == 0:
            return 0.0, 0.0
        g = math.tan(math.radians(self.slope_deg))
        a = math.radians(self.aspect_deg)
        # downhill towards (sin a, cos a): z falls along it
        return -g * math.sin(a), -g * math.cos(a)

    def height_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Terrain height (m) at plot coordinates ``x``, ``y`` (arrays of one shape)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.kind in ("flat", "slope"):
            gx, gy = self.gradient()
            return self.z0_m + gx * x + gy * y
        raise NotImplementedError(f"{self.kind} terrain heights are not implemented yet")

    def mesh(self, lo_xy: Sequence[float], hi_xy: Sequence[float], cell_m: float) -> MeshPart:
        """The terrain over the rectangle ``lo_xy``–``hi_xy`` as a grid of triangles
        ``cell_m`` on a side (or a little less, to fit), labelled ``ground``."""
        if not (math.isfinite(cell_m) and cell_m > 0):
            raise InvalidParameterError(f"terrain cell_m must be > 0, got {cell_m!r}")
        (x0, y0), (x1, y1) = (float(v) for v in lo_xy), (float(v) for v in hi_xy)
        nx = max(1, math.ceil((x1 - x0) / cell_m))
        ny = max(1, math.ceil((y1 - y0) / cell_m))
        xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        z = self.height_at(gx, gy)
        verts = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
        i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        a = (i * (ny + 1) + j).ravel()
        b, c, d = a + (ny + 1), a + 1, a + ny + 2
        faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
        return MeshPart(verts, faces.astype(np.int64), "ground", "terrain")


@dataclass(frozen=True, kw_only=True)
class PlotTree:
    """One tree of a plot.

    Parameters
    ----------
    tree_id : int
        >= 1, unique in the plot: the ``tree_id`` of its points in a scan.
    x_m, y_m : float
        Stem base position in the plot's frame.
    rotation_deg : float
        Turn about the vertical through the stem base, counter-clockwise.
    source : {"species", "mesh", "qsm", "cloud"}
        What the tree is made from (:data:`TREE_SOURCES`).
    species : str, optional
        A procedural preset (``source="species"``; see ``treesim model list``).
    seed : int
        The procedural tree's seed.
    path : str, optional
        The mesh, cylinder table or field cloud (other sources). Its stem base (the
        lowest point's x, y and z) is moved to the tree's position.
    scale : float
        Uniform scale about the stem base (1: as made).
    leaves : bool, optional
        Procedural leaves (default: the species' own).
    """

    tree_id: int
    x_m: float
    y_m: float
    rotation_deg: float = 0.0
    source: str = "species"
    species: str | None = None
    seed: int = 0
    path: str | None = None
    scale: float = 1.0
    leaves: bool | None = None

    def __post_init__(self) -> None:
        tid = self.tree_id
        if isinstance(tid, bool) or not isinstance(tid, int | np.integer):
            raise InvalidParameterError(f"tree_id must be an integer, got {tid!r}")
        if not 1 <= int(tid) <= MAX_TREE_ID:
            raise InvalidParameterError(f"tree_id must be in [1, {MAX_TREE_ID}], got {tid}")
        for name in ("x_m", "y_m", "rotation_deg"):
            finite(f"tree {tid}: {name}", getattr(self, name))
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise InvalidParameterError(f"tree {tid}: scale must be > 0, got {self.scale!r}")
        if self.source not in TREE_SOURCES:
            raise InvalidParameterError(
                f"tree {tid}: source must be one of {', '.join(TREE_SOURCES)}, got {self.source!r}"
            )
        if self.source == "species" and not self.species:
            raise InvalidParameterError(f"tree {tid}: a species tree needs a species")
        if self.source != "species" and not self.path:
            raise InvalidParameterError(f"tree {tid}: a {self.source} tree needs a path")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
            raise InvalidParameterError(f"tree {tid}: seed must be an integer >= 0")
        if self.seed < 0:
            raise InvalidParameterError(f"tree {tid}: seed must be an integer >= 0")

    @property
    def name(self) -> str:
        """``tree <id> (<species or file name>)``, for messages."""
        what = self.species if self.source == "species" else Path(str(self.path)).name
        return f"tree {self.tree_id} ({what})"


def _local_mesh(tree: PlotTree, facets: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tree as made, stem base at the origin: vertices, faces, label codes."""
    if tree.source == "species":
        from ..models import generate_tree

        return generate_tree(str(tree.species), seed=int(tree.seed), leaves=tree.leaves).mesh(
            facets
        )
    raise NotImplementedError(f"{tree.source} plot trees are not implemented yet")


@dataclass
class Plot:
    """A forest plot: trees on a terrain, within ``radius_m`` of ``centre_xy``.

    Parameters
    ----------
    trees : sequence of PlotTree
        Unique ``tree_id`` each.
    terrain : Terrain
    radius_m : float
        The plot's radius (trees stand within it; stations are planned within it).
    centre_xy : (2,) float
        The plot centre in the plot's frame.
    facets : int
        Vertices per ring of procedural and QSM trees' tubes.
    terrain_cell_m : float
        Side of the terrain mesh's grid cells.
    """

    trees: Sequence[PlotTree]
    terrain: Terrain = field(default_factory=Terrain)
    radius_m: float = 15.0
    centre_xy: tuple[float, float] = (0.0, 0.0)
    facets: int = 16
    terrain_cell_m: float = 1.0
    _parts: dict[int, list[MeshPart]] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self.trees = tuple(self.trees)
        ids = [t.tree_id for t in self.trees]
        if len(set(ids)) != len(ids):
            dup = sorted({i for i in ids if ids.count(i) > 1})
            raise InvalidParameterError(f"tree ids must be unique; repeated: {dup[:10]}")
        if not (math.isfinite(self.radius_m) and self.radius_m > 0):
            raise InvalidParameterError(f"plot radius_m must be > 0, got {self.radius_m!r}")
        self.centre_xy = tuple(float(v) for v in self.centre_xy)  # type: ignore[assignment]

    def tree(self, tree_id: int) -> PlotTree:
        """The tree with this id."""
        for t in self.trees:
            if t.tree_id == tree_id:
                return t
        raise InvalidParameterError(f"the plot has no tree {tree_id}")

    def tree_parts(self, tree_id: int) -> list[MeshPart]:
        """The tree's mesh parts (wood, leaf, ...) placed in the plot, with its tree id.
        Built once and kept."""
        if tree_id not in self._parts:
            t = self.tree(tree_id)
            v, f, lab = _local_mesh(t, self.facets)
            self._parts[tree_id] = labelled_parts(
                self._place(t, v), f, lab, name_prefix=f"{t.name}:", tree_id=t.tree_id
            )
        return self._parts[tree_id]

    def _place(self, t: PlotTree, v: np.ndarray) -> np.ndarray:
        a = math.radians(t.rotation_deg)
        c, s = math.cos(a), math.sin(a)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        out = (np.asarray(v, dtype=np.float64) * t.scale) @ rot.T
        out[:, 0] += t.x_m
        out[:, 1] += t.y_m
        out[:, 2] += self.base_z(t, out)
        return out

    def base_z(self, t: PlotTree, placed: np.ndarray | None = None) -> float:
        """Height of the tree's stem base: the terrain's lowest point within the stem's
        footprint (its vertices within 5 cm of its base height), or at its position."""
        if placed is None:
            return float(self.terrain.height_at(t.x_m, t.y_m))
        low = placed[:, 2] <= placed[:, 2].min() + 0.05
        return float(self.terrain.height_at(placed[low, 0], placed[low, 1]).min())

    def scene(
        self, tree_ids: Iterable[int] | None = None, *, terrain: bool = True, margin_m: float = 2.0
    ) -> Scene:
        """The plot as one :class:`Scene`: the trees (all, or ``tree_ids``) and the terrain
        over the plot's square plus ``margin_m``."""
        ids = [t.tree_id for t in self.trees] if tree_ids is None else list(tree_ids)
        parts: list[MeshPart] = []
        for tid in ids:
            parts += self.tree_parts(tid)
        if terrain:
            r = self.radius_m + margin_m
            cx, cy = self.centre_xy
            parts.append(self.terrain.mesh((cx - r, cy - r), (cx + r, cy + r), self.terrain_cell_m))
        return Scene(parts)
