"""Casting only where the scene can be: the same points, bit for bit, as the window.

``scan(..., cull=True)`` (the default) casts only the cells of each station's window that
some triangle's conservative angular bounds reach (:mod:`treesim.scan.occupancy`);
``cull=False`` casts the whole window rectangle. Every case here compares the two on
geometry chosen to break a careless raster: thin twigs seen edge-on, triangles across the
±180° atan2 seam and the 0/360° column seam, triangles around the zenith and the nadir,
tilted stations, partial fields of view, jitter and the beam's sub-rays.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import box_arrays, cylinder_arrays
from treesim.models import generate_tree
from treesim.scan import ScannerSpec, Station, scan
from treesim.scan.occupancy import triangle_bounds
from treesim.scene import MeshPart, Scene


def identical(a, b) -> None:
    """Same points and fields, in the same order, bit for bit."""
    assert len(a.cloud) == len(b.cloud)
    np.testing.assert_array_equal(a.cloud.points, b.cloud.points)
    for name, values in a.cloud.fields.items():
        np.testing.assert_array_equal(values, b.cloud.fields[name], err_msg=name)


def culled_and_window(scene, stations, spec, **kw):
    culled = scan(scene, stations, spec, **kw)
    whole = scan(scene, stations, spec, cull=False, **kw)
    identical(culled, whole)
    assert culled.cull and not whole.cull
    return culled, whole


def part(v, f, label="wood", name="part"):
    return MeshPart(vertices=v, faces=f, label=label, name=name)


def strip(p0, p1, width_m, normal_hint=(0.0, 0.0, 1.0)):
    """A flat strip (two triangles) from p0 to p1, ``width_m`` wide."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    side = np.cross(axis, normal_hint)
    side = side / np.linalg.norm(side) * width_m / 2
    v = np.array([p0 - side, p0 + side, p1 + side, p1 - side])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


SPEC = ScannerSpec(
    horizontal_resolution_deg=0.1, vertical_resolution_deg=0.1, vertical_fov_deg=(-90.0, 90.0)
)


def test_a_procedural_tree_from_three_stations():
    tree = generate_tree("sapling", seed=3)
    v, f, _ = tree.mesh(facets=8)
    scene = Scene([part(v, f, name="sapling")])
    c = (v.min(axis=0) + v.max(axis=0)) / 2
    stations = [
        Station(position_m=(c[0] + 6 * np.cos(a), c[1] + 6 * np.sin(a), v[:, 2].min() + 1.5))
        for a in np.radians([0.0, 120.0, 240.0])
    ]
    culled, whole = culled_and_window(scene, stations, SPEC.with_(vertical_fov_deg=(-40.0, 90.0)))
    assert len(culled.cloud) > 1000
    # most of a sapling's window is sky: far fewer rays
    assert culled.rays_cast < 0.5 * whole.rays_cast
    assert culled.summary()["pulses_window"] == whole.rays_cast


def test_thin_twigs_seen_edge_on_and_end_on():
    parts = [
        # 1 mm strips whose plane contains the station: seen exactly edge-on
        part(*strip((5.0, -1.0, 1.5), (5.0, 1.0, 1.5), 0.001, (0.0, 0.0, 1.0)), name="edge"),
        part(*strip((6.0, 0.3, 0.0), (6.0, 0.3, 3.0), 0.001, (6.0, 0.3, 0.0)), name="edge2"),
        # a 0.5 mm twig pointing at the station, and one across the view
        part(*cylinder_arrays(0.0005, 0.8, 6, (0.0, 0.0, 0.0)), name="end_on"),
        part(*cylinder_arrays(0.0005, 2.0, 6, (7.0, -0.4, 0.2)), name="across"),
    ]
    # turn the end-on twig to point along x, 4 m out
    v = parts[2].vertices
    parts[2] = part(np.c_[v[:, 2] + 4.0, v[:, 1] - 0.2, v[:, 0] + 1.2], parts[2].faces, name="end")
    scene = Scene(parts)
    st = [Station(position_m=(0.0, 0.0, 1.5))]
    spec = SPEC.with_(horizontal_resolution_deg=0.01, vertical_resolution_deg=0.01)
    culled, whole = culled_and_window(scene, st, spec)
    assert len(culled.cloud) > 0
    assert culled.rays_cast < 0.2 * whole.rays_cast


