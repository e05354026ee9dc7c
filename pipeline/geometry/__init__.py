"""Geometry kernels shared by the stages (compare, reconstruct, scan).

At the bottom of the package, beside ``cloud``, ``frame`` and ``io``: it imports only
``treesim.errors``. Coordinates are metres, float64, preferably in a
:class:`~treesim.frame.LocalFrame`.

* :mod:`~treesim.geometry.triangles`: exact point-to-triangle and point-to-mesh distances,
  and the triangles around vertices;
* :mod:`~treesim.geometry.sampling`: area-uniform sampling of a mesh surface;
* :mod:`~treesim.geometry.hidden`: a mesh's closed parts, and which points on it lie
  inside another closed part (surface no scanner outside can see);
* :mod:`~treesim.geometry.spacing`: a cloud's nearest-neighbour spacing, k-d trees.
"""

from .hidden import MeshParts, inside_other_parts, mesh_parts
from .sampling import sample_surface
from .spacing import kdtree, point_spacing
from .triangles import (
    closest_points_on_triangles,
    point_to_mesh_distances,
    triangles_around,
    vertex_triangles,
    well_conditioned,
)

__all__ = [
    "MeshParts",
    "closest_points_on_triangles",
    "inside_other_parts",
    "kdtree",
    "mesh_parts",
    "point_spacing",
    "point_to_mesh_distances",
    "sample_surface",
    "triangles_around",
    "vertex_triangles",
    "well_conditioned",
]
