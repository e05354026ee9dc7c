"""E57 (optional, through pye57): poses applied in float64, scans merged, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from treesim.errors import InputFormatError
from treesim.io import e57

pye57 = pytest.importorskip("pye57")

GEO = np.array([500000.0, 5500000.0, 300.0])


def _write(path: Path, scans: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
    """Scans of (local points, rotation quaternion w,x,y,z, translation)."""
    f = pye57.E57(str(path), mode="w")
    try:
        for i, (pts, rotation, translation) in enumerate(scans):
            data = {
                "cartesianX": pts[:, 0].copy(),
                "cartesianY": pts[:, 1].copy(),
                "cartesianZ": pts[:, 2].copy(),
                "intensity": np.linspace(0.0, 1.0, len(pts)),
            }
            f.write_scan_raw(data, name=f"scan{i}", rotation=rotation, translation=translation)
    finally:
        f.close()


def test_scans_are_merged_with_their_poses_in_float64(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    a = rng.uniform(-2, 2, (200, 3)).astype(np.float32).astype(np.float64)
    b = rng.uniform(-2, 2, (150, 3)).astype(np.float32).astype(np.float64)
    quarter = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # 90 deg about z
    path = tmp_path / "two.e57"
    _write(path, [(a, np.array([1.0, 0, 0, 0]), GEO), (b, quarter, GEO + [10.0, 0, 0])])
    cloud = e57.read_e57(path)
    assert len(cloud) == 350
    np.testing.assert_allclose(cloud.points[:200], a + GEO, rtol=0, atol=1e-6)
    turned = np.c_[-b[:, 1], b[:, 0], b[:, 2]] + GEO + [10.0, 0, 0]
    np.testing.assert_allclose(cloud.points[200:], turned, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(cloud.fields["station"], [0] * 200 + [1] * 150)
    assert cloud.fields["intensity"].shape == (350,)
    assert cloud.metadata["e57_scans"] == 2
    np.testing.assert_allclose(cloud.metadata["stations"][1], GEO + [10.0, 0, 0], atol=1e-6, rtol=0)


def test_not_an_e57_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.e57"
    path.write_bytes(b"not an e57 file at all" * 100)
    with pytest.raises(InputFormatError, match="could not be read as E57"):
        e57.read_e57(path)


def test_missing_pye57_is_a_clear_error(tmp_path: Path, monkeypatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "pye57", None)  # import pye57 now raises ImportError
    assert not e57.available()
    with pytest.raises(InputFormatError, match="needs the optional package pye57"):
        e57.read_e57(tmp_path / "x.e57")


def test_write_e57_one_scan_per_station_with_its_pose(tmp_path: Path) -> None:
    """A cloud with stations written as E57 reads back as the same points (to well under a
    micrometre at a 5e6 m offset) with one scan per station, its pose the station."""
    from treesim.cloud import Cloud
    from treesim.io import read_cloud, write_cloud

    rng = np.random.default_rng(1)
    stations = [
        list(GEO + [1.0, 2.0, 1.5]),
        list(GEO + [-8.0, 3.0, 1.6]),
        list(GEO + [4.0, -6.0, 1.4]),
    ]
    station = rng.integers(0, 3, 500)
    pts = np.asarray(stations)[station] + rng.uniform(-10, 10, (500, 3))
    cloud = Cloud(pts, {"station": station, "intensity": rng.random(500)}, {"stations": stations})
    path = write_cloud(tmp_path / "field.e57", cloud)
    back = read_cloud(path)
    order = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0], station))
    back_order = np.lexsort(
        (back.points[:, 2], back.points[:, 1], back.points[:, 0], back.fields["station"])
    )
    assert np.abs(back.points[back_order] - pts[order]).max() < 1e-6
    assert back.metadata["stations"] == stations
    assert back.metadata["stations_posed"] == [True, True, True]
    assert e57.read_e57_stations(path) == stations
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left


def test_a_scan_without_a_pose(tmp_path: Path) -> None:
    """A scan with no pose reads (its points as stored, flagged not posed), but its
    station position is refused with a message that says what to do."""
    from types import SimpleNamespace

    pts = np.random.default_rng(2).uniform(-2, 2, (50, 3))
    header = SimpleNamespace(
        rotation=None,
        translation=None,
        name="no pose",
        **{
            f"{c}{m}": getattr(pts[:, k], f)
            for k, c in enumerate("xyz")
            for m, f in (("Minimum", "min"), ("Maximum", "max"))
        },
    )
    for k in list(vars(header)):
        if k.endswith(("Minimum", "Maximum")):
            setattr(header, k, float(getattr(header, k)()))
    path = tmp_path / "noposes.e57"
    f = pye57.E57(str(path), mode="w")
    try:
        data = {f"cartesian{c}": pts[:, k].copy() for k, c in enumerate("XYZ")}
        f.write_scan_raw(data, scan_header=header)
    finally:
        f.close()
    cloud = e57.read_e57(path)
    assert cloud.metadata["stations_posed"] == [False]
    assert np.allclose(cloud.points, pts)
    with pytest.raises(InputFormatError, match="scan 0 has no pose.*stations as a CSV"):
        e57.read_e57_stations(path)
