"""Scans that run but may not be what was meant say so (``ScanResult.warnings``): a
station on a surface or enclosed by inverted geometry, triangles lost to precision."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import box_arrays, cylinder_arrays
from treesim.params import ScannerSpec
from treesim.scan import Station, scan
from treesim.scene import MeshPart, Scene

COARSE = ScannerSpec(horizontal_resolution_deg=2.0, vertical_resolution_deg=2.0)


def _scan(v, f, *stations, spec=COARSE, **kwargs):
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood", name="test")])
    return scan(scene, [Station(position_m=p) for p in stations], spec, **kwargs)


@pytest.mark.parametrize(
    "station",
    [(1.0, 0.0, 1.0), (1.0, 1.0, 2.0), (0.0, 1.0, 0.5)],
    ids=["on-a-face", "on-a-corner", "on-an-edge-face"],
)
def test_a_station_on_a_surface_is_named(station):
    v, f = box_arrays((-1, -1, 0), (1, 1, 2))
    r = _scan(v, f, (5.0, 0.0, 1.0), station)
    assert len(r.warnings) == 1 and r.warnings[0].startswith("station 1 at ")
    assert "is on a wood surface" in r.warnings[0]
    assert r.summary()["warnings"] == r.warnings


def test_a_station_on_a_curved_surface_is_named():
    v, f = cylinder_arrays(0.15, 2.0, 64)
    r = _scan(v, f, (0.15, 0.0, 1.0))
    assert any("is on a wood surface" in w for w in r.warnings)


def test_a_station_enclosed_by_inverted_geometry_is_named():
    v, f = box_arrays((-1, -1, 0), (1, 1, 2))
    r = _scan(v, f[:, ::-1], (0.0, 0.0, 1.0))  # normals inwards: the inside check passes
    assert len(r.warnings) == 1 and "looks enclosed by the wood geometry" in r.warnings[0]
    assert "normals inverted" in r.warnings[0]


@pytest.mark.parametrize("station", [(5.0, 0.0, 1.0), (1.001, 0.0, 1.0), (0.0, 0.0, 3.0)])
def test_ordinary_stations_give_no_warning(station):
    v, f = box_arrays((-1, -1, 0), (1, 1, 2))
    assert _scan(v, f, station).warnings == []
    assert _scan(v, f[:, ::-1], station).warnings == []  # outside: parity is even


def test_triangles_lost_in_float64_far_from_the_origin_are_counted():
    # a 1 m box keeps its shape at 1e13 m (float64 steps of 2 mm there); a 1 mm twig beside
    # it rounds to a line
    big = np.array([1e13, 1e13, 0.0])
    bv, bf = box_arrays((-0.5, -0.5, 0.0), (0.5, 0.5, 1.0))
    tv, tf = cylinder_arrays(0.0005, 0.5, 16, (0.0, 1.0, 0.0))
    v = np.vstack([bv, tv]) + big
    f = np.vstack([bf, tf + len(bv)])
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood", name="far")])
    assert scene.dropped_degenerate >= len(tf) // 2
    r = scan(scene, [Station(position_m=tuple(big + [3.0, 0.0, 0.5]))], COARSE)
    assert len(r.warnings) == 1 and "have no area in float64 and were dropped" in r.warnings[0]
    assert "1e+13 m" in r.warnings[0]


def test_triangles_distorted_in_float32_are_counted():
    v, f = cylinder_arrays(0.01, 0.5, 16)
    far_v = np.array([[2e5, 0.0, 0.0], [2e5, 1.0, 0.0], [2e5, 0.0, 1.0]])
    vv = np.vstack([v, far_v])
    ff = np.vstack([f, [[len(v), len(v) + 1, len(v) + 2]]])  # the frame's centre is 1e5 m out
    # (cull=False: the occupancy raster of so large a scene takes seconds to bisect)
    r = _scan(vv, ff, (1.0, 0.0, 0.25), cull=False)
    assert len(r.warnings) == 1 and "distorted in float32" in r.warnings[0]
    # a scene of that size near the origin gives no warning
    assert _scan(v, f, (1.0, 0.0, 0.25)).warnings == []
