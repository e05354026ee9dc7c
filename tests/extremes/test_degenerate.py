"""Degenerate input: what the scanner does with meshes and stations that are not nice.

Decisions (docs/commands/scan.md, "Degenerate input"; ``treesim.scene.Scene``):

* zero-area triangles are dropped and counted; duplicate triangles (either orientation)
  and non-manifold edges are kept, and change nothing the rays can tell;
* a NaN or infinite coordinate in a vertex a triangle uses is a one-line error (exit 1,
  nothing written); vertices no triangle uses are ignored;
* an empty file, or one without triangles, is a one-line error;
* a mesh outside every field of view or beyond every range is a valid empty cloud, and
  the command says why;
* a station inside a closed mesh, or standing on a surface, sees what a float64 ray
  from it meets first (the refusal of stations inside, and warnings, are the command's
  business, not the geometry's).
"""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.conftest import box_arrays, messages
from tests.extremes.shapes import (
    float32_ray_error_m,
    rectangle,
    rectangle_pulses,
    rotation_x,
    rotation_z,
)
from tests.extremes.test_range import bound_m
from treesim.cli import main
from treesim.errors import InvalidGeometryError
from treesim.io import read_cloud
from treesim.io.mesh import write_mesh
from treesim.scan import ScannerSpec, Station, scan
from treesim.scene import MeshPart, Scene

EXAMPLES = settings(max_examples=4, deadline=None, derandomize=True)
SPHERE = ScannerSpec(
    horizontal_resolution_deg=1.0, vertical_resolution_deg=1.0, vertical_fov_deg=(-90.0, 90.0)
)


def keys(res, spec) -> np.ndarray:
    f = res.cloud.fields
    return f["scan_line"].astype(np.int64) * spec.n_azimuth + f["scan_column"].astype(np.int64)


def identical(a, b) -> None:
    np.testing.assert_array_equal(a.cloud.points, b.cloud.points)
    for name, values in a.cloud.fields.items():
        np.testing.assert_array_equal(values, b.cloud.fields[name], err_msg=name)


# -- zero-area, duplicate and non-manifold triangles ------------------------------------


@EXAMPLES
@given(azimuth=st.floats(0.0, 360.0), height=st.floats(-1.0, 3.0), seed=st.integers(0, 2**16))
def test_zero_area_and_duplicate_triangles_change_nothing(azimuth, height, seed):
    v, f = box_arrays((-1.0, -0.5, 0.0), (1.0, 0.5, 2.0))
    clean = Scene([MeshPart(vertices=v, faces=f, label="wood")])
    rng = np.random.default_rng(seed)
    # every triangle once more, half of them the other way round
    dup = f[rng.permutation(len(f))]
    flip = rng.random(len(dup)) < 0.5
    dup[flip] = dup[flip][:, ::-1]
    # zero-area triangles: a repeated corner, three collinear points, one point thrice
    mid = (v[f[:, 0]] + v[f[:, 1]]) / 2  # on an edge of the box
    vz = np.vstack([v, mid])
    m = np.arange(len(f)) + len(v)
    zero = np.concatenate(
        [
            np.stack([f[:, 0], f[:, 0], f[:, 2]], 1),
            np.stack([f[:, 0], m, f[:, 1]], 1),
            np.stack([f[:, 2], f[:, 2], f[:, 2]], 1),
        ]
    )
    messy_faces = np.concatenate([f, dup, zero])[rng.permutation(4 * len(f) + len(f))]
    messy = Scene([MeshPart(vertices=vz, faces=messy_faces, label="wood")])
    assert messy.dropped_degenerate == len(zero) and messy.n_triangles == 2 * len(f)
    a = np.radians(azimuth)
    st_ = [Station(position_m=(4 * np.cos(a), 4 * np.sin(a), height))]
    spec = ScannerSpec(horizontal_resolution_deg=0.3, vertical_resolution_deg=0.3)
    identical(scan(clean, st_, spec), scan(messy, st_, spec))


