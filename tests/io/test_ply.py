"""PLY: double coordinates, typed properties, metadata comments, meshes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plyfile
import pytest

from treesim.cloud import LABEL_NAMES, Cloud
from treesim.errors import InputFormatError
from treesim.io import read_cloud, write_cloud


def test_round_trip_is_exact(tmp_path: Path, geo_cloud: Cloud) -> None:
    path = write_cloud(tmp_path / "geo.ply", geo_cloud)
    cloud = read_cloud(path)
    np.testing.assert_array_equal(cloud.points, geo_cloud.points)
    assert list(cloud.fields) == list(geo_cloud.fields)
    for name, values in geo_cloud.fields.items():
        assert cloud.fields[name].dtype == values.dtype, name
        np.testing.assert_array_equal(cloud.fields[name], values, name)
    assert cloud.metadata["label_names"] == LABEL_NAMES
    assert cloud.metadata["scanner"] == {"fov": 300}


def test_header_has_double_xyz_and_comments(tmp_path: Path, geo_cloud: Cloud) -> None:
    path = write_cloud(tmp_path / "geo.ply", geo_cloud)
    data = plyfile.PlyData.read(str(path))
    assert not data.text
    assert data.byte_order == "<"
    types = {p.name: p.val_dtype for p in data["vertex"].properties}
    assert types["x"] == types["y"] == types["z"] == "f8"
    assert "treesim label_names 0=other,1=wood,2=leaf,3=ground" in data.comments


def test_bool_and_int64_fields(tmp_path: Path) -> None:
    cloud = Cloud(
        np.zeros((2, 3)),
        {"hit": np.array([True, False]), "index": np.array([0, 7], dtype=np.int64)},
    )
    back = read_cloud(write_cloud(tmp_path / "a.ply", cloud))
    assert back.fields["hit"].dtype == np.uint8
    np.testing.assert_array_equal(back.fields["hit"], [1, 0])
    assert back.fields["index"].dtype == np.int32
    np.testing.assert_array_equal(back.fields["index"], [0, 7])


def test_mesh_ply_reads_vertices(tmp_path: Path) -> None:
    vertex = np.array(
        [(0.0, 0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 2.0), (0.0, 1.0, 0.5, 3.0)],
        dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("quality", "f4")],
    )
    face = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    plyfile.PlyData(
        [plyfile.PlyElement.describe(vertex, "vertex"), plyfile.PlyElement.describe(face, "face")],
        text=True,
    ).write(str(tmp_path / "mesh.ply"))
    cloud = read_cloud(tmp_path / "mesh.ply")
    assert cloud.points.dtype == np.float64
    np.testing.assert_array_equal(cloud.points, [[0, 0, 0], [1, 0, 0], [0, 1, 0.5]])
    assert list(cloud.fields) == ["quality"]
    assert cloud.fields["quality"].dtype == np.float32


def test_big_endian_ply(tmp_path: Path) -> None:
    vertex = np.array(
        [(5e5, 5.5e6, 1.0, 9)], dtype=[("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("i", ">u2")]
    )
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], byte_order=">").write(
        str(tmp_path / "be.ply")
    )
    cloud = read_cloud(tmp_path / "be.ply")
    np.testing.assert_array_equal(cloud.points, [[5e5, 5.5e6, 1.0]])
    assert cloud.fields["i"].dtype == np.dtype("=u2")
    assert cloud.fields["i"][0] == 9


def test_ply_without_vertices(tmp_path: Path) -> None:
    edge = np.array([(0, 1)], dtype=[("a", "i4"), ("b", "i4")])
    plyfile.PlyData([plyfile.PlyElement.describe(edge, "edge")]).write(str(tmp_path / "e.ply"))
    with pytest.raises(InputFormatError, match="vertex"):
        read_cloud(tmp_path / "e.ply")


def test_corrupt_ply(tmp_path: Path, geo_cloud: Cloud) -> None:
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nformat nonsense\nend_header\n")
    with pytest.raises(InputFormatError, match="PLY"):
        read_cloud(garbage)
    data = write_cloud(tmp_path / "geo.ply", geo_cloud).read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-20])
    with pytest.raises(InputFormatError):
        read_cloud(tmp_path / "cut.ply")
