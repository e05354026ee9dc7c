"""The plot core: :class:`Terrain`, :class:`PlotTree`, :class:`Plot` (see :mod:`treesim.plot`)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..frame import LocalFrame
from ..params._fields import finite
from ..scene import MAX_TREE_ID, MeshPart, Scene, labelled_parts
from ._sources import local_tree, placed_table, rotation

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
        The DTM raster (ESRI ASCII grid ``.asc``) or ground cloud (any cloud format) of
        ``dtm`` and ``cloud`` terrains, in the plot's coordinates. Relative paths are
        relative to ``base_dir``.
    base_dir : str, optional
        The folder relative paths start from (a plot file's folder; default the current
        one).

    Notes
    -----
    A ``dtm`` is bilinear between its cell centres (NODATA cells take their nearest
    valid cell's height; beyond the grid, the nearest edge's); a ``cloud`` is linear on
    the Delaunay triangles of its points in x, y (the nearest point's height beyond
    their hull). See :mod:`treesim.plot._surface`.

    Examples
    --------
    >>> import treesim as ts
    >>> ts.Terrain(kind="slope", slope_deg=10.0, aspect_deg=90.0).kind
    'slope'
    """

    kind: str = "flat"
    z0_m: float = 0.0
    slope_deg: float = 0.0
    aspect_deg: float = 0.0
    path: str | None = None
    base_dir: str | None = field(default=None, compare=False)
    _surface: Any = field(default=None, init=False, repr=False, compare=False)

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

    @property
    def file(self) -> Path | None:
        """The terrain's file, resolved against ``base_dir`` (None: flat or slope)."""
        if not self.path:
            return None
        p = Path(self.path)
        return p if p.is_absolute() or self.base_dir is None else Path(self.base_dir) / p

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
        if self._surface is None:
            from ._surface import surface_from_cloud, surface_from_dtm

            read = surface_from_dtm if self.kind == "dtm" else surface_from_cloud
            object.__setattr__(self, "_surface", read(self.file))
        return self._surface(x, y)

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
    z_m : float, optional
        Stem base height in the plot's frame. Default: on the terrain, at its lowest
        point under the stem's footprint. A tree whose source already stands where it
        grew (a twin's QSM, on the field cloud's own terrain) gives it, so that the
        plot does not seat it again: re-seated on a 15° slope, twin trees were lifted by
        up to 21 cm and their crowns missed the field scan's points.
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
    dbh_m, height_m : float, optional
        Targets of a procedural tree (``source="species"``): the species' trunk length
        and radius ratio are adjusted so that this seed's tree comes close to them
        (:func:`treesim.plot._sources.fit_species`); the tree's exact figures are
        :meth:`Plot.truth`'s. Other sources ignore them (a stand file may carry the
        figures it measured).
    field_cloud : str, optional
        The field cloud the tree was measured from (``treesim plot from-cloud`` writes each
        tree's points and reconstructs its QSM from them); kept with the tree, not read to
        build it.

    Examples
    --------
    >>> import treesim as ts
    >>> tree = ts.PlotTree(tree_id=3, x_m=2.0, y_m=-1.5, species="balsam-fir", dbh_m=0.2)
    >>> tree.source
    'species'
    """

    tree_id: int
    x_m: float
    y_m: float
    z_m: float | None = None
    rotation_deg: float = 0.0
    source: str = "species"
    species: str | None = None
    seed: int = 0
    path: str | None = None
    scale: float = 1.0
    leaves: bool | None = None
    dbh_m: float | None = None
    height_m: float | None = None
    field_cloud: str | None = None

    def __post_init__(self) -> None:
        tid = self.tree_id
        if isinstance(tid, bool) or not isinstance(tid, int | np.integer):
            raise InvalidParameterError(f"tree_id must be an integer, got {tid!r}")
        if not 1 <= int(tid) <= MAX_TREE_ID:
            raise InvalidParameterError(f"tree_id must be in [1, {MAX_TREE_ID}], got {tid}")
        for name in ("x_m", "y_m", "rotation_deg"):
            finite(f"tree {tid}: {name}", getattr(self, name))
        if self.z_m is not None:
            finite(f"tree {tid}: z_m", self.z_m)
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
        for name in ("dbh_m", "height_m"):
            v = getattr(self, name)
            if v is not None and not (
                isinstance(v, int | float | np.floating)
                and not isinstance(v, bool)
                and math.isfinite(v)
                and v > 0
            ):
                raise InvalidParameterError(f"tree {tid}: {name} must be > 0 (or empty), got {v!r}")

    @property
    def name(self) -> str:
        """``tree <id> (<species or file name>)``, for messages."""
        what = self.species if self.source == "species" else Path(str(self.path)).name
        return f"tree {self.tree_id} ({what})"


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
    base_dir : str, optional
        The folder the trees' and the terrain's relative paths start from (the plot
        file's folder; default the current one). Reconstructions of ``cloud`` trees are
        kept in ``.treesim-cache/`` there.
    reconstruct : ReconstructParams, optional
        How ``cloud`` trees are reconstructed (default: the QSM's defaults).

    Notes
    -----
    Trees are built when first asked for and kept (:meth:`tree_parts`);
    :meth:`release` drops them (their bounds and triangle counts stay known), which is
    how :func:`treesim.plot.scan.scan_plot` keeps memory bounded.

    Examples
    --------
    >>> import treesim as ts
    >>> plot = ts.Plot(
    ...     [
    ...         ts.PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species="aspen"),
    ...         ts.PlotTree(tree_id=2, x_m=4.0, y_m=-3.0, species="balsam-fir", dbh_m=0.25),
    ...     ],
    ...     terrain=ts.Terrain(kind="slope", slope_deg=10.0, aspect_deg=90.0),
    ...     radius_m=10.0,
    ... )
    >>> plot.tree_ids
    [1, 2]
    """

    trees: Sequence[PlotTree]
    terrain: Terrain = field(default_factory=Terrain)
    radius_m: float = 15.0
    centre_xy: tuple[float, float] = (0.0, 0.0)
    facets: int = 16
    terrain_cell_m: float = 1.0
    base_dir: str | None = None
    reconstruct: Any = None
    _parts: dict[int, list[MeshPart]] = field(default_factory=dict, init=False, repr=False)
    _bounds: dict[int, np.ndarray] = field(default_factory=dict, init=False, repr=False)
    _ntri: dict[int, int] = field(default_factory=dict, init=False, repr=False)
    _truth: dict[int, dict[str, Any]] = field(default_factory=dict, init=False, repr=False)
    _origin: dict[int, np.ndarray] = field(default_factory=dict, init=False, repr=False)
    _tables: dict[int, Any] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self.trees = tuple(self.trees)
        for t in self.trees:
            if not isinstance(t, PlotTree):
                raise InvalidParameterError(f"plot trees must be PlotTree objects, got {t!r}")
        ids = [t.tree_id for t in self.trees]
        if len(set(ids)) != len(ids):
            dup = sorted({i for i in ids if ids.count(i) > 1})
            raise InvalidParameterError(f"tree ids must be unique; repeated: {dup[:10]}")
        if not (math.isfinite(self.radius_m) and self.radius_m > 0):
            raise InvalidParameterError(f"plot radius_m must be > 0, got {self.radius_m!r}")
        if isinstance(self.facets, bool) or not isinstance(self.facets, int | np.integer):
            raise InvalidParameterError(f"plot facets must be an integer >= 3, got {self.facets!r}")
        if self.facets < 3:
            raise InvalidParameterError(f"plot facets must be an integer >= 3, got {self.facets!r}")
        if not (math.isfinite(self.terrain_cell_m) and self.terrain_cell_m > 0):
            raise InvalidParameterError(
                f"plot terrain_cell_m must be > 0, got {self.terrain_cell_m!r}"
            )
        self.centre_xy = tuple(float(v) for v in self.centre_xy)  # type: ignore[assignment]
        if len(self.centre_xy) != 2 or not all(math.isfinite(v) for v in self.centre_xy):
            raise InvalidParameterError(
                f"plot centre_xy must be two finite numbers, got {self.centre_xy}"
            )
        if self.base_dir is not None and self.terrain.base_dir is None:
            from dataclasses import replace

            self.terrain = replace(self.terrain, base_dir=str(self.base_dir))
        self._by_id = {t.tree_id: t for t in self.trees}

    @property
    def tree_ids(self) -> list[int]:
        """The trees' ids, in the plot's order."""
        return [t.tree_id for t in self.trees]

    def tree(self, tree_id: int) -> PlotTree:
        """The tree with this id."""
        try:
            return self._by_id[int(tree_id)]
        except (KeyError, TypeError, ValueError):
            raise InvalidParameterError(f"the plot has no tree {tree_id}") from None

    @property
    def _base(self) -> Path | None:
        return None if self.base_dir is None else Path(self.base_dir)

    def tree_parts(self, tree_id: int) -> list[MeshPart]:
        """The tree's mesh parts (wood, leaf, ...) placed in the plot, with its tree id.
        Built once and kept (until :meth:`release`)."""
        if tree_id not in self._parts:
            t = self.tree(tree_id)
            # a tree built before (dropped, or built by a task) is meshed from its table
            # where that gives the same mesh (no second generation of a procedural tree)
            known = self._tables.get(tree_id)
            v, f, lab, base, table = local_tree(
                t, int(self.facets), self._base, self.reconstruct, known
            )
            self._tables[tree_id] = table
            placed = self._place(t, np.asarray(v, dtype=np.float64) - base)
            parts = labelled_parts(placed, f, lab, name_prefix=f"{t.name}:", tree_id=t.tree_id)
            used = placed[np.unique(np.asarray(f))]
            self._bounds[tree_id] = np.stack([used.min(axis=0), used.max(axis=0)])
            self._ntri[tree_id] = int(len(f))
            self._origin[tree_id] = np.asarray(base, dtype=np.float64)
            self._parts[tree_id] = parts
        return self._parts[tree_id]

    def tree_bounds(self, tree_id: int) -> np.ndarray:
        """(2, 3) float64 min and max corner of the placed tree (built once if needed;
        known after :meth:`release`)."""
        if tree_id not in self._bounds:
            self.tree_parts(tree_id)
        return self._bounds[tree_id].copy()

    def tree_table(self, tree_id: int) -> Any:
        """The tree's cylinder table placed as its mesh is in the plot (world coordinates:
        its stem base at the tree's position, on the terrain), or None for a tree with no
        table (a plain mesh). Built once if needed."""
        bounds = self.tree_bounds(tree_id)
        table = self._tables.get(tree_id)
        if table is None:
            return None
        t = self.tree(tree_id)
        # as _place: the source's stem base (its lowest point) to the tree's position,
        # standing on the terrain, which puts the placed mesh's lowest point at the base
        shift = np.array([t.x_m, t.y_m, bounds[0, 2]])
        return placed_table(table, self._origin[tree_id], t.scale, rotation(t.rotation_deg), shift)

    def tree_triangles(self, tree_id: int) -> int:
        """Number of triangles of the tree's mesh (built once if needed)."""
        if tree_id not in self._ntri:
            self.tree_parts(tree_id)
        return self._ntri[tree_id]

    @property
    def loaded(self) -> list[int]:
        """Ids of the trees whose meshes are held now."""
        return list(self._parts)

    def release(self, tree_ids: Iterable[int] | None = None) -> None:
        """Drop the meshes of these trees (default all); they are rebuilt when asked for."""
        for tid in list(self._parts) if tree_ids is None else list(tree_ids):
            self._parts.pop(tid, None)

    def tree_facts(self, tree_id: int) -> dict[str, Any]:
        """What the plot knows of a tree without holding its mesh: its bounds, triangle
        count, source origin and cylinder table (built once if needed). A task that
        built the tree hands them to its parent's plot (:meth:`set_tree_facts`), which
        then places and counts the tree without building it."""
        bounds = self.tree_bounds(tree_id)
        return {
            "bounds": bounds,
            "triangles": self._ntri[tree_id],
            "origin": self._origin[tree_id],
            "table": self._tables.get(tree_id),
        }

    def set_tree_facts(self, tree_id: int, facts: dict[str, Any]) -> None:
        """Take a tree's :meth:`tree_facts` as known (from another process that built
        the same tree): bounds, triangle count and truth then need no build.

        Examples
        --------
        >>> import treesim as ts
        >>> a = ts.Plot([ts.PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species="sapling")])
        >>> b = ts.Plot(a.trees)
        >>> b.set_tree_facts(1, a.tree_facts(1))
        >>> bool((b.tree_bounds(1) == a.tree_bounds(1)).all()), b.loaded
        (True, [])
        """
        self.tree(tree_id)  # an unknown id is refused
        self._bounds[tree_id] = np.asarray(facts["bounds"], dtype=np.float64).copy()
        self._ntri[tree_id] = int(facts["triangles"])
        self._origin[tree_id] = np.asarray(facts["origin"], dtype=np.float64)
        self._tables[tree_id] = facts["table"]

    def knows(self, tree_id: int) -> bool:
        """Whether the tree's bounds and triangles are known (built once, or given)."""
        return tree_id in self._bounds

    def blank(self) -> Plot:
        """The same plot with nothing built or known of its trees (what a task is sent:
        it builds what it needs itself)."""
        from dataclasses import replace

        return replace(self)

    def _place(self, t: PlotTree, v: np.ndarray) -> np.ndarray:
        rot = rotation(t.rotation_deg)
        out = (np.asarray(v, dtype=np.float64) * t.scale) @ rot.T
        out[:, 0] += t.x_m
        out[:, 1] += t.y_m
        out[:, 2] += self.base_z(t, out)
        return out

    def base_z(self, t: PlotTree, placed: np.ndarray | None = None) -> float:
        """Height of the tree's stem base: its ``z_m`` where given, else the terrain's
        lowest point within the stem's footprint (its vertices within 5 cm of its base
        height), or at its position."""
        if t.z_m is not None:
            return float(t.z_m)
        if placed is None:
            return float(self.terrain.height_at(t.x_m, t.y_m))
        low = placed[:, 2] <= placed[:, 2].min() + 0.05
        return float(self.terrain.height_at(placed[low, 0], placed[low, 1]).min())

    def truth(self, tree_id: int) -> dict[str, Any]:
        """The tree's reference figures as placed in the plot: its cylinder table's
        summary (``dbh_m``, ``height_m``, ``volume_total_m3``, ``volume_stem_m3``,
        ``volume_branch_m3``, ``n_cylinders``; exact for procedural trees, the table's own
        for QSM and reconstructed cloud trees), its position, stem base height and bounds,
        and ``source``. A mesh tree has no table: ``height_m`` is its bounds' height and
        the rest None."""
        if tree_id not in self._truth:
            t = self.tree(tree_id)
            bounds = self.tree_bounds(tree_id)
            table = self._tables.get(tree_id)
            if table is None:
                fig: dict[str, Any] = {
                    "dbh_m": None,
                    "height_m": float(bounds[1, 2] - bounds[0, 2]),
                    "volume_total_m3": None,
                    "volume_stem_m3": None,
                    "volume_branch_m3": None,
                    "n_cylinders": None,
                }
            else:
                base = self._origin[tree_id]
                moved = placed_table(table, base, t.scale, rotation(t.rotation_deg), np.zeros(3))
                s = moved.summary()
                fig = {
                    k: s[k]
                    for k in (
                        "dbh_m",
                        "height_m",
                        "volume_total_m3",
                        "volume_stem_m3",
                        "volume_branch_m3",
                        "n_cylinders",
                    )
                }
            self._truth[tree_id] = {
                "tree_id": t.tree_id,
                "source": t.source,
                "species": t.species,
                "x_m": t.x_m,
                "y_m": t.y_m,
                "base_z_m": float(bounds[0, 2]),
                **fig,
                "bounds_m": bounds.tolist(),
                "triangles": self.tree_triangles(tree_id),
            }
        return dict(self._truth[tree_id])

    def frame(self) -> LocalFrame:
        """The plot's float64 frame: its centre at the terrain's height there (rounded to
        whole millimetres). Scans of the plot are cast around it, so any subset of its
        trees scanned from a station shares their float32 geometry with the whole."""
        cx, cy = self.centre_xy
        z = float(self.terrain.height_at(cx, cy))
        return LocalFrame(origin=(round(cx, 3), round(cy, 3), round(z, 3)))

    def terrain_part(self, margin_m: float = 2.0) -> MeshPart:
        """The terrain over the plot's square plus ``margin_m``, labelled ``ground``."""
        r = self.radius_m + margin_m
        cx, cy = self.centre_xy
        return self.terrain.mesh((cx - r, cy - r), (cx + r, cy + r), self.terrain_cell_m)

    def scene(
        self, tree_ids: Iterable[int] | None = None, *, terrain: bool = True, margin_m: float = 2.0
    ) -> Scene:
        """The plot as one :class:`Scene`: the trees (all, or ``tree_ids``) and the terrain
        over the plot's square plus ``margin_m``."""
        ids = self.tree_ids if tree_ids is None else list(tree_ids)
        parts: list[MeshPart] = []
        for tid in ids:
            parts += self.tree_parts(tid)
        if terrain:
            parts.append(self.terrain_part(margin_m))
        return Scene(parts)
