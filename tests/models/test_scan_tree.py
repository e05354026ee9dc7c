"""A leaf-on procedural tree through the virtual scanner: leaf and wood hits labelled right."""

from __future__ import annotations

import numpy as np

from tests.models.geometry import near_distances
from treesim.cloud import LABEL_CODES
from treesim.scan import ScannerSpec, ring_layout, scan
from treesim.scene import MeshPart, Scene

#: Hits are refined in float64 onto their triangle (the scanner's promise is ~1e-9 m; at
#: triangle edges a hit may sit on the plane just outside): a hit is "on" a part within this.
ON_SURFACE_M = 1e-6
#: Distances to the other part are computed exactly up to this reach (beyond: farther).
REACH_M = 0.002


def test_scan_of_a_leaf_on_tree_labels_every_hit_right(preset_trees) -> None:
    tree = preset_trees["aspen-leafon"]
    wood = tree.wood_mesh(16)
    scene = Scene(
        [
            MeshPart(vertices=wood.vertices, faces=wood.faces, label="wood", name="wood"),
            MeshPart(
                vertices=tree.leaf_vertices, faces=tree.leaf_faces, label="leaf", name="leaves"
            ),
        ]
    )
    assert scene.dropped_degenerate == 0
    lo, hi = scene.bounds
    stations = ring_layout(
        3,
        distance_m=12.0,
        height_m=1.5,
        centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
        base_z_m=float(lo[2]),
    )
    spec = ScannerSpec(horizontal_resolution_deg=0.2, vertical_resolution_deg=0.2)
    result = scan(scene, stations, spec, nthreads=2)
    points = result.cloud.points
    label = result.cloud.fields["label"]
    n_wood = int((label == LABEL_CODES["wood"]).sum())
    n_leaf = int((label == LABEL_CODES["leaf"]).sum())
    assert n_wood > 1000 and n_leaf > 1000 and n_wood + n_leaf == len(points)
    assert set(np.unique(result.cloud.fields["station"])) == {0, 1, 2}

    # Exact float64 distances from every hit to each part (Open3D's closest-point query
    # is float32 and, on these long thin triangles, off by up to ~0.7 mm: not used).
    d_wood = near_distances(points, wood.vertices, wood.faces, REACH_M)
    d_leaf = near_distances(points, tree.leaf_vertices, tree.leaf_faces, REACH_M)
    is_wood = label == LABEL_CODES["wood"]
    own = np.where(is_wood, d_wood, d_leaf)
    other = np.where(is_wood, d_leaf, d_wood)
    assert own.max() < ON_SURFACE_M  # every hit lies on a triangle of its labelled part
    assert (other > own).all()  # ... and the other part is farther away
    # Leaves never touch the wood: no hit lies on both.
    assert (other > ON_SURFACE_M).all()