@EXAMPLES
@given(
    fins=st.integers(3, 6),
    spin=st.floats(0.0, 360.0),
    tilt=st.floats(0.0, 20.0),
    azimuth=st.floats(0.0, 360.0),
    z=st.floats(-0.8, 0.8),
)
def test_fins_on_one_non_manifold_edge_are_each_seen_where_they_are_nearest(
    fins, spin, tilt, azimuth, z
):
    # `fins` rectangles hinged on one edge (shared by all of them: non-manifold)
    turn = rotation_z(spin) @ rotation_x(tilt)
    half = (0.5, 1.0)
    parts, frames = [], []
    for k in range(fins):
        out = rotation_z(360.0 * k / fins + 17.0)
        rot = turn @ out @ rotation_x(90.0)  # e1 away from the hinge, e2 along it
        centre = half[0] * rot[:, 0]
        verts, faces = rectangle(centre, rot, half, (3, 5))
        parts.append(MeshPart(vertices=verts, faces=faces, label="wood", name=f"fin{k}"))
        frames.append((centre, rot))
    scene = Scene(parts)
    a = np.radians(azimuth)
    station = np.array([3 * np.cos(a), 3 * np.sin(a), z])
    spec = ScannerSpec(horizontal_resolution_deg=0.4, vertical_resolution_deg=0.4)
    res = scan(scene, [Station(position_m=tuple(station))], spec)
    got = keys(res, spec)
    eps = float32_ray_error_m(3.0, 4.5, 2.5)
    sure, possible = [], []
    for centre, rot in frames:
        s, p, _ = rectangle_pulses(spec, station, centre, rot, half, eps)
        sure.append(s)
        possible.append(p)
    assert np.isin(np.concatenate(sure), got).all()  # no pulse missing
    assert np.isin(got, np.concatenate(possible)).all()  # none spurious
    # every point on the nearest fin along its ray (float64 from the construction),
    # where no fin's border lies within float32's error of the ray (its choice there)
    clear = ~np.isin(got, np.setdiff1d(np.concatenate(possible), np.concatenate(sure)))
    d = res.cloud.points[clear] - station
    rng = np.linalg.norm(d, axis=1)
    d /= rng[:, None]
    nearest = np.full(len(d), np.inf)
    for centre, rot in frames:
        n = rot[:, 2]
        t = ((centre - station) @ n) / (d @ n)
        q = station + t[:, None] * d - centre
        inside = (np.abs(q @ rot[:, 0]) <= half[0] + 1e-9) & (
            np.abs(q @ rot[:, 1]) <= half[1] + 1e-9
        )
        nearest = np.where(inside & (t > 0), np.minimum(nearest, t), nearest)
    cos = np.cos(np.radians(res.cloud.fields["incidence_deg"][clear].astype(np.float64)))
    assert clear.mean() > 0.9
    assert (np.abs(rng - nearest) <= bound_m(3.0, 2.5) / cos).all()


# -- NaN and infinite vertices, empty files ---------------------------------------------


def test_nan_in_unused_vertices_is_ignored_in_used_ones_refused():
    v, f = box_arrays((-1.0, -0.5, 0.0), (1.0, 0.5, 2.0))
    spec = ScannerSpec(horizontal_resolution_deg=1.0, vertical_resolution_deg=1.0)
    st_ = [Station(position_m=(4.0, 0.0, 1.0))]
    clean = scan(Scene([MeshPart(vertices=v, faces=f)]), st_, spec)
    spare = np.vstack([v, [[np.nan, 0.0, 0.0], [np.inf, -np.inf, 1.0]]])
    identical(clean, scan(Scene([MeshPart(vertices=spare, faces=f)]), st_, spec))
    for bad in (np.nan, np.inf, -np.inf):
        vb = v.copy()
        vb[3, 1] = bad
        with pytest.raises(InvalidGeometryError, match="1 vertices have NaN or infinite"):
            Scene([MeshPart(vertices=vb, faces=f)])


