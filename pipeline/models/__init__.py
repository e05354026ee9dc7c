"""Tree models: cylinder tables (QSMs), their readers and writers, and their meshes."""

from __future__ import annotations

from .cylinders import (
    AXIS_NORM_TOLERANCE,
    CYLINDER_TAGS,
    FORMATS,
    TREESIM_COLUMNS,
    CylinderTable,
    read_cylinders,
    write_cylinders,
)
from .mesh import (
    cylinder_mesh,
    cylinders_to_mesh,
    faces_per_cylinder,
    mesh_volume,
    vertices_per_cylinder,
)

__all__ = [
    "AXIS_NORM_TOLERANCE",
    "CYLINDER_TAGS",
    "FORMATS",
    "TREESIM_COLUMNS",
    "CylinderTable",
    "cylinder_mesh",
    "cylinders_to_mesh",
    "faces_per_cylinder",
    "mesh_volume",
    "read_cylinders",
    "vertices_per_cylinder",
    "write_cylinders",
]
