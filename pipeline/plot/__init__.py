"""Forest plots: trees with positions and ids on a terrain, as one scannable scene (the
core: :mod:`treesim.plot.core`; files: :mod:`.io`; stands: :mod:`.generate`; scanning:
:mod:`.scan`).

A :class:`Plot` is a set of :class:`PlotTree` (each a procedural species, a mesh file, a
QSM table or a field cloud to reconstruct, placed at ``(x_m, y_m)`` on the terrain and
turned by ``rotation_deg`` about its stem base) and a :class:`Terrain` (flat, a plane
sloping down towards an aspect, a DTM raster or a ground cloud). Every tree's triangles
carry its ``tree_id`` (>= 1; the terrain 0), so a scan of the plot labels each point with
the tree it hit (:func:`treesim.scan.scan_fields`).

Coordinates are metres in the plot's frame: x east, y north, z up; the terrain's height
at the plot centre is its ``z0_m``. A tree's stem base stands on the terrain's lowest
point under its stem (on a slope, the uphill side of the stem is buried, none of it
floats).
"""

from .core import TERRAIN_KINDS, TREE_SOURCES, Plot, PlotTree, Terrain

__all__ = [
    "TERRAIN_KINDS",
    "TREE_SOURCES",
    "Plot",
    "PlotTree",
    "Terrain",
]