@pytest.mark.parametrize("heading_deg", [0.0, 180.0, 90.0])
def test_triangles_across_the_azimuth_seams(heading_deg):
    # boxes behind (atan2's ±180° seam) and in front (the grid's 0/360° column seam)
    back = box_arrays((-6.0, -0.7, 0.0), (-5.0, 0.9, 2.0))
    front = box_arrays((5.0, -0.3, 0.0), (6.0, 0.4, 2.0))
    scene = Scene([part(*back, name="back"), part(*front, name="front")])
    st = [Station(position_m=(0.0, 0.0, 1.0), heading_deg=heading_deg)]
    culled, whole = culled_and_window(scene, st, SPEC)
    az = np.degrees(np.arctan2(culled.cloud.points[:, 1], culled.cloud.points[:, 0]))
    assert (np.abs(az) > 170).any() and (np.abs(az) < 10).any()
    assert culled.rays_cast < whole.rays_cast


def test_triangles_around_the_zenith_and_the_nadir():
    # a plate right above the station (its triangles contain the vertical axis: every
    # azimuth), a ring of plates near the zenith that do not, the same below
    parts = [
        part(*box_arrays((-1.0, -1.0, 4.0), (1.0, 1.0, 4.05)), name="zenith"),
        part(*box_arrays((-1.0, -1.0, -3.05), (1.0, 1.0, -3.0)), name="nadir"),
    ]
    for a in np.radians([20.0, 140.0, 260.0]):
        x, y = 0.4 * np.cos(a), 0.4 * np.sin(a)
        parts.append(part(*box_arrays((x, y, 6.0), (x + 0.2, y + 0.05, 6.1)), name="near"))
    scene = Scene(parts)
    st = [Station(position_m=(0.0, 0.0, 0.0))]
    b = triangle_bounds(parts[0].vertices[parts[0].faces])
    assert b.full_az.any()  # the case is what it claims to be
    culled, _ = culled_and_window(scene, st, SPEC.with_(horizontal_resolution_deg=0.5))
    el = np.degrees(
        np.arcsin(culled.cloud.points[:, 2] / np.linalg.norm(culled.cloud.points, axis=1))
    )
    assert el.max() > 89.0 and el.min() < -89.0


@pytest.mark.parametrize(
    "station",
    [
        Station(position_m=(0.0, 0.0, 1.0), heading_deg=-30.0, pitch_deg=12.0, roll_deg=-7.0),
        Station(position_m=(5.0, 0.2, 3.0)),  # above the box, inside its footprint
    ],
    ids=["tilted", "inside-footprint"],
)
def test_tilted_and_overhead_stations(station):
    scene = Scene(
        [
            part(*box_arrays((4.0, -0.5, 0.0), (6.0, 0.5, 2.0))),
            part(*strip((3, -2, 0.5), (3.5, 2, 2.5), 0.002)),
        ]
    )
    culled_and_window(scene, [station], SPEC.with_(horizontal_resolution_deg=0.05))


def test_a_partial_field_of_view_cutting_through_the_scene():
    scene = Scene([part(*box_arrays((4.0, -1.0, 0.0), (6.0, 1.0, 2.0)))])
    spec = SPEC.with_(horizontal_fov_deg=(-3.0, 7.0), vertical_fov_deg=(-10.0, 5.0))
    culled, _ = culled_and_window(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec)
    az = np.degrees(np.arctan2(culled.cloud.points[:, 1], culled.cloud.points[:, 0]))
    assert az.min() >= -3.0 - 1e-9 and az.max() <= 7.0 + 1e-9


