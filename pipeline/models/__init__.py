"""Tree models: cylinder tables (QSMs), procedural trees, and their meshes.

* :mod:`.cylinders`: :class:`CylinderTable`, read (TreeQSM CSV and text export,
  SimpleForest, treesim CSV), validated, measured and written;
* :mod:`.mesh`: tables as triangle meshes, a closed prism per cylinder or a closed,
  mitred tube per branch (:func:`tubes_to_mesh`);
* :mod:`.junctions`: QSM tables meshed with closed junctions, each branch's tube
  starting inside its parent (:func:`branch_tubes`, :func:`sink_branches`);
* :mod:`.lod`: level of detail, facets per cylinder from the point spacing a scanner
  gets at it (:func:`lod_facets`, :func:`plan_lod`);
* :mod:`.procedural`: Weber & Penn trees (:func:`generate_tree`) whose cylinder table is
  the exact truth of their mesh, grown by :mod:`.builder` from the species presets of
  :mod:`.species` (:data:`SPECIES`, read from ``data/species.toml``).
"""

from __future__ import annotations

from .cylinders import (
    AXIS_NORM_TOLERANCE,
    CYLINDER_TAGS,
    FORMATS,
    TREEQSM_TEXT_COLUMNS,
    TREESIM_COLUMNS,
    CylinderTable,
    read_cylinders,
    write_cylinders,
)
from .junctions import SunkTable, branch_tubes, qsm_mesh, sink_branches
from .lod import LOD_MIN_FACETS, LOD_TOLERANCE, LodPlan, lod_facets, plan_lod
from .mesh import (
    JOINTS,
    TubeMesh,
    cylinder_mesh,
    cylinders_to_mesh,
    faces_per_cylinder,
    mesh_triangle_count,
    mesh_volume,
    meshed_facets,
    tubes_to_mesh,
    vertices_per_cylinder,
)
from .procedural import (
    LEAF_SHAPES,
    SHAPES,
    SPECIES,
    LeafParams,
    ProceduralTree,
    StemLevel,
    TreeParams,
    generate_tree,
    shape_ratio,
    species_preset,
)

__all__ = [
    "AXIS_NORM_TOLERANCE",
    "CYLINDER_TAGS",
    "FORMATS",
    "JOINTS",
    "LEAF_SHAPES",
    "LOD_MIN_FACETS",
    "LOD_TOLERANCE",
    "SPECIES",
    "SHAPES",
    "TREEQSM_TEXT_COLUMNS",
    "TREESIM_COLUMNS",
    "CylinderTable",
    "LeafParams",
    "LodPlan",
    "ProceduralTree",
    "StemLevel",
    "SunkTable",
    "TreeParams",
    "TubeMesh",
    "branch_tubes",
    "cylinder_mesh",
    "cylinders_to_mesh",
    "faces_per_cylinder",
    "generate_tree",
    "lod_facets",
    "mesh_triangle_count",
    "mesh_volume",
    "qsm_mesh",
    "meshed_facets",
    "plan_lod",
    "species_preset",
    "read_cylinders",
    "shape_ratio",
    "sink_branches",
    "tubes_to_mesh",
    "vertices_per_cylinder",
    "write_cylinders",
]
