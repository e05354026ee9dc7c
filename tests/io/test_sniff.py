"""Files known by their bytes (``sniff_format``) and read and checked whole
(``inspect_file``): every format with a misleading or missing name, exact counts and
bounds, and every way a file can be bad, each one treesim error with a reason. A property:
any bytes, and any truncation of a valid file, give a FileInfo or a TreesimError, never
another exception."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
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
from treesim.io import FileInfo, inspect_file, sniff_format, write_cloud, write_mesh

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
# Each example's outcome is checked against what the test knows of the bytes: the magic
# numbers of the formats, the counts and bounds of the rows it wrote, whether it cut a
# binary file short.
hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies

#: The first bytes of each binary format, as the formats' specifications give them.
MAGIC = {"las": b"LASF", "laz": b"LASF", "ply": b"ply", "glb": b"glTF", "e57": b"ASTM-E57"}


def _outcome(path: Path) -> FileInfo | TreesimError:
    try:
        return inspect_file(path)
    except TreesimError as exc:
        return exc


def _could_come_from(info: FileInfo, data: bytes) -> None:
    """A FileInfo read from ``data`` names a format those bytes can be, and sane figures."""
    if info.format in MAGIC:
        assert data.startswith(MAGIC[info.format]), (info.format, data[:8])
    elif info.format == "stl" and not data[:5].lower() == b"solid":
        assert len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]
    else:  # the text formats
        assert b"\x00" not in data, info.format
    lo, hi = np.asarray(info.bounds[0]), np.asarray(info.bounds[1])
    assert info.n_points >= 1 and np.isfinite(lo).all() and (lo <= hi).all(), info


@hypothesis.settings(max_examples=60, deadline=None, derandomize=True)
@hypothesis.given(
    data=st.one_of(
        st.binary(max_size=2000),
        # text of numbers, some of it XYZ rows: what a sniffer may take for a cloud
        st.text(alphabet="0123456789 .-e,\n", max_size=400).map(str.encode),
    )
)
def test_any_bytes_are_read_or_refused(tmp_path_factory, data):
    p = tmp_path_factory.mktemp("any") / "x"
    p.write_bytes(data)
    got = _outcome(p)
    if not data:
        assert isinstance(got, EmptyInputError)
    elif isinstance(got, FileInfo):
        _could_come_from(got, data)


_coord = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@hypothesis.settings(max_examples=40, deadline=None, derandomize=True)
@hypothesis.given(
    rows=st.lists(st.tuples(_coord, _coord, _coord), min_size=1, max_size=40),
    sep=st.sampled_from([" ", ",", "\t", ", "]),
    newline=st.sampled_from(["\n", "\r\n"]),
)
def test_any_xyz_rows_are_read_exactly(tmp_path_factory, rows, sep, newline):
    # the rows written with repr (which round-trips a float64): every row read, the
    # bounds the rows' own minimum and maximum, exactly
    p = tmp_path_factory.mktemp("xyz") / "x"
    p.write_text("".join(sep.join(map(repr, r)) + newline for r in rows), encoding="utf-8")
    got = _outcome(p)
    assert isinstance(got, FileInfo), got
    assert (got.format, got.kind, got.n_points) == ("xyz", "cloud", len(rows))
    xyz = np.array(rows, dtype=np.float64)
    np.testing.assert_array_equal(got.bounds[0], xyz.min(axis=0))
    np.testing.assert_array_equal(got.bounds[1], xyz.max(axis=0))


#: Flip each byte of a LAS/LAZ file's header and VLRs, the first 8 bytes after them (a
#: LAZ's chunk table offset) and its last 8 (the chunk table), one at a time, and inspect.
_FLIP_HEADER_BYTES = """
import struct, sys
from pathlib import Path
from treesim.errors import TreesimError
from treesim.io import inspect_file
src, dst = Path(sys.argv[1]), Path(sys.argv[2])
data = src.read_bytes()
(offset,) = struct.unpack_from("<I", data, 96)
for i in [*range(offset + 8), *range(len(data) - 8, len(data))]:
    b = bytearray(data)
    b[i] ^= 0xFF
    dst.write_bytes(bytes(b))
    try:
        inspect_file(dst)
    except TreesimError:
        pass
    except BaseException as exc:
        sys.exit(f"byte {i} flipped: {type(exc).__name__}: {exc}")
"""


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_every_las_header_byte_flipped_is_read_or_refused(tmp_path, suffix):
    # deterministic where the property below samples: every byte of the part of the file
    # that says how much to read. In a child process: a corrupt LAZ can abort the process
    src = write_cloud(tmp_path / f"c{suffix}", _cloud(300))
    done = subprocess.run(
        [sys.executable, "-c", _FLIP_HEADER_BYTES, str(src), str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "RUST_BACKTRACE": "0"},
    )
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory) -> dict[str, bytes]:
    d = tmp_path_factory.mktemp("valid")
    out = {s: write_cloud(d / f"c{s}", _cloud(300)).read_bytes() for s in (".laz", ".las", ".ply")}
    v, f = _box()
    out[".obj"] = write_mesh(d / "m.obj", v, f).read_bytes()
    return out


def _obj_faces(data: bytes) -> list[list[int]]:
    """The faces a (possibly cut) OBJ holds: its ``f`` lines with at least three vertex
    indices, the last, cut line included when it still has three."""
    lines = data.decode("utf-8").split("\n")
    return [[int(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("f ")
            and len(ln.split()) >= 4]  # fmt: skip


@hypothesis.settings(max_examples=80, deadline=None, derandomize=True)
@hypothesis.given(
    which=st.sampled_from([".laz", ".las", ".ply", ".obj"]),
    keep=st.one_of(st.just(1.0), st.floats(0.0, 1.0)),  # whole files too, cut or flipped
    flip=st.one_of(st.none(), st.integers(0, 10**6)),
)
def test_any_truncation_or_bit_flip_is_read_or_refused(tmp_path_factory, valid_files, which,
                                                       keep, flip):  # fmt: skip
    whole = valid_files[which]
    data = bytearray(whole[: int(len(whole) * keep)])
    flipped = bool(data) and flip is not None
    if flipped:
        data[flip % len(data)] ^= 0xFF
    p = tmp_path_factory.mktemp("cut") / "x"
    p.write_bytes(bytes(data))
    got = _outcome(p)
    n_points, n_triangles = (8, 12) if which == ".obj" else (300, None)
    if isinstance(got, FileInfo):
        _could_come_from(got, bytes(data))
        # nothing read that the file did not hold
        assert got.kind == ("mesh" if which == ".obj" else "cloud")
        assert got.n_points <= n_points and (got.n_triangles or 0) <= (n_triangles or 0)
    if flipped:
        return
    if len(data) == len(whole):  # untouched: read whole
        assert isinstance(got, FileInfo), got
        assert (got.n_points, got.n_triangles) == (n_points, n_triangles)
    elif which != ".obj":  # a binary cloud cut short says so
        assert isinstance(got, TreesimError), got
    else:  # a cut OBJ is read up to its last whole face (vertices all come first)
        faces = _obj_faces(bytes(data))
        if faces:
            assert isinstance(got, FileInfo), got
            assert got.n_triangles == len(faces)
            assert got.n_points == len({i for f in faces for i in f})
        else:
            assert isinstance(got, TreesimError), got
