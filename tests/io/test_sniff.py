"""Files known by their bytes (``sniff_format``) and read and checked whole
(``inspect_file``): every format with a misleading or missing name, exact counts and
bounds, and every way a file can be bad, each one treesim error with a reason. A property:
any bytes, and any truncation of a valid file, give a FileInfo or a TreesimError, never
another exception."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from treesim.cloud import Cloud
from treesim.errors import (
    EmptyInputError,
    InputFormatError,
    InvalidGeometryError,
    TreesimError,
    UnsupportedFormatError,
)
from treesim.io import inspect_file, sniff_format, write_cloud, write_mesh

from .conftest import GEO_ORIGIN

BUNDLED = Path(__file__).resolve().parents[2] / "pipeline" / "data" / "coffee_tree" / "cloud.txt"


def _cloud(n: int = 500) -> Cloud:
    rng = np.random.default_rng(11)
    pts = GEO_ORIGIN + rng.uniform(-2.0, 2.0, (n, 3))
    return Cloud(pts, {"intensity": rng.integers(0, 65535, n).astype(np.uint16)})


def _anonymous(path: Path) -> Path:
    """The file renamed to a name that says nothing (as an upload is stored)."""
    target = path.with_name(f"blob-{path.suffix[1:]}")
    path.rename(target)
    return target


@pytest.mark.parametrize("suffix, fmt", [(".laz", "laz"), (".las", "las"), (".ply", "ply"),
                                         (".xyz", "xyz")])  # fmt: skip
def test_clouds_by_their_bytes(tmp_path, suffix, fmt):
    cloud = _cloud()
    path = _anonymous(write_cloud(tmp_path / f"c{suffix}", cloud))
    assert sniff_format(path, filename="misleading.obj") == fmt
    info = inspect_file(path, filename="misleading.obj")
    assert (info.format, info.kind, info.suffix) == (fmt, "cloud", suffix)
    assert info.n_points == 500 and info.n_triangles is None
    tol = 1e-4 if fmt in ("las", "laz") else 1e-9  # LAS stores 0.1 mm integers
    np.testing.assert_allclose(info.bounds[0], cloud.points.min(0), atol=tol, rtol=0)
    np.testing.assert_allclose(info.bounds[1], cloud.points.max(0), atol=tol, rtol=0)
    assert "intensity" in info.fields
    json.dumps(info.to_dict())


def _box() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    m = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl", ".off"])
def test_meshes_by_their_bytes(tmp_path, suffix):
    import trimesh

    v, f = _box()
    path = tmp_path / f"box{suffix}"
    if suffix in (".ply", ".obj"):
        write_mesh(path, v, f)
    else:
        trimesh.Trimesh(v, f, process=False).export(path)
    path = _anonymous(path)
    assert sniff_format(path) == suffix[1:]
    info = inspect_file(path, filename="box.las")
    assert info.kind == "mesh" and info.n_triangles == 12 and info.n_points >= 8
    np.testing.assert_allclose(info.bounds[0], [-0.5, -1.0, -1.5])
    np.testing.assert_allclose(info.bounds[1], [0.5, 1.0, 1.5])


def test_ascii_stl_and_glb(tmp_path):
    import trimesh

    v, f = _box()
    mesh = trimesh.Trimesh(v, f, process=False)
    ascii_stl = tmp_path / "a"
    ascii_stl.write_bytes(trimesh.exchange.stl.export_stl_ascii(mesh).encode())
    assert sniff_format(ascii_stl) == "stl"
    glb = tmp_path / "g"
    glb.write_bytes(mesh.export(file_type="glb"))
    assert sniff_format(glb) == "glb"
    assert inspect_file(glb).n_triangles == 12


def test_text_variants(tmp_path):
    p = tmp_path / "t"
    p.write_text("x,y,z,intensity\n1,2,3,4\n5,6,7,8\n")
    assert sniff_format(p) == "xyz"
    info = inspect_file(p)
    assert info.n_points == 2 and info.bounds == ([1.0, 2.0, 3.0], [5.0, 6.0, 7.0])
    p.write_text("# a comment\n2\n1 2 3\n4 5 6\n")  # .pts: a point count first
    assert sniff_format(p) == "xyz" and inspect_file(p).n_points == 2
    p.write_text("o tree\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert sniff_format(p) == "obj" and inspect_file(p).n_triangles == 1


def test_the_bundled_tree():
    n = sum(1 for line in BUNDLED.read_text().splitlines() if line.strip())
    info = inspect_file(BUNDLED)
    assert (info.format, info.kind, info.n_points) == ("xyz", "cloud", n)


def test_empty_file(tmp_path):
    p = tmp_path / "e"
    p.write_bytes(b"")
    with pytest.raises(EmptyInputError, match="empty"):
        inspect_file(p, filename="tree.laz")


def test_prose_named_las_is_unsupported(tmp_path):
    p = tmp_path / "x"
    p.write_text("Dear editor,\nthis is not a point cloud.\n")
    with pytest.raises(UnsupportedFormatError, match="tree.las: text that is not"):
        inspect_file(p, filename="tree.las")


def test_binary_garbage_is_unsupported(tmp_path):
    p = tmp_path / "x"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    with pytest.raises(UnsupportedFormatError, match="starts with"):
        inspect_file(p, filename="tree.png")


@pytest.mark.parametrize("suffix", [".laz", ".las", ".ply"])
def test_truncated_binary_clouds(tmp_path, suffix):
    path = write_cloud(tmp_path / f"c{suffix}", _cloud(5000))
    data = path.read_bytes()
    cut = tmp_path / "cut"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputFormatError) as err:
        inspect_file(cut, filename=f"tree{suffix}")
    assert f"tree{suffix}" in str(err.value)
    assert str(tmp_path) not in str(err.value)  # messages name the upload, not our paths


def test_truncated_las_says_how_many_points(tmp_path):
    path = write_cloud(tmp_path / "c.las", _cloud(1000))
    data = path.read_bytes()
    (tmp_path / "cut").write_bytes(data[:-100])
    with pytest.raises(InputFormatError, match=r"declares 1,000 points, the file holds 99\d"):
        inspect_file(tmp_path / "cut")


def test_nan_coordinates(tmp_path):
    p = tmp_path / "x"
    p.write_text("0 0 0\nnan 1 1\n1 2 inf\n3 3 3\n")
    with pytest.raises(InvalidGeometryError, match="2 points have NaN"):
        inspect_file(p, filename="t.xyz")
    pts = _cloud().points.copy()
    pts[[3, 7, 9], 1] = np.nan
    ply = _anonymous(write_cloud(tmp_path / "n.ply", Cloud(pts)))
    with pytest.raises(InvalidGeometryError, match="3 points"):
        inspect_file(ply)


def test_a_mesh_without_triangles(tmp_path):
    p = tmp_path / "x"
    p.write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises((EmptyInputError, InputFormatError)):
        inspect_file(p)


def test_las_header_cut_short(tmp_path):
    p = tmp_path / "x"
    p.write_bytes(b"LASF" + b"\x00" * 50)
    with pytest.raises(InputFormatError, match="complete"):
        inspect_file(p, filename="tree.las")


def test_an_stl_header_with_a_wrong_count_is_not_stl(tmp_path):
    p = tmp_path / "x"
    p.write_bytes(b"\x01" * 80 + struct.pack("<I", 5) + b"\x00" * 10)
    with pytest.raises(UnsupportedFormatError):
        sniff_format(p)


# -- property: nothing but a FileInfo or a TreesimError ---------------------------------------
hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies


def _outcome(path: Path) -> str:
    try:
        inspect_file(path)
    except TreesimError:
        return "refused"
    return "read"


@hypothesis.settings(max_examples=60, deadline=None, derandomize=True)
@hypothesis.given(data=st.binary(max_size=2000))
def test_any_bytes_are_read_or_refused(tmp_path_factory, data):
    p = tmp_path_factory.mktemp("any") / "x"
    p.write_bytes(data)
    _outcome(p)


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory) -> dict[str, bytes]:
    d = tmp_path_factory.mktemp("valid")
    out = {s: write_cloud(d / f"c{s}", _cloud(300)).read_bytes() for s in (".laz", ".las", ".ply")}
    v, f = _box()
    out[".obj"] = write_mesh(d / "m.obj", v, f).read_bytes()
    return out


@hypothesis.settings(max_examples=80, deadline=None, derandomize=True)
@hypothesis.given(
    which=st.sampled_from([".laz", ".las", ".ply", ".obj"]),
    keep=st.floats(0.0, 1.0),
    flip=st.integers(0, 10**6),
)
def test_any_truncation_or_bit_flip_is_read_or_refused(tmp_path_factory, valid_files, which,
                                                       keep, flip):  # fmt: skip
    data = bytearray(valid_files[which][: int(len(valid_files[which]) * keep)])
    if data and flip % 3 == 0:
        data[flip % len(data)] ^= 0xFF
    p = tmp_path_factory.mktemp("cut") / "x"
    p.write_bytes(bytes(data))
    _outcome(p)
