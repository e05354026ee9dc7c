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

The parameters and the species presets are in :mod:`treesim.models.species` (the presets
as data, ``treesim/data/species.toml``); the builder that grows them is
:mod:`treesim.models.builder`. This module puts them together: :func:`generate_tree` and
the tree it returns, :class:`ProceduralTree`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cloud import LABEL_CODES
from ..errors import InvalidParameterError
from .builder import MIN_JUNCTION_FACETS, TreeBuilder
from .cylinders import CylinderTable
from .mesh import TubeMesh, mesh_volume, tubes_to_mesh
from .species import (
    CHILD_RADIUS_LIMIT,
    LEAF_SHAPES,
    SHAPES,
    SPECIES,
    LeafParams,
    StemLevel,
    TreeParams,
    shape_ratio,
    species_preset,
)

__all__ = [
    "CHILD_RADIUS_LIMIT",
    "LEAF_SHAPES",
    "MIN_JUNCTION_FACETS",
    "SHAPES",
    "SPECIES",
    "LeafParams",
    "ProceduralTree",
    "StemLevel",
    "TreeParams",
    "generate_tree",
    "shape_ratio",
    "species_preset",
]


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
    builder = TreeBuilder(params, wood_rng)
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