def test_jitter_and_full_beam_sampling_and_chunk_sizes():
    tree = generate_tree("sapling", seed=1)
    v, f, _ = tree.mesh(facets=6)
    scene = Scene([part(v, f)])
    c = (v.min(axis=0) + v.max(axis=0)) / 2
    st = [Station(position_m=(c[0] + 5.0, c[1], v[:, 2].min() + 1.0))]
    spec = ScannerSpec(
        horizontal_resolution_deg=0.2,
        vertical_resolution_deg=0.2,
        angular_jitter_sd_deg=0.05,
        beam_divergence_mrad=2.0,
        subrays=7,
        beam_sampling="full",
        return_mode="all",
        range_noise_sd_m=0.002,
    )
    a, _ = culled_and_window(scene, st, spec)
    b = scan(scene, st, spec, chunk_rays=997)
    identical(a, b)
    assert len(a.cloud) > 100


def test_geometry_no_station_can_record_is_not_loaded():
    near = box_arrays((4.0, -0.5, 0.0), (5.0, 0.5, 2.0))
    far = box_arrays((60.0, -0.5, 0.0), (61.0, 0.5, 2.0))  # beyond max_range_m
    high = box_arrays((-0.5, -0.5, 30.0), (0.5, 0.5, 31.0))  # above the field of view
    scene = Scene([part(*near, name="near"), part(*far, name="far"), part(*high, name="high")])
    st = [Station(position_m=(0.0, 0.0, 1.0))]
    spec = ScannerSpec(
        horizontal_resolution_deg=0.2,
        vertical_resolution_deg=0.2,
        vertical_fov_deg=(-40.0, 60.0),
        max_range_m=50.0,
    )
    auto = scan(scene, st, spec)
    full = scan(scene, st, spec, lod="full")
    np.testing.assert_array_equal(auto.cloud.points, full.cloud.points)
    geo = auto.lod["geometry"]
    assert (geo["triangles"], geo["loaded"]) == (36, 12)
    assert (geo["beyond_range"], geo["outside_fov"]) == (12, 12)
    assert "beyond 50 m" in geo["why"]
    assert full.lod["geometry"]["loaded"] == 36


def test_nothing_in_range_is_an_empty_scan():
    scene = Scene([part(*box_arrays((60.0, -0.5, 0.0), (61.0, 0.5, 2.0)))])
    spec = ScannerSpec(max_range_m=50.0, horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5)
    r = scan(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec)
    assert len(r.cloud) == 0 and r.rays_cast == 0
    assert r.lod["geometry"]["loaded"] == 0
    assert set(r.cloud.fields) >= {"range_m", "scan_line", "station"}


def test_chunked_planning_and_validation_change_nothing(monkeypatch):
    """Scene validation, the triangles to load, the caster's per-triangle data and the
    occupancy grid work a chunk of triangles at a time: tiny chunks (and gathering the
    triangles from vertices and faces a chunk at a time) give the same scene, plan and
    points, bit for bit."""
    import importlib

    import treesim.scene as scene_module

    occupancy = importlib.import_module("treesim.scan.occupancy")
    caster = importlib.import_module("treesim.scan.caster")
    from treesim.scan.rays import windowed_grid

    tree = generate_tree("sapling", seed=3)
    v, f, _ = tree.mesh(facets=8)
    ground = box_arrays((-8.0, -8.0, v[:, 2].min() - 0.2), (8.0, 8.0, v[:, 2].min()))
    parts = [part(v, f, name="sapling"), part(*ground, label="ground", name="ground")]
    c = (v.min(axis=0) + v.max(axis=0)) / 2
    stations = [Station(position_m=(c[0] + 5.0, c[1], v[:, 2].min() + 1.5))]
    spec = SPEC.with_(vertical_fov_deg=(-40.0, 90.0), max_range_m=7.0)
    scene = Scene(parts)
    ref = scan(scene, stations, spec)
    # the occupancy grid a chunk of triangles (and of bisected pieces) at a time is that
    # of all of them at once
    o = stations[0].position
    rel = (scene.vertices - o) @ stations[0].rotation
    box = rel[scene.faces].reshape(-1, 3)
    from treesim.scan.rays import box_window

    win = windowed_grid(spec, box_window(box.min(axis=0), box.max(axis=0)))
    given = occupancy.occupancy_grid(rel, scene.faces, spec, win, 0.0, abs_error_m=1e-6)
    assert len(scene.faces) < occupancy._PIECE_CHUNK  # one chunk, against many
    monkeypatch.setattr(occupancy, "_PIECE_CHUNK", 997)
    gathered = occupancy.occupancy_grid(rel, scene.faces, spec, win, 0.0, abs_error_m=1e-6)
    assert given.n_pulses == gathered.n_pulses > 0
    np.testing.assert_array_equal(
        given.indices(0, given.n_pulses), gathered.indices(0, given.n_pulses)
    )
    monkeypatch.setattr(caster, "BOUNDS_CHUNK", 1009)
    monkeypatch.setattr(scene_module, "_CHECK_CHUNK", 101)
    small = Scene(parts)
    np.testing.assert_array_equal(small.faces, scene.faces)
    assert small.dropped_degenerate == scene.dropped_degenerate
    again = scan(small, stations, spec)
    identical(again, ref)
    assert again.lod == ref.lod
    assert [s.pulses_cast for s in again.station_stats] == [
        s.pulses_cast for s in ref.station_stats
    ]


