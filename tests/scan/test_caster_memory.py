"""Memory while casting (issue 25): one copy of the geometry, figures gathered when read.

The scene holds int32 faces and a used-vertex mask; the caster holds no per-triangle or
per-vertex array of its own (it reads the scene's, through an int32 index when only some
triangles are loaded) and gathers each hit's corners, normal and smallest height; the
occupancy cull adds each chunk's boxes to its raster as it goes. The oracles: the
figures computed over whole arrays with plain numpy (what a held array gave), the
scene's own arrays subset by the mask, a raster filled box by box in Python, and the
bytes numpy allocates (tracemalloc: exact and deterministic, not a measure of RSS).
"""

from __future__ import annotations

import importlib
import tracemalloc

import numpy as np
import pytest

from tests.conftest import box_arrays
from treesim.frame import LocalFrame
from treesim.models import generate_tree
from treesim.scene import MeshPart, Scene

caster_module = importlib.import_module("treesim.scan.caster")
occupancy = importlib.import_module("treesim.scan.occupancy")


def _scene() -> Scene:
    tree = generate_tree("sapling", seed=3)
    v, f, _ = tree.mesh(facets=8)
    ground = box_arrays((-8.0, -8.0, v[:, 2].min() - 0.2), (8.0, 8.0, v[:, 2].min()))
    parts = [
        MeshPart(vertices=v + 1e5, faces=f, label="wood", name="sapling", tree_id=3),
        MeshPart(vertices=ground[0] + 1e5, faces=ground[1], label="ground", name="ground"),
    ]
    return Scene(parts)


def test_the_scene_holds_int32_faces_and_a_used_mask():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0], [5, 5, 5]])
    scene = Scene([MeshPart(vertices=v, faces=np.array([[0, 1, 2], [4, 1, 2]]), name="m")])
    assert scene.faces.dtype == np.int32
    np.testing.assert_array_equal(scene.faces, [[0, 1, 2], [4, 1, 2]])
    np.testing.assert_array_equal(scene.used_vertices, v[[0, 1, 2, 4]])
    np.testing.assert_array_equal(scene.bounds, [[0, 0, 0], [5, 5, 5]])
    assert scene._used.dtype == bool and scene._used.nbytes == len(v)


@pytest.mark.parametrize("held", [False, True])
@pytest.mark.parametrize("partial", [False, True])
def test_the_caster_keeps_no_per_triangle_array_and_gathers_the_same_figures(
    monkeypatch, partial, held
):
    """Gathered (a large scene's; here forced) or held (a small one's normals and
    heights): the figures whole-array numpy gives, and nothing else per triangle."""
    if not held:
        monkeypatch.setattr(caster_module, "HELD_GEOMETRY_BYTES", 0)
    scene = _scene()
    nf = scene.n_triangles
    keep = None
    if partial:
        keep = np.zeros(nf, dtype=bool)
        keep[::3] = True
    frame = LocalFrame(origin=(1e5 + 0.25, 1e5 - 0.5, 1e5))
    caster = caster_module.Caster(scene, frame, nthreads=1, keep=keep)
    shared = {id(a) for a in (scene.vertices, scene.faces, scene.face_label, scene.face_tree)}

    # every distinct array the caster (and its gathering views) holds, less the scene's
    held_bytes = {
        id(a): a.nbytes
        for obj in (caster, caster.faces, caster.label, caster.tree)
        for a in getattr(obj, "__dict__", {}).values()
        if isinstance(a, np.ndarray) and id(a) not in shared
    }
    # the loaded triangles' int32 index, when only some are loaded; the held normals
    # and heights of a small scene; else nothing
    n_loaded = int(keep.sum()) if partial else nf
    bound = (4 * n_loaded if partial else 0) + (28 * n_loaded if held else 0) + 1024
    assert sum(held_bytes.values()) <= bound
    assert isinstance(caster.normal, np.ndarray) == held
    # the oracle: whole arrays, as a held copy computed them
    f = scene.faces if keep is None else scene.faces[keep]
    v = scene.vertices - frame.origin_array
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(p1 - p0, p2 - p0)
    area2 = np.linalg.norm(n, axis=1)
    edge2 = np.stack([((p1 - p0) ** 2).sum(1), ((p2 - p1) ** 2).sum(1), ((p2 - p0) ** 2).sum(1)])
    h32 = (area2 / np.sqrt(edge2.max(axis=0))).astype(np.float32)
    idx = np.random.default_rng(0).integers(0, len(f), 500)
    np.testing.assert_array_equal(caster.normal[idx], (n / area2[:, None])[idx])
    np.testing.assert_array_equal(caster.v0[idx], p0[idx])
    np.testing.assert_array_equal(caster.h_min32[idx], h32[idx])
    np.testing.assert_array_equal(caster.v, v)
    np.testing.assert_array_equal(caster.faces[idx], f[idx])
    np.testing.assert_array_equal(np.asarray(caster.faces), f)
    labels = scene.face_label if keep is None else scene.face_label[keep]
    trees = scene.face_tree if keep is None else scene.face_tree[keep]
    np.testing.assert_array_equal(caster.label[idx], labels[idx])
    np.testing.assert_array_equal(caster.tree[idx], trees[idx])
    assert len(caster.faces) == len(caster.normal) == len(f)


