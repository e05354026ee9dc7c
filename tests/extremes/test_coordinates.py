"""Coordinates: the same scene at the origin and shifted by 1e5, 1e6 and 1e7 m.

The scene (a tilted prism for a trunk, a crumpled sheet for rough ground: convex and
concave edges) has every vertex on a 2**-20 m grid and its bounding box centred on the
origin, and the shifts are whole metres, so every shifted coordinate is exact (44
significant bits at most, of float64's 53) and the scanner's local frame, centred on
the bounding box, sees the very same numbers: the shifted cloud must be the cloud at the
origin plus the shift, rounded once, bit for bit ("the precision of doubles there").

Compared with the mesh, each point then lies on it to the scanner's bound (docs/concepts.md:
1e-9 m) plus the rounding of its shifted coordinates, half an ulp of each (ulp(1e7 m) =
1.9e-9 m): the distance compare measures may be that much, and no more.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.extremes.shapes import prism, rotation_x, rotation_z, sheet
from tests.extremes.test_range import bound_m
from tests.scan.test_scan_precision import BOUND_M
from treesim.compare import compare
from treesim.io import read_cloud
from treesim.io.mesh import write_mesh
from treesim.params import CompareParams, ScanParams
from treesim.scan import ScannerSpec, Station, scan
from treesim.scene import MeshPart, Scene
from treesim.steps import compare_files, scan_files

SHIFTS_M = [1e5, 1e6, 1e7]
GRID = 2.0**-20
SPEC = ScannerSpec(horizontal_resolution_deg=0.25, vertical_resolution_deg=0.25)


def on_grid(v: np.ndarray) -> np.ndarray:
    return np.round(v / GRID) * GRID


def shift_of(s: float) -> np.ndarray:
    """A shift of magnitude ``s`` in x, half of it in y and a hundredth in z (whole m)."""
    return np.array([s, -s / 2, s / 100])


def tree_scene(tilt: float, spin: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A trunk (a 10-facet prism, 0.3 m across, 3 m high, tilted) on rough ground (a
    6 m crumpled sheet laid flat), on the 2**-20 m grid, bounding box centred on 0.
    Returns (vertices, faces, labels)."""
    pv, pf = prism(10, 0.15, 3.0)
    pv = pv @ (rotation_z(spin) @ rotation_x(tilt)).T
    gv, gf, _ = sheet(30, 6.0, 0.03, seed)
    gv = gv[:, [1, 2, 0]]  # lay the sheet down: its heights along z
    gv[:, 2] -= 0.05
    gf = gf[:, ::-1]  # keep its triangles facing up
    v = on_grid(np.vstack([pv, gv]))
    f = np.vstack([pf, gf + len(pv)])
    lab = np.r_[np.ones(len(pf), np.uint8), np.full(len(gf), 3, np.uint8)]
    lo, hi = v.min(axis=0), v.max(axis=0)
    return v - (lo + hi) / 2, f, lab  # exact: both on the grid, far from overflow


def make_scene(v, f, lab) -> Scene:
    return Scene.from_labelled_mesh(v, f, lab)


def station_points(azimuth: float, distance_m: float, height_m: float) -> np.ndarray:
    a = np.radians(azimuth)
    return on_grid(np.array([distance_m * np.cos(a), distance_m * np.sin(a), height_m]))


@settings(max_examples=4, deadline=None, derandomize=True)
@given(
    tilt=st.floats(0.0, 20.0),
    spin=st.floats(0.0, 36.0),
    seed=st.integers(0, 2**16),
    azimuth=st.floats(0.0, 360.0),
    distance=st.floats(2.0, 8.0),
    height=st.floats(-1.0, 1.0),
)
def test_a_shifted_scene_gives_the_same_cloud_shifted(tilt, spin, seed, azimuth, distance, height):
    v, f, lab = tree_scene(tilt, spin, seed)
    o = station_points(azimuth, distance, height)
    base = scan(make_scene(v, f, lab), [Station(position_m=tuple(o))], SPEC)
    assert len(base.cloud) > 1000
    for s in SHIFTS_M:
        sh = shift_of(s)
        moved = scan(make_scene(v + sh, f, lab), [Station(position_m=tuple(o + sh))], SPEC)
        np.testing.assert_array_equal(moved.cloud.points, base.cloud.points + sh)
        for name in ("scan_line", "scan_column", "label", "range_m", "incidence_deg"):
            np.testing.assert_array_equal(moved.cloud.fields[name], base.cloud.fields[name])


