"""Streaming writers: chunks read back like a whole write, atomic output, empty files."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from pathlib import Path

import laspy
import numpy as np
import plyfile
import pytest

from treesim.cloud import LABEL_NAMES, Cloud
from treesim.errors import InputFormatError, InvalidGeometryError, InvalidParameterError
from treesim.io import (
    CloudWriter,
    las,
    open_cloud_writer,
    read_cloud,
    supported_suffixes,
    write_cloud,
)
from treesim.io.ply import PlyCloudWriter

from .conftest import GEO_ORIGIN

SUFFIXES = [".las", ".laz", ".ply", ".xyz", ".csv"]

#: The fields of a simulated scan, plus a boolean and a 64-bit one.
FIELD_DTYPES = {
    "station": np.dtype(np.uint16),
    "range_m": np.dtype(np.float64),
    "incidence_deg": np.dtype(np.float32),
    "label": np.dtype(np.uint8),
    "return_number": np.dtype(np.uint8),
    "number_of_returns": np.dtype(np.uint8),
    "intensity": np.dtype(np.uint16),
    "scan_line": np.dtype(np.int32),
    "scan_column": np.dtype(np.int32),
    "hit": np.dtype(bool),
    "index": np.dtype(np.int64),
}

METADATA = {"label_names": dict(LABEL_NAMES), "scanner": {"fov": 300}}


def scan_cloud(n: int = 3000, seed: int = 0) -> Cloud:
    """A georeferenced cloud with every field of :data:`FIELD_DTYPES`."""
    rng = np.random.default_rng(seed)
    points = GEO_ORIGIN + rng.uniform(-20.0, 20.0, (n, 3))
    returns = rng.integers(1, 4, n)
    fields = {
        "station": rng.integers(0, 5, n),
        "range_m": rng.uniform(0.5, 80.0, n),
        "incidence_deg": rng.uniform(0.0, 90.0, n),
        "label": rng.integers(0, 4, n),
        "return_number": rng.integers(1, returns + 1),
        "number_of_returns": returns,
        "intensity": rng.integers(0, 65536, n),
        "scan_line": rng.integers(-10, 2_000_000, n),
        "scan_column": rng.integers(0, 5000, n),
        "hit": rng.random(n) < 0.5,
        "index": np.arange(n, dtype=np.int64),
    }
    fields = {k: np.asarray(v).astype(FIELD_DTYPES[k]) for k, v in fields.items()}
    return Cloud(points, fields, dict(METADATA))


def random_chunks(n: int, seed: int = 1) -> Iterator[slice]:
    """Slices covering ``range(n)`` in random sizes, with empty ones among them."""
    rng = np.random.default_rng(seed)
    start = 0
    while start < n:
        size = 0 if rng.random() < 0.2 else int(rng.integers(1, 700))
        yield slice(start, min(n, start + size))
        start += size
    yield slice(n, n)


def write_in_chunks(path: Path, cloud: Cloud, **options) -> CloudWriter:
    fields = {name: values.dtype for name, values in cloud.fields.items()}
    with open_cloud_writer(path, fields=fields, metadata=cloud.metadata, **options) as out:
        for part in random_chunks(len(cloud)):
            out.write(cloud.points[part], {k: v[part] for k, v in cloud.fields.items()})
    return out


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture
def small_batches(monkeypatch: pytest.MonkeyPatch) -> None:
    """LAS/LAZ hand laspy batches of 512 points: flushes inside and across chunks."""
    monkeypatch.setattr(las, "BATCH_POINTS", 512)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_chunks_read_back_like_a_whole_write(
    tmp_path: Path, suffix: str, small_batches: None
) -> None:
    cloud = scan_cloud()
    whole = read_cloud(write_cloud(tmp_path / f"whole{suffix}", cloud))
    writer = write_in_chunks(tmp_path / f"chunks{suffix}", cloud)
    assert writer.points_written == len(cloud)
    chunks = read_cloud(writer.path)

    if suffix in (".las", ".laz"):  # offsets differ (first chunk's minimum): scale-close
        tolerance = 1e-4 / 2 * (1 + 1e-6)
        assert np.abs(chunks.points - cloud.points).max() <= tolerance
        assert np.abs(whole.points - cloud.points).max() <= tolerance
    else:
        np.testing.assert_array_equal(chunks.points, whole.points)
    assert list(chunks.fields) == list(whole.fields)
    for name, values in whole.fields.items():
        assert chunks.fields[name].dtype == values.dtype, name
        np.testing.assert_array_equal(chunks.fields[name], values, name)
    if suffix in (".las", ".laz", ".ply"):
        assert chunks.metadata["label_names"] == LABEL_NAMES
        assert chunks.metadata["scanner"] == {"fov": 300}
    assert leftovers(tmp_path) == sorted([f"whole{suffix}", f"chunks{suffix}"])


@pytest.mark.parametrize("suffix", [".ply", ".xyz"])
def test_float64_precision(tmp_path: Path, suffix: str) -> None:
    cloud = scan_cloud(500)
    back = read_cloud(write_in_chunks(tmp_path / f"a{suffix}", cloud).path)
    if suffix == ".ply":
        np.testing.assert_array_equal(back.points, cloud.points)
        np.testing.assert_array_equal(back.fields["range_m"], cloud.fields["range_m"])
    else:  # text: 9 decimals for coordinates (1 nm plus float64's rounding), 15 digits
        np.testing.assert_allclose(back.points, cloud.points, rtol=0, atol=1e-9)
        np.testing.assert_allclose(back.fields["range_m"], cloud.fields["range_m"], rtol=1e-14)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_header_counts_and_bounds(tmp_path: Path, suffix: str, small_batches: None) -> None:
    cloud = scan_cloud()
    path = write_in_chunks(tmp_path / f"a{suffix}", cloud).path
    data = laspy.read(path)
    header = data.header
    assert header.point_count == len(cloud)
    xyz = np.column_stack([data.x, data.y, data.z])
    np.testing.assert_allclose(header.mins, xyz.min(axis=0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(header.maxs, xyz.max(axis=0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(header.mins, cloud.points.min(axis=0), rtol=0, atol=5e-5)
    by_return = np.bincount(cloud.fields["return_number"], minlength=16)[1:]
    np.testing.assert_array_equal(header.number_of_points_by_return, by_return)


def test_las_return_defaults_counted(tmp_path: Path) -> None:
    with open_cloud_writer(tmp_path / "a.laz", fields={}) as out:
        out.write(GEO_ORIGIN + np.zeros((3, 3)))
        out.write(GEO_ORIGIN + np.ones((2, 3)))
    data = laspy.read(tmp_path / "a.laz")
    np.testing.assert_array_equal(data.return_number, 1)
    np.testing.assert_array_equal(data.number_of_returns, 1)
    assert data.header.number_of_points_by_return[0] == 5


def test_las_offsets_from_hint_or_first_chunk(tmp_path: Path) -> None:
    points = GEO_ORIGIN + np.array([[0.0, 0.0, 0.0], [-7.5, 3.0, -2.25]])
    hint = GEO_ORIGIN - 100.5
    with open_cloud_writer(tmp_path / "hint.las", fields={}, origin_hint_m=hint) as out:
        out.write(points)
        assert np.array_equal(out.offsets, np.floor(hint))
    with open_cloud_writer(tmp_path / "first.las", fields={}) as out:
        out.write(np.empty((0, 3)))
        assert out.offsets is None
        out.write(points[:1])
        out.write(points[1:])  # below the first chunk's minimum: negative integers
    assert read_cloud(tmp_path / "hint.las").metadata["las_offsets"] == np.floor(hint).tolist()
    back = read_cloud(tmp_path / "first.las")
    assert back.metadata["las_offsets"] == np.floor(GEO_ORIGIN).tolist()
    np.testing.assert_allclose(back.points, points, rtol=0, atol=5e-5)


@pytest.mark.skipif(
    laspy.LazBackend.LazrsParallel not in laspy.LazBackend.detect_available(),
    reason="lazrs is not installed",
)
def test_parallel_laz_reads_back_with_default_and_sequential_backends(
    tmp_path: Path, small_batches: None
) -> None:
    cloud = scan_cloud()
    fields = {name: values.dtype for name, values in cloud.fields.items()}
    for threads, backend in [(0, laspy.LazBackend.LazrsParallel), (1, laspy.LazBackend.Lazrs)]:
        path = tmp_path / f"t{threads}.laz"
        with open_cloud_writer(path, fields=fields, threads=threads) as out:
            for part in random_chunks(len(cloud)):
                out.write(cloud.points[part], {k: v[part] for k, v in cloud.fields.items()})
            assert out.laz_backend == backend
        default = laspy.read(path)
        sequential = laspy.read(path, laz_backend=laspy.LazBackend.Lazrs)
        assert default.header.point_count == sequential.header.point_count == len(cloud)
        np.testing.assert_array_equal(default.points.array, sequential.points.array)
        np.testing.assert_allclose(default.xyz, cloud.points, rtol=0, atol=5e-5)
        np.testing.assert_array_equal(default.station, cloud.fields["station"])
    first, second = laspy.read(tmp_path / "t0.laz"), laspy.read(tmp_path / "t1.laz")
    np.testing.assert_array_equal(first.points.array, second.points.array)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_abort_leaves_nothing_and_keeps_existing(
    tmp_path: Path, suffix: str, small_batches: None
) -> None:
    cloud = scan_cloud(2000)
    fields = {name: values.dtype for name, values in cloud.fields.items()}
    existing = write_cloud(tmp_path / f"kept{suffix}", Cloud(np.ones((2, 3))))
    before = existing.read_bytes()
    for path in (existing, tmp_path / f"new{suffix}"):
        out = open_cloud_writer(path, fields=fields, metadata=cloud.metadata)
        out.write(cloud.points, cloud.fields)  # LAS/LAZ: several batches handed to laspy
        out.abort()
        out.abort()  # again: nothing to do
        assert out.closed
        with pytest.raises(InvalidParameterError, match="aborted"):
            out.write(cloud.points[:0], {k: v[:0] for k, v in cloud.fields.items()})
        with pytest.raises(InvalidParameterError, match="aborted"):
            out.close()
    assert leftovers(tmp_path) == [existing.name]
    assert existing.read_bytes() == before


class Crash(Exception):
    pass


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_crash_inside_with_leaves_nothing(tmp_path: Path, suffix: str) -> None:
    existing = write_cloud(tmp_path / f"kept{suffix}", Cloud(np.ones((2, 3))))
    before = existing.read_bytes()
    for path in (existing, tmp_path / f"new{suffix}"):
        with pytest.raises(Crash):  # the caller's exception, not a mapped one
            with open_cloud_writer(path, fields={"range_m": np.float64}) as out:
                out.write(GEO_ORIGIN + np.zeros((5, 3)), {"range_m": np.ones(5)})
                raise Crash("the scanner failed")
        assert out.closed
    assert leftovers(tmp_path) == [existing.name]
    assert existing.read_bytes() == before


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_bad_chunk_aborts(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"a{suffix}"
    out = open_cloud_writer(path, fields={})
    out.write(np.zeros((4, 3)))
    with pytest.raises(InvalidGeometryError, match="row 5"):
        out.write(np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 2.0]]))
    assert out.closed
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_int32_overflow_message(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"a{suffix}"
    with pytest.raises(InvalidGeometryError, match="coarser las_scale_m") as info:
        with open_cloud_writer(path, fields={}, origin_hint_m=[0.0, 0.0, 0.0]) as out:
            out.write(np.zeros((3, 3)))
            out.write(np.array([[1.0, 0.0, 0.0], [0.0, -300_000.0, 0.0]]))
    message = str(info.value)
    assert "300000 m from the LAS offsets (0, 0, 0)" in message
    assert "row 4" in message and "las_scale_m=0.0001" in message
    assert leftovers(tmp_path) == []
    # at 1 mm the same points fit
    with open_cloud_writer(path, fields={}, origin_hint_m=[0, 0, 0], las_scale_m=1e-3) as out:
        out.write(np.array([[1.0, 0.0, 0.0], [0.0, -300_000.0, 0.0]]))
    np.testing.assert_allclose(read_cloud(path).points[:, 1], [0.0, -300_000.0])


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_empty_writer_writes_a_valid_empty_file(tmp_path: Path, suffix: str) -> None:
    fields = {"station": np.uint16, "range_m": np.float64}
    with open_cloud_writer(tmp_path / f"e{suffix}", fields=fields, metadata=METADATA) as out:
        out.write(np.empty((0, 3)), {"station": np.empty(0), "range_m": np.empty(0)})
    assert out.points_written == 0
    back = read_cloud(out.path)
    assert back.points.shape == (0, 3) and back.points.dtype == np.float64
    assert {"range_m", "station"} <= set(back.fields)  # LAS adds its standard dimensions
    assert all(len(v) == 0 for v in back.fields.values())
    if suffix in (".las", ".laz"):
        header = laspy.read(out.path).header
        assert header.point_count == 0
        assert list(header.mins) == list(header.maxs) == [0.0, 0.0, 0.0]
    elif suffix == ".ply":
        assert b"\nelement vertex 0\n" in out.path.read_bytes()
        assert plyfile.PlyData.read(str(out.path))["vertex"].count == 0
    else:
        delimiter = "," if suffix == ".csv" else " "
        assert out.path.read_text() == delimiter.join(["x", "y", "z", *fields]) + "\n"


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_write_cloud_of_an_empty_cloud_with_fields(tmp_path: Path, suffix: str) -> None:
    empty = scan_cloud(0)
    empty.fields["normal"] = np.empty((0, 3))  # a 2-D field: columns normal_0 ... normal_2
    back = read_cloud(write_cloud(tmp_path / f"e{suffix}", empty))
    assert len(back) == 0
    assert {"normal_0", "normal_2", "station"} <= set(back.fields)


def test_ply_count_is_patched_plainly(tmp_path: Path) -> None:
    cloud = scan_cloud(1234)
    path = write_in_chunks(tmp_path / "a.ply", cloud).path
    head = path.read_bytes().split(b"end_header\n")[0].decode("ascii").splitlines()
    assert "element vertex 1234" in head  # no leading zeros, no trailing spaces
    assert all(line == line.strip() for line in head)
    data = plyfile.PlyData.read(str(path))
    assert data["vertex"].count == 1234
    assert data.comments[:2] == [
        "treesim label_names 0=other,1=wood,2=leaf,3=ground",
        'treesim scanner {"fov": 300}',
    ]
    writer = PlyCloudWriter(tmp_path / "b.ply", fields={"f": np.float32})
    assert len(writer._header(0)) == len(writer._header(2**64 - 1))
    writer.abort()


def test_ply_reads_in_open3d(tmp_path: Path) -> None:
    o3d = pytest.importorskip("open3d")
    cloud = scan_cloud(800)
    path = write_in_chunks(tmp_path / "a.ply", cloud).path
    pcd = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(pcd.point.positions.numpy(), cloud.points)
    np.testing.assert_array_equal(
        pcd.point.range_m.numpy().ravel(), cloud.fields["range_m"]
    )  # (Open3D skips ushort properties such as station, with a warning)
    with open_cloud_writer(tmp_path / "e.ply", fields={"range_m": np.float64}) as out:
        pass
    assert len(o3d.t.io.read_point_cloud(str(out.path)).point.positions) == 0


def test_ply_64_bit_values_beyond_32_bits_are_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidGeometryError, match="declare it float64"):
        with open_cloud_writer(tmp_path / "a.ply", fields={"index": np.int64}) as out:
            out.write(np.zeros((2, 3)), {"index": np.array([0, 1])})
            out.write(np.zeros((1, 3)), {"index": np.array([2**40])})
    assert leftovers(tmp_path) == []
    with open_cloud_writer(tmp_path / "a.ply", fields={"index": np.float64}) as out:
        out.write(np.zeros((1, 3)), {"index": np.array([2**40])})
    assert read_cloud(out.path).fields["index"][0] == 2**40


def test_fields_are_checked_and_cast(tmp_path: Path) -> None:
    out = open_cloud_writer(tmp_path / "a.ply", fields={"f": np.float32, "n": np.int16})
    with pytest.raises(InvalidParameterError, match=r"missing \['n'\], undeclared \['m'\]"):
        out.write(np.zeros((1, 3)), {"f": [1.0], "m": [2]})
    assert leftovers(tmp_path) == []
    with pytest.raises(InvalidGeometryError, match="shape"):
        with open_cloud_writer(tmp_path / "a.ply", fields={"f": np.float32, "n": np.int16}) as out:
            out.write(np.zeros((2, 3)), {"f": [1.0], "n": [1, 2]})
    assert leftovers(tmp_path) == []
    with open_cloud_writer(tmp_path / "a.ply", fields={"f": np.float32, "n": np.int16}) as out:
        out.write(np.zeros((2, 3)), {"f": np.array([0.5, 1.5]), "n": [3, -4]})
    back = read_cloud(out.path)
    assert back.fields["f"].dtype == np.float32 and back.fields["n"].dtype == np.int16
    np.testing.assert_array_equal(back.fields["n"], [3, -4])


@pytest.mark.parametrize("suffix", [".las", ".ply", ".xyz"])
def test_bad_declarations_create_nothing(tmp_path: Path, suffix: str) -> None:
    with pytest.raises(InvalidGeometryError, match="numeric"):
        open_cloud_writer(tmp_path / f"a{suffix}", fields={"name": np.dtype("U4")})
    with pytest.raises(InvalidGeometryError, match="coordinate"):
        open_cloud_writer(tmp_path / f"a{suffix}", fields={"X": np.float64})
    assert leftovers(tmp_path) == []


def test_option_errors(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="las_scale_m"):
        open_cloud_writer(tmp_path / "a.laz", fields={}, las_scale_m=-1)
    with pytest.raises(InvalidParameterError, match="origin_hint_m"):
        open_cloud_writer(tmp_path / "a.laz", fields={}, origin_hint_m=[0.0, np.nan, 0.0])
    with pytest.raises(InvalidParameterError, match="threads"):
        open_cloud_writer(tmp_path / "a.laz", fields={}, threads=-2)
    with pytest.raises(InputFormatError, match="E57"):
        open_cloud_writer(tmp_path / "a.e57", fields={})
    with pytest.raises(InputFormatError, match="could not write"):
        open_cloud_writer(tmp_path / "missing" / "a.laz", fields={})
    # LAS options are ignored by the other formats
    with open_cloud_writer(tmp_path / "a.ply", fields={}, las_scale_m=1e-3, threads=1) as out:
        out.write(np.ones((1, 3)))
    assert leftovers(tmp_path) == ["a.ply"]


def test_close_twice_and_write_after_close(tmp_path: Path) -> None:
    out = open_cloud_writer(tmp_path / "a.xyz", fields={})
    out.write(np.ones((2, 3)))
    assert out.close() == tmp_path / "a.xyz"
    assert out.close() == tmp_path / "a.xyz"
    out.abort()  # a closed file stays
    with pytest.raises(InvalidParameterError, match="closed"):
        out.write(np.ones((1, 3)))
    assert len(read_cloud(tmp_path / "a.xyz")) == 2


def test_dropped_writer_leaves_nothing(tmp_path: Path) -> None:
    out = open_cloud_writer(tmp_path / "a.laz", fields={})
    out.write(np.ones((2, 3)))
    with pytest.warns(ResourceWarning, match="never closed"):
        del out
        gc.collect()
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("suffix", sorted(set(supported_suffixes())))
@pytest.mark.parametrize("with_fields", [False, True])
def test_every_format_writes_an_empty_cloud(tmp_path: Path, suffix: str, with_fields) -> None:
    """write_cloud of a cloud with no points writes a valid empty file in every format it
    writes (no ValueError from an empty array); E57, which holds scans of points, says
    it needs one."""
    empty = scan_cloud(0) if with_fields else Cloud(np.empty((0, 3)))
    path = tmp_path / f"e{suffix}"
    if suffix == ".e57":
        with pytest.raises(InputFormatError, match="no points; an E57 scan needs"):
            write_cloud(path, empty)
        return
    back = read_cloud(write_cloud(path, empty))
    assert back.points.shape == (0, 3)
    if with_fields:
        assert {"station", "range_m"} <= set(back.fields)
    assert all(len(v) == 0 for v in back.fields.values())