def test_the_difference_raster_counts_every_box_whatever_the_flushes():
    rng = np.random.default_rng(4)
    n_rows, n_cols, cell, n = 13, 17, 2, 400
    r0 = rng.integers(0, n_rows, n)
    r1 = np.minimum(r0 + rng.integers(0, 4, n), n_rows - 1)
    c0 = rng.integers(0, n_cols, n)
    c1 = np.where(rng.random(n) < 0.2, -1, np.minimum(c0 + rng.integers(0, 5, n), n_cols - 1))
    w = np.where(rng.random(n) < 0.3, rng.integers(0, 2 * n_cols, n), -1)
    truth = np.zeros((n_rows, n_cols), dtype=np.int64)
    for i in range(n):
        if c1[i] >= c0[i]:
            truth[r0[i] : r1[i] + 1, c0[i] : c1[i] + 1] += 1
        if w[i] >= 0:
            truth[r0[i] : r1[i] + 1, : w[i] // cell + 1] += 1
    raster = occupancy._DiffRaster(n_rows, n_cols, cell)
    raster.flush_at = 100  # counted every few calls, and once at the end
    for a in range(0, n, 37):
        s = slice(a, a + 37)
        raster.add_boxes(r0[s], r1[s], c0[s], c1[s], w[s])
    got = raster.counts().cumsum(axis=0).cumsum(axis=1)[:n_rows, :n_cols]
    np.testing.assert_array_equal(got, truth)


def test_the_occupancy_cull_holds_no_box_per_triangle(monkeypatch):
    """Small triangles (none bisected), bounded a chunk at a time: the bytes numpy holds at
    the peak do not grow with the triangles beyond the chunk's and the raster's (the cull
    held ~150 B a triangle when every box waited for the end)."""
    from treesim.scan import ScannerSpec
    from treesim.scan.rays import box_window, windowed_grid

    monkeypatch.setattr(occupancy, "_PIECE_CHUNK", 2048)
    monkeypatch.setattr(occupancy, "_FLUSH_CORNERS", 4096)
    spec = ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5)

    def peak(n: int) -> int:
        rng = np.random.default_rng(1)
        centre = rng.normal(size=(n, 3)) * 2.0 + np.array([10.0, 10.0, 2.0])  # azimuth ~45°
        tri = centre[:, None, :] + rng.normal(size=(n, 3, 3)) * 0.2
        v, f = tri.reshape(-1, 3), np.arange(3 * n).reshape(n, 3)
        win = windowed_grid(spec, box_window(v.min(axis=0), v.max(axis=0)))
        tracemalloc.start()
        occupancy.occupancy_grid(v, f, spec, win, 0.0, abs_error_m=1e-6)
        top = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return top

    small, large = peak(20_000), peak(80_000)
    # 60 000 more triangles: the bool per piece of the level's big-piece mask, and room
    assert large - small <= 4 * 60_000


def test_a_scan_with_gathered_normals_is_the_held_ones_bit_for_bit(monkeypatch):
    """The same points and fields, beam on and off, whether the caster holds its normals
    and heights or gathers them."""
    from treesim.scan import ScannerSpec, Station, scan

    scene = _scene()
    lo, hi = scene.bounds
    st = [Station(position_m=(0.5 * (lo[0] + hi[0]) + 5.0, 0.5 * (lo[1] + hi[1]), lo[2] + 1.5))]
    specs = [
        ScannerSpec(horizontal_resolution_deg=0.25, vertical_resolution_deg=0.25),
        ScannerSpec(
            horizontal_resolution_deg=0.5,
            vertical_resolution_deg=0.5,
            beam_divergence_mrad=2.0,
            subrays=7,
            return_mode="all",
        ),
    ]
    # the edge model reads the hits' normals and planes in its own loops
    specs.append(specs[1].with_(beam_sampling="edge", subrays=19))
    held = [scan(scene, st, spec, nthreads=1).cloud for spec in specs]
    monkeypatch.setattr(caster_module, "HELD_GEOMETRY_BYTES", 0)
    gathered = [scan(scene, st, spec, nthreads=1).cloud for spec in specs]
    for a, b in zip(held, gathered, strict=True):
        assert len(a) > 1000
        np.testing.assert_array_equal(a.points, b.points)
        for name in a.fields:
            np.testing.assert_array_equal(a.fields[name], b.fields[name], err_msg=name)
