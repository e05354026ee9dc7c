"""One tree as a plot to plan for: a procedural species, or a mesh file.

A single tree is planned as a plot of one tree (id 1) on flat ground at its stem base,
the candidates within ``radius_m`` of it: by default 1.5 × the station rule's distance
(:func:`treesim.scan.stations.station_distance_m`), so that the rule's ring lies well
inside the candidate area.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EmptyInputError
from ..io.mesh import load_mesh
from ..plot import Plot, PlotTree, Terrain
from ..scene import MeshPart
from .layouts import rule_distance_m

__all__ = ["mesh_tree_plot", "model_tree_plot", "species_tree_plot"]

#: The default candidate area of a single tree, in station-rule distances.
RADIUS_FACTOR = 1.5


def species_tree_plot(
    species: str,
    *,
    seed: int = 0,
    leaves: bool | None = None,
    facets: int = 16,
    radius_m: float | None = None,
) -> Plot:
    """A plot of one procedural tree at the origin on flat ground."""
    tree = PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species=species, seed=int(seed), leaves=leaves)
    plot = Plot([tree], radius_m=radius_m or 1.0, facets=facets)
    if radius_m is None:
        v = np.concatenate([p.vertices for p in plot.tree_parts(1)])
        plot.radius_m = RADIUS_FACTOR * rule_distance_m(v)
    return plot


def model_tree_plot(mp: Any, *, radius_m: float | None = None) -> tuple[Plot, dict[str, Any]]:
    """(plot, what): :func:`species_tree_plot` of the tree a
    :class:`treesim.params.models.ModelParams` names (``treesim plan --species``, the
    service's ``tree``), and its species, seed, leaves and facets (a plan's inputs)."""
    plot = species_tree_plot(
        str(mp.species), seed=mp.seed, leaves=mp.leaves, facets=mp.facets, radius_m=radius_m
    )
    return plot, {"species": mp.species, "seed": mp.seed, "leaves": mp.leaves, "facets": mp.facets}


class _MeshPlot(Plot):
    """A plot whose one tree is the mesh file's parts as read (``source="mesh"``), kept
    where the file has them: the file is read once, in :func:`mesh_tree_plot`, to find
    the stem base. The parts are held for good (one tree): :meth:`Plot.release` (a plot
    scan releases every tree it is done with) must not send :meth:`tree_parts` back to
    the file, which would place the tree again and keep the ground parts left out here."""

    def __init__(
        self,
        parts: list[MeshPart],
        tree: PlotTree,
        terrain: Terrain,
        radius_m: float,
        centre_xy: tuple[float, float],
    ) -> None:
        super().__init__([tree], terrain=terrain, radius_m=radius_m, centre_xy=centre_xy)
        self._held = parts
        # what Plot.tree_parts records as it builds a tree: bounds and triangles
        used = np.concatenate([np.asarray(p.vertices)[np.unique(p.faces)] for p in parts])
        self._bounds[tree.tree_id] = np.stack([used.min(axis=0), used.max(axis=0)])
        self._ntri[tree.tree_id] = int(sum(len(p.faces) for p in parts))

    def tree_parts(self, tree_id: int) -> list[MeshPart]:
        if tree_id == self.trees[0].tree_id:
            self._parts[tree_id] = self._held
        return super().tree_parts(tree_id)


def mesh_tree_plot(path: str | Path, *, radius_m: float | None = None) -> Plot:
    """A plot of the tree in a mesh file, where it stands: its stem base is the mean x, y
    of the vertices within 5 cm of its lowest point, on flat ground at that height."""
    parts = load_mesh(path)
    parts = [p for p in parts if p.label != "ground"]
    if not parts:
        raise EmptyInputError(f"{path}: no tree parts (every part is labelled ground)")
    v = np.concatenate([np.asarray(p.vertices, np.float64) for p in parts])
    low = v[:, 2] <= v[:, 2].min() + 0.05
    bx, by = (float(c) for c in v[low, :2].mean(axis=0))
    z0 = float(v[:, 2].min())
    parts = [MeshPart(p.vertices, p.faces, p.label, p.name, 1) for p in parts]
    tree = PlotTree(tree_id=1, x_m=bx, y_m=by, source="mesh", path=str(path))
    r = radius_m or RADIUS_FACTOR * rule_distance_m(v)
    return _MeshPlot(parts, tree, Terrain(z0_m=z0), r, (bx, by))
