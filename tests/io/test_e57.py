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
