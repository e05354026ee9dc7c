"""LAS/LAZ: precision at georeferenced coordinates, standard and extra dimensions."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from treesim.cloud import LABEL_NAMES, Cloud
from treesim.errors import InputFormatError, InvalidGeometryError, InvalidParameterError
from treesim.io import read_cloud, write_cloud

EXTRA_DTYPES = {
    "station": np.uint16,
    "range_m": np.float64,
    "incidence_deg": np.float32,
    "label": np.uint8,
    "scan_line": np.int32,
    "scan_column": np.int32,
}


@pytest.mark.parametrize("suffix", [".las", ".laz"])
@pytest.mark.parametrize("scale", [1e-4, 1e-3])
def test_round_trip_georeferenced(
    tmp_path: Path, geo_cloud: Cloud, suffix: str, scale: float
) -> None:
    path = write_cloud(tmp_path / f"geo{suffix}", geo_cloud, las_scale_m=scale)
    cloud = read_cloud(path)
    assert cloud.points.dtype == np.float64
    assert np.abs(cloud.points - geo_cloud.points).max() <= scale / 2 * (1 + 1e-6)
    assert cloud.metadata["las_point_format"] == 6
    assert cloud.metadata["las_scales"] == [scale] * 3
    assert cloud.metadata["las_offsets"] == [500000.0, 5499993.0, 300.0]


def test_extra_dims_keep_names_dtypes_and_values(tmp_path: Path, geo_cloud: Cloud) -> None:
    path = write_cloud(tmp_path / "geo.laz", geo_cloud)
    cloud = read_cloud(path)
    for name, dtype in EXTRA_DTYPES.items():
        assert cloud.fields[name].dtype == dtype, name
        np.testing.assert_array_equal(cloud.fields[name], geo_cloud.fields[name], name)

    las = laspy.read(path)
    extra = {d.name: d for d in las.point_format.extra_dimensions}
    assert set(extra) == set(EXTRA_DTYPES)
    assert all(extra[name].description for name in extra)
    assert extra["label"].description == "0=other,1=wood,2=leaf,3=ground"


def test_standard_fields_land_in_standard_dims(tmp_path: Path, geo_cloud: Cloud) -> None:
    path = write_cloud(tmp_path / "geo.laz", geo_cloud)
    las = laspy.read(path)
    assert las.header.point_format.id == 6
    assert str(las.header.version) == "1.4"
    assert "intensity" not in las.point_format.extra_dimension_names
    np.testing.assert_array_equal(las.intensity, geo_cloud.fields["intensity"])
    np.testing.assert_array_equal(las.return_number, geo_cloud.fields["return_number"])
    np.testing.assert_array_equal(las.number_of_returns, geo_cloud.fields["number_of_returns"])
    np.testing.assert_allclose(las.x, geo_cloud.points[:, 0], rtol=0, atol=5e-5)
    np.testing.assert_allclose(las.y, geo_cloud.points[:, 1], rtol=0, atol=5e-5)


def test_standard_fields_are_clipped(tmp_path: Path) -> None:
    cloud = Cloud(
        np.zeros((4, 3)),
        {
            "intensity": np.array([-5.0, 0.6, 70000.0, np.nan]),
            "return_number": np.array([0, 1, 7, 99]),
            "classification": np.array([2, 300, -1, 5]),
        },
    )
    las = laspy.read(write_cloud(tmp_path / "a.las", cloud))
    np.testing.assert_array_equal(las.intensity, [0, 1, 65535, 0])
    np.testing.assert_array_equal(las.return_number, [1, 1, 7, 15])
    np.testing.assert_array_equal(las.number_of_returns, [1, 1, 1, 1])  # default
    np.testing.assert_array_equal(las.classification, [2, 255, 0, 5])


def test_metadata_round_trip(tmp_path: Path, geo_cloud: Cloud) -> None:
    cloud = read_cloud(write_cloud(tmp_path / "geo.las", geo_cloud))
    assert cloud.metadata["label_names"] == LABEL_NAMES
    assert cloud.metadata["scanner"] == {"fov": 300}
    assert cloud.metadata["source_path"] == str(tmp_path / "geo.las")


def test_label_names_read_from_description_alone(tmp_path: Path) -> None:
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dims([laspy.ExtraBytesParams("label", "u1", "0=other,1=wood")])
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(2, header=header))
    las.label = np.array([0, 1])
    las.write(tmp_path / "a.las")
    cloud = read_cloud(tmp_path / "a.las")
    assert cloud.metadata["label_names"] == {0: "other", 1: "wood"}
    np.testing.assert_array_equal(cloud.fields["label"], [0, 1])


def test_bool_and_int64_fields(tmp_path: Path) -> None:
    cloud = Cloud(
        np.zeros((2, 3)),
        {"hit": np.array([True, False]), "big": np.array([2**40, -1], dtype=np.int64)},
    )
    back = read_cloud(write_cloud(tmp_path / "a.laz", cloud))
    assert back.fields["hit"].dtype == np.uint8
    np.testing.assert_array_equal(back.fields["hit"], [1, 0])
    assert back.fields["big"].dtype == np.int64
    np.testing.assert_array_equal(back.fields["big"], [2**40, -1])


def test_extent_too_large_for_scale(tmp_path: Path) -> None:
    cloud = Cloud(np.array([[0.0, 0.0, 0.0], [300_000.0, 0.0, 0.0]]))
    with pytest.raises(InvalidGeometryError, match="coarser las_scale_m"):
        write_cloud(tmp_path / "a.laz", cloud, las_scale_m=1e-4)
    back = read_cloud(write_cloud(tmp_path / "a.laz", cloud, las_scale_m=1e-3))
    np.testing.assert_allclose(back.points, cloud.points, atol=5e-4, rtol=0)


def test_bad_scale(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="las_scale_m"):
        write_cloud(tmp_path / "a.las", Cloud(np.zeros((1, 3))), las_scale_m=0)


def test_nan_coordinates_are_rejected(tmp_path: Path) -> None:
    cloud = Cloud(np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 2.0]]))
    with pytest.raises(InvalidGeometryError, match="row 1"):
        write_cloud(tmp_path / "a.laz", cloud)


def test_long_field_name_is_rejected(tmp_path: Path) -> None:
    cloud = Cloud(np.zeros((1, 3)), {"n" * 40: np.zeros(1)})
    with pytest.raises(InvalidGeometryError, match="32"):
        write_cloud(tmp_path / "a.las", cloud)


def test_corrupt_files(tmp_path: Path, geo_cloud: Cloud) -> None:
    garbage = tmp_path / "garbage.las"
    garbage.write_bytes(b"not a las file at all" * 10)
    with pytest.raises(InputFormatError, match="LAS"):
        read_cloud(garbage)
    data = write_cloud(tmp_path / "geo.laz", geo_cloud).read_bytes()
    truncated = tmp_path / "truncated.laz"
    truncated.write_bytes(data[: len(data) - 40])
    with pytest.raises(InputFormatError):
        read_cloud(truncated)