def coordinate_rounding_m(coords: np.ndarray) -> float:
    """Half an ulp of each coordinate's magnitude, as a distance: √3 / 2 ulp."""
    return float(np.sqrt(3) / 2 * np.spacing(np.abs(coords).max()))


@pytest.mark.parametrize("s", [0.0, *SHIFTS_M])
def test_compare_finds_the_shifted_cloud_on_its_mesh(s):
    v, f, lab = tree_scene(12.0, 7.0, 3)
    sh = shift_of(s)
    scene = make_scene(v + sh, f, lab)
    res = scan(scene, [Station(position_m=tuple(station_points(30.0, 5.0, 0.5) + sh))], SPEC)
    cmp = compare(res.cloud, scene, params=CompareParams(nthreads=1))
    bound = BOUND_M + coordinate_rounding_m(v + sh)
    assert cmp.accuracy.max_m <= bound, (cmp.accuracy.max_m, bound)


def test_files_at_1e7_m_keep_doubles_in_ply_and_tenths_of_mm_in_laz(tmp_path: Path):
    # the whole loop on files: mesh written, scanned, the cloud written, read, compared
    v, f, lab = tree_scene(12.0, 7.0, 3)
    sh = shift_of(1e7)
    mesh = write_mesh(tmp_path / "scene.ply", v + sh, f, face_label=lab)
    station = [tuple(station_points(30.0, 5.0, 0.5) + sh)]
    params = ScanParams(scanner=SPEC)
    for suffix, bound in [
        (".ply", BOUND_M + coordinate_rounding_m(v + sh)),
        # LAZ stores 0.1 mm steps: half a step per coordinate, plus the points' own bound
        (".laz", np.sqrt(3) / 2 * 1e-4 + BOUND_M + coordinate_rounding_m(v + sh)),
    ]:
        out = tmp_path / f"scan{suffix}"
        step = scan_files([mesh], params, out, stations=station)
        cloud = read_cloud(out)
        assert len(cloud) == step.result.n_points > 1000
        assert np.abs(cloud.points - sh).max() < 10.0  # where the scene is
        done = compare_files(out, mesh, CompareParams(nthreads=1), tmp_path / f"cmp{suffix}")
        assert done.result.accuracy.max_m <= bound, (suffix, done.result.accuracy.max_m, bound)


def test_compare_finds_a_cloud_on_its_mesh_beside_concave_edges_too():
    # seen head-on from 2 km, scan lines run along the crumpled sheet's cell diagonals:
    # hits lie within float32's tie of an edge, where the float32 closest-triangle pick
    # took the neighbour across a concave edge and compare measured 9.5e-9 m
    v, f, _ = sheet(200, 2.0, 0.003, 0)
    scene = Scene([MeshPart(vertices=v, faces=f, label="ground", name="sheet")])
    res = max(np.degrees(2.0 / 2000.0) / 400, 0.0005)
    spec = ScannerSpec(
        horizontal_resolution_deg=res,
        vertical_resolution_deg=res,
        vertical_fov_deg=(-90.0, 90.0),
        max_range_m=2500.0,
    )
    r = scan(scene, [Station(position_m=(2000.0, 0.0, 0.0))], spec, check_inside=False)
    assert len(r.cloud) > 10_000
    cmp = compare(r.cloud, scene, params=CompareParams(nthreads=1))
    # the points' own bound (tests/extremes/test_range.py) at the largest incidence
    cos = np.cos(np.radians(r.cloud.fields["incidence_deg"].max()))
    assert cmp.accuracy.max_m <= bound_m(2000.0, 2.0) / cos, cmp.accuracy.max_m
