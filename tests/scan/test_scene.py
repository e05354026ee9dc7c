"""Loading scenes: formats, part labels, validation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tests.conftest import box_arrays, shared_path
from treesim.errors import EmptyInputError, InputFormatError, InvalidGeometryError
from treesim.io import load_mesh, load_scene
from treesim.io.mesh import write_mesh
from treesim.scan import ScannerSpec, Station, scan
from treesim.scene import label_from_name


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".off", ".glb"])
def test_every_mesh_format_loads_with_float64_vertices(tmp_path, suffix):
    v, f = box_arrays((0.0, 0.0, 0.0), (1.0, 2.0, 3.0))
    path = tmp_path / f"box{suffix}"
    trimesh.Trimesh(v, f, process=False).export(path)
    scene = load_scene([path])
    assert scene.n_triangles == 12
    assert scene.vertices.dtype == np.float64
    # integer corners are exact in every format, float32 ones (STL, GLB) included
    np.testing.assert_array_equal(scene.bounds, [[0, 0, 0], [1, 2, 3]])


def test_treesim_meshes_keep_georeferenced_precision_and_labels(tmp_path):
    v, f = box_arrays((500000.123456, 5500000.654321, 300.0), (500001.0, 5500001.0, 301.0))
    lab = np.array([1] * 6 + [2] * 6, dtype=np.uint8)
    for suffix in (".ply", ".obj"):
        path = write_mesh(tmp_path / f"m{suffix}", v, f, face_label=lab)
        parts = load_mesh(path)
        assert sorted(p.label for p in parts) == ["leaf", "wood"]
        for p in parts:
            assert np.abs(p.vertices.min(axis=0) - v.min(axis=0)).max() == 0.0


@pytest.mark.parametrize(
    ("name", "label"),
    [
        ("Leaves", "leaf"),
        ("TrunkAndBranches", "wood"),
        ("needles_01", "leaf"),
        ("Terrain", "ground"),
        ("bark", "wood"),
        ("Material.001", "other"),
    ],
)
def test_labels_from_group_and_material_names(name, label):
    assert label_from_name(name) == label


def test_caller_label_overrides_names(tmp_path):
    v, f = box_arrays((0, 0, 0), (1, 1, 1))
    path = write_mesh(tmp_path / "x.obj", v, f)
    assert {p.label for p in load_mesh(path, label="ground")} == {"ground"}


def test_degenerate_triangles_are_dropped_and_counted(tmp_path):
    v, f = box_arrays((0, 0, 0), (1, 1, 1))
    v = np.vstack([v, [[5, 5, 5]]])
    f = np.vstack([f, [[0, 0, 8]], [[1, 8, 8]]])
    from treesim.scene import MeshPart, Scene

    scene = Scene([MeshPart(vertices=v, faces=f, label="wood")])
    assert scene.n_triangles == 12 and scene.dropped_degenerate == 2


def test_bad_meshes_are_refused(tmp_path):
    with pytest.raises(InputFormatError, match="not found"):
        load_mesh(tmp_path / "none.obj")
    (tmp_path / "pts.obj").write_text("v 0 0 0\nv 1 1 1\n")
    with pytest.raises(EmptyInputError, match="no triangles"):
        load_mesh(tmp_path / "pts.obj")
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n")
    with pytest.raises(InvalidGeometryError, match="NaN"):
        load_scene([tmp_path / "nan.obj"])


def test_helios_apple_sapling_parts_are_labelled_and_scanned():
    path = shared_path("models", "apple_sapling", "tree1_leafon.obj")
    scene = load_scene([path])
    assert set(scene.labels_present()) == {"wood", "leaf"}
    lo, hi = scene.bounds
    c = (lo + hi) / 2
    res = scan(
        scene,
        [Station(position_m=(c[0] + 6.0, c[1], lo[2] + 1.5))],
        ScannerSpec(horizontal_resolution_deg=0.1, vertical_resolution_deg=0.1),
    )
    labels = set(np.unique(res.cloud.fields["label"]).tolist())
    assert labels == {1, 2}  # wood and leaf both hit
