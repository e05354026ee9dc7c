"""Dispatch by suffix: supported suffixes, unknown suffixes, missing files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from treesim.cloud import Cloud
from treesim.errors import InputFormatError, InvalidParameterError, TreesimError
from treesim.io import FORMATS, read_cloud, supported_suffixes, write_cloud


def test_registry_covers_every_format() -> None:
    assert supported_suffixes() == sorted(
        [".asc", ".csv", ".e57", ".las", ".laz", ".ply", ".pts", ".txt", ".xyz"]
    )
    assert all(suffix == suffix.lower() for suffix in FORMATS)


def test_unknown_suffix_lists_supported(tmp_path: Path) -> None:
    path = tmp_path / "cloud.rcp"
    path.write_bytes(b"\0")
    with pytest.raises(InputFormatError) as info:
        read_cloud(path)
    message = str(info.value)
    assert ".rcp" in message and ".e57" in message
    for suffix in (".las", ".laz", ".ply", ".xyz", ".csv"):
        assert suffix in message
    with pytest.raises(InputFormatError, match="supported"):
        write_cloud(tmp_path / "cloud.obj", Cloud(np.zeros((1, 3))))


def test_no_suffix(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="no suffix"):
        read_cloud(tmp_path / "cloud")


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="not found"):
        read_cloud(tmp_path / "absent.laz")


def test_directory_is_not_a_file(tmp_path: Path) -> None:
    folder = tmp_path / "cloud.xyz"
    folder.mkdir()
    with pytest.raises(InputFormatError, match="not a file"):
        read_cloud(folder)


@pytest.mark.parametrize("name", ["UPPER.XYZ", "Mixed.LaZ", "mesh.PLY", "sheet.CSV", "a.Las"])
def test_suffix_is_case_insensitive(tmp_path: Path, name: str) -> None:
    cloud = Cloud(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]))
    written = write_cloud(tmp_path / name, cloud)
    assert written == tmp_path / name
    np.testing.assert_allclose(read_cloud(written).points, cloud.points, atol=1e-4, rtol=0)


def test_columns_only_for_text(tmp_path: Path) -> None:
    path = write_cloud(tmp_path / "a.ply", Cloud(np.zeros((1, 3))))
    with pytest.raises(InvalidParameterError, match="columns"):
        read_cloud(path, columns=["x", "y", "z"])


def test_unwritable_destination(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="could not write"):
        write_cloud(tmp_path / "missing_dir" / "a.ply", Cloud(np.zeros((1, 3))))
    assert not (tmp_path / "missing_dir").exists()


def test_failed_write_leaves_no_file(tmp_path: Path) -> None:
    bad = Cloud(np.zeros((2, 3)), {"name": np.array(["a", "b"])})
    for suffix in (".ply", ".laz", ".xyz"):
        with pytest.raises(TreesimError, match="numeric"):
            write_cloud(tmp_path / f"a{suffix}", bad)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".xyz", ".csv", ".las", ".laz", ".ply"])
def test_empty_cloud_round_trip(tmp_path: Path, suffix: str) -> None:
    path = write_cloud(tmp_path / f"empty{suffix}", Cloud(np.empty((0, 3))))
    cloud = read_cloud(path)
    assert cloud.points.shape == (0, 3)
    assert cloud.points.dtype == np.float64
