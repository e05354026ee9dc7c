"""A scan's pulse times in files (issue 26): LAS/LAZ ``gps_time`` (point format 6, GPS
week time) read back by laspy itself, PLY ``time_s``; the points unchanged."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from treesim.cloud import Cloud
from treesim.io import read_cloud, write_cloud
from treesim.io.las import LasCloudWriter
from treesim.scan import scan_metadata

#: Pulse times a scan gives (s since the station's start): a VZ-400's 3.3 µs pulse
#: period, up to its 180 s scan.
TIMES_S = np.array([0.0, 1 / 300_000, 0.02, 59.999996666666666, 179.99, 123.456789012])


@pytest.fixture
def timed_cloud(geo_cloud: Cloud) -> Cloud:
    fields = {**geo_cloud.fields, "time_s": TIMES_S.copy()}
    return Cloud(geo_cloud.points, fields, {**geo_cloud.metadata, **scan_metadata([])})


@pytest.mark.parametrize("suffix", [".laz", ".las"])
def test_gps_time_round_trip_through_laspy(timed_cloud, tmp_path: Path, suffix: str):
    path = write_cloud(tmp_path / f"scan{suffix}", timed_cloud)
    las = laspy.read(path)
    assert las.header.point_format.id == 6 and str(las.header.version) == "1.4"
    assert las.header.global_encoding.gps_time_type == laspy.header.GpsTimeType.WEEK_TIME
    # a standard field, not an extra dimension; float64 exactly
    assert "time_s" not in las.point_format.extra_dimension_names
    assert np.array_equal(np.asarray(las.gps_time), TIMES_S)
    back = read_cloud(path)
    assert np.array_equal(back.fields["time_s"], TIMES_S)  # the metadata names it back
    assert "gps_time" not in back.fields
    assert np.abs(back.points - timed_cloud.points).max() <= 0.5e-4 + 1e-9


def test_a_cloud_of_its_own_gps_time_keeps_it(timed_cloud, tmp_path: Path):
    gps = np.linspace(1e9, 1e9 + 5, len(timed_cloud))
    cloud = Cloud(timed_cloud.points, {**timed_cloud.fields, "gps_time": gps}, timed_cloud.metadata)
    las = laspy.read(write_cloud(tmp_path / "own.laz", cloud))
    assert np.array_equal(np.asarray(las.gps_time), gps)
    assert np.array_equal(np.asarray(las["time_s"]), TIMES_S)  # then an extra dimension


def test_streamed_laz_carries_times(timed_cloud, tmp_path: Path):
    fields = {k: v.dtype for k, v in timed_cloud.fields.items()}
    with LasCloudWriter(tmp_path / "s.laz", fields=fields, metadata=timed_cloud.metadata) as w:
        w.write(timed_cloud.points[:3], {k: v[:3] for k, v in timed_cloud.fields.items()})
        w.write(timed_cloud.points[3:], {k: v[3:] for k, v in timed_cloud.fields.items()})
    assert np.array_equal(np.asarray(laspy.read(w.path).gps_time), TIMES_S)


def test_without_times_gps_time_stays_zero_and_is_read_as_gps_time(geo_cloud, tmp_path):
    back = read_cloud(write_cloud(tmp_path / "plain.laz", geo_cloud))
    assert "time_s" not in back.fields
    assert not back.fields["gps_time"].any()


def test_ply_time_s_round_trip(timed_cloud, tmp_path: Path):
    path = write_cloud(tmp_path / "scan.ply", timed_cloud)
    header = path.read_bytes().split(b"end_header")[0].decode("ascii")
    assert "property double time_s" in header
    back = read_cloud(path)
    assert back.fields["time_s"].dtype == np.float64
    assert np.array_equal(back.fields["time_s"], TIMES_S)
    assert np.array_equal(back.points, timed_cloud.points)
