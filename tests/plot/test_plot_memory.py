"""Memory while a plot station casts (issue 25): one copy of the geometry.

A station's trees are dropped from the plot once its scene holds them (the scene is the
one copy that casts); the caster keeps no per-triangle corner array and its edge-fan
incidence in int32; a tree saved for the station tasks reads back exactly. The oracles
are the plot's own station-by-tree verdicts (which trees a later station needs) and the
arrays' sizes and dtypes, not the code under test's figures."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from treesim.frame import LocalFrame
from treesim.params import ScanParams
from treesim.plot import Plot, PlotTree
from treesim.plot.scan import load_tree_parts, save_tree_parts, scan_plot, station_trees
from treesim.scan import ScannerSpec, Station
from treesim.scene import Scene

STATIONS = [Station(position_m=(0.0, -2.0, 1.5)), Station(position_m=(9.0, 0.0, 1.5))]


def _plot() -> Plot:
    pos = [(3.0, 0.0), (-3.0, 1.0), (12.0, 1.0)]
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i)
        for i, (x, y) in enumerate(pos)
    ]
    return Plot(trees, facets=8, radius_m=14)


def _params() -> ScanParams:
    spec = ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5, max_range_m=8.0)
    return replace(ScanParams(), scanner=spec)


@pytest.mark.parametrize("cache", [0, 10**9])
def test_a_stations_trees_are_dropped_before_it_casts(monkeypatch, cache):
    import treesim.steps as steps

    plot = _plot()
    spec = _params().scanner
    needs = [set(station_trees(plot, st, spec)["loaded"]) for st in STATIONS]
    assert needs[0] and needs[1] and needs[0] != needs[1]  # the case means something
    held = []
    real = steps.scan_scene

    def spy(scene, *args, **kw):
        held.append((set(plot.loaded), len(scene.parts)))
        return real(scene, *args, **kw)

    monkeypatch.setattr(steps, "scan_scene", spy)
    scan_plot(plot, STATIONS, _params(), cache_triangles=cache)
    assert len(held) == 2
    # while station 0 casts, the plot holds at most what station 1 still needs (the
    # cache's purpose), and nothing with no cache; while the last casts, nothing
    assert held[0][0] == (needs[1] if cache else set())
    assert held[1][0] == set()
    assert all(n == 0 for _, n in held)  # the scene let its parts go too


def test_the_caster_holds_one_float64_copy_and_int32_fans():
    from treesim.scan.caster import Caster

    plot = _plot()
    scene = Scene(plot.tree_parts(1) + plot.tree_parts(2), keep_tree_ids=True)
    nv, nf = len(scene.vertices), scene.n_triangles
    caster = Caster(scene, LocalFrame(origin=(0.0, 0.0, 0.0)), nthreads=1)
    shared = {id(scene.faces), id(scene.face_label), id(scene.face_tree)}
    own = sum(
        a.nbytes for a in vars(caster).values() if isinstance(a, np.ndarray) and id(a) not in shared
    )
    # its local float64 vertices, float64 normals, float32 smallest heights: no more
    assert own <= 24 * nv + 24 * nf + 4 * nf + 4096
    # the first corners are gathered, the same values a held array gave
    tri = np.array([0, nf // 2, nf - 1])
    np.testing.assert_array_equal(caster.v0[tri], caster.v[scene.faces[tri, 0]])
    corners, ptr, inc = caster._fans()
    assert corners.dtype == np.int32 and inc.dtype == np.int32
    assert corners.shape == (nf, 3) and len(inc) == 3 * nf and ptr[-1] == 3 * nf


def test_a_saved_tree_reads_back_exactly(tmp_path):
    plot = _plot()
    parts = plot.tree_parts(2)
    save_tree_parts(tmp_path, 2, parts)
    back = load_tree_parts(tmp_path, 2)
    assert len(back) == len(parts)
    for a, b in zip(parts, back, strict=True):
        assert (a.label, a.name, a.tree_id) == (b.label, b.name, b.tree_id)
        assert b.vertices.dtype == np.float64 and b.faces.dtype == np.int32
        np.testing.assert_array_equal(np.asarray(a.vertices), b.vertices)
        np.testing.assert_array_equal(np.asarray(a.faces), b.faces)
        assert isinstance(b.vertices, np.memmap)  # read when the scene copies it
    # the same scene, bit for bit, from either
    s1, s2 = Scene(parts), Scene(back)
    np.testing.assert_array_equal(s1.vertices, s2.vertices)
    np.testing.assert_array_equal(s1.faces, s2.faces)
