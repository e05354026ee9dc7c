"""Tree ids on scene parts reach every scanned point (and the cloud files)."""

from __future__ import annotations

import numpy as np
import pytest

from treesim.errors import InvalidParameterError
from treesim.io import read_cloud, write_cloud
from treesim.scan import ScannerSpec, Station, scan, scan_fields
from treesim.scene import MeshPart, Scene


def _box(centre, tree_id, label="wood"):
    c = np.asarray(centre, dtype=float)
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-1, 1)])
    faces = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    return MeshPart(corners + c, faces, label, f"box{tree_id}", tree_id=tree_id)


def test_every_point_carries_the_tree_it_hit(tmp_path):
    centres = {1: (5.0, 0.0, 1.0), 2: (0.0, 5.0, 1.0), 7: (-5.0, 0.0, 1.0)}
    scene = Scene([_box(c, t) for t, c in centres.items()])
    assert scene.tree_ids == [1, 2, 7]
    spec = ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5)
    cloud = scan(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec).cloud
    ids = cloud.fields["tree_id"]
    assert ids.dtype == np.uint32
    assert set(np.unique(ids)) == set(centres)
    for t, c in centres.items():
        p = cloud.points[ids == t]
        # each point lies on its own box (1 x 1 x 2 m), nowhere else
        assert np.all(np.abs(p - c) <= np.array([0.5, 0.5, 1.0]) + 1e-9)
    for suffix in (".laz", ".ply"):
        write_cloud(tmp_path / f"s{suffix}", cloud)
        back = read_cloud(tmp_path / f"s{suffix}")
        np.testing.assert_array_equal(back.fields["tree_id"], ids)


def test_a_scene_without_trees_has_no_tree_field():
    scene = Scene([_box((5.0, 0.0, 1.0), 0)])
    assert scene.face_tree is None and scene.tree_ids == []
    assert "tree_id" not in scan_fields(scene)
    # terrain (0) beside a tree: the terrain's points read 0
    both = Scene([_box((5.0, 0.0, 1.0), 3), _box((-5.0, 0.0, 1.0), 0, "ground")])
    assert both.tree_ids == [0, 3]


@pytest.mark.parametrize("bad", [-1, 2**32, 1.5, True, "3"])
def test_bad_tree_ids_are_refused(bad):
    with pytest.raises(InvalidParameterError, match="tree_id"):
        _box((0, 0, 0), bad)


def test_labelled_parts_keep_only_their_own_vertices():
    from treesim.models import generate_tree
    from treesim.scene import labelled_parts

    v, f, lab = generate_tree("aspen-leafon", seed=3).mesh(facets=8)
    parts = labelled_parts(v, f, lab, tree_id=4)
    assert sum(len(p.vertices) for p in parts) == len(np.unique(f))
    assert all(p.tree_id == 4 for p in parts)
    # the same triangles, in the same order, as parts that share the whole array
    shared = Scene([MeshPart(v, f[lab == c], p.label, p.name) for c, p in
                    zip(np.unique(lab), parts, strict=True)])  # fmt: skip
    compact = Scene(parts)
    np.testing.assert_array_equal(compact.vertices[compact.faces], shared.vertices[shared.faces])
    np.testing.assert_array_equal(compact.face_label, shared.face_label)
    assert len(compact.vertices) < len(shared.vertices)
    spec = ScannerSpec(horizontal_resolution_deg=0.3, vertical_resolution_deg=0.3)
    st = [Station(position_m=(12.0, 0.0, 1.5))]
    a, b = scan(compact, st, spec).cloud, scan(shared, st, spec).cloud
    assert len(a) > 1000
    np.testing.assert_array_equal(a.points, b.points)
    for k in ("label", "range_m", "intensity"):
        np.testing.assert_array_equal(a.fields[k], b.fields[k])