def _run(argv, capsys) -> tuple[int, str, str]:
    rc = main(argv)
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".off", ".glb"])
def test_an_empty_mesh_file_is_a_one_line_error(tmp_path, capsys, suffix):
    mesh = tmp_path / f"empty{suffix}"
    mesh.write_bytes(b"")
    out = tmp_path / "out.laz"
    rc, _, err = _run(["scan", str(mesh), "-o", str(out), "--station", "5,0,1"], capsys)
    assert rc == 1
    assert messages(err) == [f"treesim: error: empty{suffix}: the file is empty (0 bytes)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [mesh.name]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("v 0 0 0\nv 1 0 0\nv inf 1 0\nf 1 2 3\n", "1 vertices have NaN or infinite"),
        ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "no (non-degenerate) triangles"),
    ],
    ids=["inf", "only-zero-area"],
)
def test_meshes_nothing_can_be_made_of_are_one_line_errors(tmp_path, capsys, text, message):
    mesh = tmp_path / "bad.obj"
    mesh.write_text(text)
    rc, _, err = _run(["scan", str(mesh), "-o", str(tmp_path / "o.laz")], capsys)
    lines = messages(err)
    assert rc == 1 and len(lines) == 1 and message in lines[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.obj"]


# -- out of every field of view or range -----------------------------------------------


@pytest.mark.parametrize("suffix", [".laz", ".ply"])
def test_a_mesh_outside_every_field_of_view_or_range_is_a_valid_empty_cloud(
    tmp_path, capsys, suffix
):
    above = box_arrays((-0.5, -0.5, 30.0), (0.5, 0.5, 31.0))  # above a 60° field of view
    far = box_arrays((80.0, -0.5, 0.0), (81.0, 0.5, 1.0))  # beyond 50 m
    v = np.vstack([above[0], far[0]])
    f = np.vstack([above[1], far[1] + len(above[0])])
    mesh = write_mesh(tmp_path / "away.ply", v, f)
    out = tmp_path / f"none{suffix}"
    argv = ["scan", str(mesh), "-o", str(out), "--station", "0,0,1", "--resolution-deg", "1"]
    rc, _, err = _run([*argv, "--max-range-m", "50", "--vfov-deg=-40,60"], capsys)
    assert rc == 0
    assert "no points were recorded" in err
    assert "beyond 50 m from every station" in err and "outside every field of view" in err
    cloud = read_cloud(out)
    assert len(cloud) == 0 and cloud.points.shape == (0, 3)
    if suffix == ".laz":
        assert laspy.read(out).header.point_count == 0
    info = json.loads(out.with_suffix(".json").read_text())
    assert info["points"] == 0 and info["lod"]["geometry"]["loaded"] == 0
    assert (info["lod"]["geometry"]["beyond_range"], info["lod"]["geometry"]["outside_fov"]) == (
        12,
        12,
    )


# -- stations inside a closed mesh, or on a surface -------------------------------------


def box_exit_m(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance along each ray from ``o`` (inside the box) to the box's walls."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf))
    return t.min(axis=1)


def sphere_directions(spec: ScannerSpec, lines: np.ndarray, cols: np.ndarray) -> np.ndarray:
    el = np.radians(spec.vertical_fov_deg[0] + lines * spec.vertical_resolution_deg)
    az = np.radians(spec.horizontal_fov_deg[0] + cols * spec.horizontal_resolution_deg)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


@EXAMPLES
@given(
    size=st.tuples(st.floats(1.0, 6.0), st.floats(1.0, 6.0), st.floats(1.0, 4.0)),
    where=st.tuples(st.floats(0.2, 0.8), st.floats(0.2, 0.8), st.floats(0.2, 0.8)),
)
def test_a_station_inside_a_closed_box_sees_every_wall_once_per_ray(size, where):
    lo = np.array([-1.0, 2.0, 0.5])
    hi = lo + np.array(size)
    o = lo + np.array(where) * (hi - lo)
    v, f = box_arrays(tuple(lo), tuple(hi))
    scene = Scene([MeshPart(vertices=v, faces=f, label="other")])
    spec = SPHERE.with_(min_range_m=0.0)
    res = scan(scene, [Station(position_m=tuple(o))], spec, check_inside=False)
    # every pulse of the sphere, once: a closed box has no gap, edges and diagonals included
    assert len(res.cloud) == spec.n_azimuth * spec.n_elevation
    assert len(np.unique(keys(res, spec))) == len(res.cloud)
    f_ = res.cloud.fields
    d = sphere_directions(spec, f_["scan_line"], f_["scan_column"])
    cos = np.cos(np.radians(f_["incidence_deg"].astype(np.float64)))
    err = np.abs(f_["range_m"] - box_exit_m(o, d, lo, hi))
    assert (err <= bound_m(0.0, float(np.abs(hi).max()) * 2) / cos).all(), err.max()


@pytest.mark.parametrize("wall", ["floor", "side"])
def test_a_station_standing_on_a_surface_sees_what_lies_off_it(wall):
    # inside a closed room, the station exactly on its floor (or on a side wall): rays
    # leaving that surface reach the other walls; rays into it see nothing beyond it
    lo, hi = np.array([-2.0, -3.0, 0.0]), np.array([4.0, 2.0, 3.0])
    o = np.array([0.25, -0.5, 0.0]) if wall == "floor" else np.array([4.0, -0.5, 1.25])
    normal_in = np.array([0.0, 0.0, 1.0]) if wall == "floor" else np.array([-1.0, 0.0, 0.0])
    v, f = box_arrays(tuple(lo), tuple(hi))
    scene = Scene([MeshPart(vertices=v, faces=f, label="other")])
    res = scan(scene, [Station(position_m=tuple(o))], SPHERE, check_inside=False)
    lines, cols = np.divmod(np.arange(SPHERE.n_elevation * SPHERE.n_azimuth), SPHERE.n_azimuth)
    d = sphere_directions(SPHERE, lines, cols)
    leaving = d @ normal_in
    t = box_exit_m(o, d, lo, hi)
    # sure: leaving by more than float32's angle, and farther than the nearest range
    eps = float32_ray_error_m(6.0, 8.0, 8.0)
    sure = (leaving > 1e-3) & (t > SPHERE.min_range_m + eps)
    possible = leaving > -1e-3
    got = keys(res, SPHERE)
    key = lines * SPHERE.n_azimuth + cols
    assert np.isin(key[sure], got).all(), int((~np.isin(key[sure], got)).sum())
    assert np.isin(got, key[possible]).all()
    at = np.searchsorted(key, got)
    cos = np.cos(np.radians(res.cloud.fields["incidence_deg"].astype(np.float64)))
    err = np.abs(res.cloud.fields["range_m"] - t[at])
    assert (err <= bound_m(0.0, 8.0) / cos).all(), err.max()