def test_pieces_at_a_full_turns_column_seam_are_not_cut_forever(monkeypatch):
    # boxes all round make the window the full turn, whose raster measures column angles
    # from a seam beside azimuth 0; a tree on the +x axis lies across it. A piece across
    # the seam was counted as wide as the raster, stayed big however small it was cut,
    # and the seam's pieces doubled every level up to MAX_PIECES (2,097,152)
    import importlib

    occupancy = importlib.import_module("treesim.scan.occupancy")
    v, f, _ = generate_tree("sapling", seed=0).mesh(facets=8)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    tree = v - np.array([c[0] - 6.0, c[1], 0.0])
    boxes = [((-0.5, 5.0, 0.0), (0.5, 6.0, 2.0)), ((-6.0, -0.5, 0.0), (-5.0, 0.5, 2.0))]
    boxes.append(((-0.5, -6.0, 0.0), (0.5, -5.0, 2.0)))
    parts = [part(tree, f, name="tree")]
    parts += [part(*box_arrays(lo, hi), name=f"box{i}") for i, (lo, hi) in enumerate(boxes)]
    # ground all round: every column holds geometry, so the seam cannot sit in a gap
    g = np.linspace(-9.0, 9.0, 13)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    gv = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    k = np.arange(12)[:, None] * 13 + np.arange(12)[None, :]
    k = k.ravel()
    gf = np.concatenate(
        [np.column_stack([k, k + 13, k + 1]), np.column_stack([k + 1, k + 13, k + 14])]
    )
    parts.append(part(gv, gf, label="ground", name="ground"))
    scene = Scene(parts)
    pieces: list[int] = []
    bisect = occupancy._bisect_longest

    def counted(rows):
        pieces.append(rows.shape[2])
        return bisect(rows)

    monkeypatch.setattr(occupancy, "_bisect_longest", counted)
    culled, whole = culled_and_window(scene, [Station(position_m=(0.0, 0.0, 1.0))], SPEC)
    az = culled.station_stats[0].azimuth_window_deg
    assert az is None or az[1] - az[0] >= 359.0, az  # the full turn
    assert pieces, "no piece was bisected: the case does not reach the seam's pieces"
    # a piece is halved each level: the largest (a ground triangle beside the station,
    # ~100° wide) is within the 512-cell box of 2 x 2-pulse cells after about ten levels
    # (measured before the fix: 21 levels, 10,409 pieces bisected; after: 8 and 1,980)
    assert len(pieces) <= 12 and sum(pieces) < scene.n_triangles, pieces
    assert culled.rays_cast < whole.rays_cast
