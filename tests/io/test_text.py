"""Delimited text clouds: headers, columns=, delimiters, bad lines, precision."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import bundled_path
from treesim.cloud import Cloud
from treesim.errors import EmptyInputError, InputFormatError, InvalidGeometryError
from treesim.io import read_cloud, write_cloud

from .conftest import GEO_ORIGIN


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_headerless_extra_columns_become_col_fields(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.xyz", "1 2 3 10 0.5\n4.5\t5 6 20 0.25\n\n7 8 9e0 30 1\n")
    cloud = read_cloud(path)
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4.5, 5, 6], [7, 8, 9]])
    assert cloud.points.dtype == np.float64
    assert list(cloud.fields) == ["col3", "col4"]
    np.testing.assert_array_equal(cloud.fields["col3"], [10, 20, 30])
    np.testing.assert_array_equal(cloud.fields["col4"], [0.5, 0.25, 1])
    assert cloud.metadata["source_path"] == str(path)


def test_header_names_are_lower_cased_and_locate_xyz(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.txt", "Intensity X Y Z\n7 1 2 3\n8 4 5 6\n")
    cloud = read_cloud(path)
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])
    assert list(cloud.fields) == ["intensity"]
    np.testing.assert_array_equal(cloud.fields["intensity"], [7, 8])


def test_cloudcompare_style_header(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.asc", "//X,Y,Z,Scalar_field\n1,2,3,4\n")
    cloud = read_cloud(path)
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3]])
    assert list(cloud.fields) == ["scalar_field"]


def test_columns_override(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.xyz", "1 2 3 40\n5 6 7 80\n")
    cloud = read_cloud(path, columns=["x", "y", "z", "intensity"])
    assert list(cloud.fields) == ["intensity"]
    np.testing.assert_array_equal(cloud.fields["intensity"], [40, 80])
    cloud = read_cloud(path, columns=["intensity", "z", "x", "y"])
    np.testing.assert_array_equal(cloud.points, [[3, 40, 2], [7, 80, 6]])
    cloud = read_cloud(path, columns=["x", "y", "z", None])
    assert cloud.fields == {}


def test_columns_override_replaces_header(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.txt", "a b c d\n1 2 3 4\n")
    with pytest.raises(InputFormatError, match="columns="):
        read_cloud(path)
    cloud = read_cloud(path, columns=["x", "y", "z", "w"])
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3]])
    np.testing.assert_array_equal(cloud.fields["w"], [4])


def test_columns_must_match_and_name_xyz(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.xyz", "1 2 3 4\n")
    with pytest.raises(InputFormatError, match="4"):
        read_cloud(path, columns=["x", "y", "z"])
    with pytest.raises(InputFormatError, match="'z'"):
        read_cloud(path, columns=["x", "y", "w", "v"])
    with pytest.raises(InputFormatError, match="repeats"):
        read_cloud(path, columns=["x", "y", "z", "x"])


def test_comma_separated_csv(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.csv", "x,y,z,range_m\r\n1.5, 2.5 ,3.5,0.1\r\n4,5,6,0.2\r\n")
    cloud = read_cloud(path)
    np.testing.assert_array_equal(cloud.points, [[1.5, 2.5, 3.5], [4, 5, 6]])
    np.testing.assert_array_equal(cloud.fields["range_m"], [0.1, 0.2])


def test_headerless_csv_with_bom_and_comments(tmp_path: Path) -> None:
    path = tmp_path / "a.csv"
    path.write_bytes(b"\xef\xbb\xbf# exported\n1,2,3\n4,5,6 # trailing\n")
    np.testing.assert_array_equal(read_cloud(path).points, [[1, 2, 3], [4, 5, 6]])


def test_semicolon_separated(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.txt", "1;2;3\n4;5;6\n")
    np.testing.assert_array_equal(read_cloud(path).points, [[1, 2, 3], [4, 5, 6]])


def test_pts_point_count_line_is_skipped(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.pts", "2\n1 2 3 -1200 10 20 30\n4 5 6 800 40 50 60\n")
    cloud = read_cloud(path)
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [4, 5, 6]])
    assert list(cloud.fields) == ["col3", "col4", "col5", "col6"]


def test_non_numeric_line_names_line_number(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.xyz", "x y z\n1 2 3\n\n4 5 6\n7 oops 9\n10 11 12\n")
    with pytest.raises(InputFormatError, match=r"line 5\b.*oops"):
        read_cloud(path)


def test_second_header_like_line_names_line_number(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.xyz", "x y z\nfoo bar baz\n1 2 3\n")
    with pytest.raises(InputFormatError, match="line 2"):
        read_cloud(path)


def test_ragged_line_names_line_number(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.csv", "1,2,3\n4,5,6\n7,8\n")
    with pytest.raises(InputFormatError, match=r"line 3 has 2 values"):
        read_cloud(path)


def test_too_few_columns(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.xyz", "1 2\n3 4\n")
    with pytest.raises(InputFormatError, match="x y z"):
        read_cloud(path)


def test_binary_file_with_text_suffix(tmp_path: Path) -> None:
    path = tmp_path / "a.txt"
    path.write_bytes(b"\xff\xfe\x00\x01garbage\x80\x81")
    with pytest.raises(InputFormatError, match="UTF-8"):
        read_cloud(path)


def test_nan_rows_are_kept_for_validate(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.xyz", "1 2 3\nnan 5 6\n7 8 9\n")
    cloud = read_cloud(path)
    assert len(cloud) == 3
    assert np.isnan(cloud.points[1, 0])
    with pytest.raises(InvalidGeometryError, match="row 1"):
        cloud.validate()


def test_empty_and_header_only_files(tmp_path: Path) -> None:
    cloud = read_cloud(_write(tmp_path / "a.xyz", ""))
    assert cloud.points.shape == (0, 3)
    with pytest.raises(EmptyInputError):
        cloud.validate()
    cloud = read_cloud(_write(tmp_path / "b.csv", "x,y,z,intensity\n"))
    assert cloud.points.shape == (0, 3)
    assert cloud.fields["intensity"].shape == (0,)


@pytest.mark.parametrize("suffix", [".xyz", ".csv", ".txt"])
def test_round_trip_georeferenced(tmp_path: Path, geo_cloud: Cloud, suffix: str) -> None:
    path = write_cloud(tmp_path / f"geo{suffix}", geo_cloud)
    header = path.read_text().splitlines()[0]
    delimiter = "," if suffix == ".csv" else " "
    assert header.split(delimiter)[:4] == ["x", "y", "z", "intensity"]
    cloud = read_cloud(path)
    np.testing.assert_allclose(cloud.points, geo_cloud.points, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(cloud.points[0], GEO_ORIGIN)
    assert list(cloud.fields) == list(geo_cloud.fields)
    for name, values in geo_cloud.fields.items():
        assert cloud.fields[name].dtype == np.float64
        # float32 fields are written with 9 significant digits: exact once cast back
        np.testing.assert_array_equal(cloud.fields[name].astype(values.dtype), values, name)


def test_write_bool_and_float_fields(tmp_path: Path) -> None:
    cloud = Cloud(
        np.zeros((2, 3)),
        {"hit": np.array([True, False]), "r": np.array([0.1, 1 / 3]), "k": np.array([1, 2])},
    )
    back = read_cloud(write_cloud(tmp_path / "a.xyz", cloud))
    np.testing.assert_array_equal(back.fields["hit"], [1, 0])
    np.testing.assert_allclose(back.fields["r"], [0.1, 1 / 3], rtol=1e-14)
    np.testing.assert_array_equal(back.fields["k"], [1, 2])


def test_write_rejects_bad_field_names(tmp_path: Path) -> None:
    cloud = Cloud(np.zeros((1, 3)), {"two words": np.zeros(1)})
    with pytest.raises(InvalidGeometryError, match="rename"):
        write_cloud(tmp_path / "a.xyz", cloud)


def test_bundled_coffee_tree_text() -> None:
    # the sample the package bundles (the same file as ../shared/data's coffee tree)
    cloud = read_cloud(bundled_path("coffee_tree", "cloud.txt")).validate()
    assert len(cloud) == 14_667
    assert cloud.fields == {}
    assert np.ptp(cloud.points[:, 2]) > 1.0  # a tree, not a flat sheet
