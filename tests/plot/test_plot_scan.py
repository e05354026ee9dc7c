"""Scanning plots: known answers on terrains and placed trees, and station-by-station
loading that gives the whole plot's points."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from treesim.models import generate_tree
from treesim.params import ScanParams
from treesim.plot import Plot, PlotTree, Terrain
from treesim.plot.scan import box_reachable, scan_plot, station_trees, tree_figures
from treesim.scan import ScannerSpec, Station, scan


def _params(res=0.25, **spec):
    return replace(
        ScanParams(),
        scanner=ScannerSpec(horizontal_resolution_deg=res, vertical_resolution_deg=res, **spec),
    )


def _saplings(positions, **kw):
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i, rotation_deg=17.0 * i)
        for i, (x, y) in enumerate(positions)
    ]
    return Plot(trees, facets=8, **kw)


def test_flat_terrain_points_lie_at_z0():
    plot = _saplings([(3.0, 0.0)], terrain=Terrain(z0_m=1.25), radius_m=6)
    r = scan_plot(plot, [(0.0, 0.0, 2.75)], _params(0.5))
    ground = r.cloud.fields["label"] == 3
    assert ground.sum() > 1000
    np.testing.assert_allclose(r.cloud.points[ground, 2], 1.25, rtol=0, atol=1e-9)
    # terrain points carry tree id 0, the tree's its own
    assert set(np.unique(r.cloud.fields["tree_id"][ground])) == {0}
    assert set(np.unique(r.cloud.fields["tree_id"][~ground])) == {1}


def test_slope_points_lie_on_the_plane_and_trees_stand_on_it():
    ter = Terrain(kind="slope", z0_m=0.5, slope_deg=15.0, aspect_deg=90.0)  # falls to +x
    plot = _saplings([(3.0, 0.0), (-3.0, 2.0)], terrain=ter, radius_m=6)
    r = scan_plot(plot, [(0.0, -1.0, 2.0)], _params(0.5))
    p = r.cloud.points
    ground = r.cloud.fields["label"] == 3
    plane = 0.5 - np.tan(np.radians(15.0)) * p[ground, 0]
    np.testing.assert_allclose(p[ground, 2], plane, rtol=0, atol=1e-9)
    for t in plot.trees:
        b = plot.tree_bounds(t.tree_id)
        # the stem base sits on the terrain's lowest point under the stem: no part floats
        assert b[0, 2] == pytest.approx(float(ter.height_at(b[1, 0], 0.0)), abs=0.5)
        low = plot.tree_parts(t.tree_id)[0].vertices
        assert (low[:, 2] >= ter.height_at(low[:, 0], low[:, 1]) - 0.3).all()


def test_trees_points_lie_inside_their_own_bounds():
    pos = [(3.0, 0.0), (-3.0, 1.5), (0.5, 4.0)]
    plot = _saplings(pos, radius_m=6)
    r = scan_plot(plot, [(0.0, -2.0, 1.5), (0.0, 2.0, 1.5)], _params(0.5))
    ids = r.cloud.fields["tree_id"]
    assert set(np.unique(ids)) == {0, 1, 2, 3}
    for t in plot.trees:
        b = plot.tree_bounds(t.tree_id)
        p = r.cloud.points[ids == t.tree_id]
        assert len(p) > 100
        assert (p >= b[0] - 1e-9).all() and (p <= b[1] + 1e-9).all()
        # the stem stands where the tree was put
        stem = p[p[:, 2] < 0.3]
        if len(stem) > 10:
            assert np.hypot(*(stem[:, :2].mean(axis=0) - (t.x_m, t.y_m))) < 0.2


@pytest.mark.parametrize("cache", [0, 10**8])
def test_station_by_station_gives_the_whole_plots_points(cache):
    pos = [(3.0, 0.0), (-3.0, 1.0), (0.0, 4.0), (12.0, 0.0), (-2.0, -10.0), (0.0, -3.0)]
    plot = _saplings(
        pos, terrain=Terrain(kind="slope", slope_deg=8.0, aspect_deg=30.0), radius_m=12
    )
    params = _params(0.3, max_range_m=9.0, horizontal_fov_deg=(0.0, 200.0))
    stations = [
        Station(position_m=(0.0, 0.0, 1.5)),
        Station(position_m=(6.0, -5.0, 1.5)),
        Station(position_m=(-6.0, 6.0, 1.2)),
    ]
    part = scan_plot(plot, stations, params, cache_triangles=cache)
    # some trees were left out of some stations: beyond range, and outside the view
    assert any(ld["trees_beyond_range"] for ld in part.loading)
    assert any(ld["trees_outside_fov"] for ld in part.loading)
    assert all(ld["triangles_loaded"] < ld["triangles_total"] for ld in part.loading)
    assert plot.loaded == []  # nothing held after the scan
    if cache == 0:  # nothing kept between stations: every station built its own trees
        for ld in part.loading:
            assert set(ld["trees_built"]) == set(ld["trees_loaded"])
    whole = scan(plot.scene(), stations, params.scanner, frame=plot.frame())
    a, b = part.cloud, whole.cloud
    assert len(a) == len(b) > 10_000

    def order(c):
        return np.lexsort((c.fields["scan_column"], c.fields["scan_line"], c.fields["station"]))

    ia, ib = order(a), order(b)
    for name in ("station", "scan_line", "scan_column", "label", "tree_id", "return_number"):
        np.testing.assert_array_equal(a.fields[name][ia], b.fields[name][ib], err_msg=name)
    # the same rays hit the same surfaces; where a ray meets the shared edge of two
    # triangles, Open3D may name either (its BVH differs): the point moves by rounding
    np.testing.assert_allclose(a.points[ia], b.points[ib], rtol=0, atol=1e-12)
    inc = np.abs(a.fields["incidence_deg"][ia] - b.fields["incidence_deg"][ib])
    assert (inc > 1e-3).mean() < 1e-3


def test_box_test_is_range_and_view():
    spec = ScannerSpec(max_range_m=10.0, horizontal_fov_deg=(0.0, 90.0))
    st = Station(position_m=(0.0, 0.0, 0.0))
    o = np.zeros(3)
    near_in = np.array([[2.0, 2.0, -1.0], [3.0, 3.0, 1.0]])  # azimuth 45°
    far = near_in + 20.0
    behind = -near_in[::-1]  # azimuth 225°
    assert box_reachable(near_in, st, spec, o)
    assert not box_reachable(far, st, spec, o)
    assert not box_reachable(behind, st, spec, o)
    # the station inside a box: kept
    assert box_reachable(np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), st, spec, o)


def test_station_trees_says_why():
    plot = _saplings([(3.0, 0.0), (40.0, 0.0)], radius_m=45)
    spec = ScannerSpec(max_range_m=20.0)
    out = station_trees(plot, Station(position_m=(0.0, 0.0, 1.5)), spec)
    assert out == {"loaded": [1], "beyond_range": [2], "outside_fov": []}


def test_tree_figures_measure_each_tree_on_its_own_mesh():
    plot = _saplings([(3.0, 0.0), (-3.0, 0.0), (30.0, 0.0)], radius_m=31)
    r = scan_plot(plot, [(0.0, 0.5, 1.0)], _params(0.2, max_range_m=20.0))
    rows = tree_figures(plot, r.cloud)
    assert [row["tree_id"] for row in rows] == [1, 2, 3]
    for row in rows[:2]:
        assert row["points"] == int((r.cloud.fields["tree_id"] == row["tree_id"]).sum()) > 100
        # points lie on the tree's own mesh (to float64 rounding)
        assert row["accuracy_mean_m"] < 1e-9
        assert 0.05 < row["coverage"] < 1.0
    # beyond range: no points, nothing to measure, said so
    assert rows[2]["points"] == 0 and rows[2]["coverage"] == 0.0 and "too few" in rows[2]["note"]
    # each row carries its own tree's reference figures, checked against what the test
    # builds itself rather than plot.truth (which the rows copy): the height against the
    # tree's own mesh, what was scanned (its tip cap rises ~0.2 mm above the table's top),
    # the DBH against the stem of the generator's table for that tree's seed
    for row, tree in zip(rows[:2], plot.trees[:2], strict=True):
        z = np.concatenate([p.vertices[:, 2] for p in plot.tree_parts(tree.tree_id)])
        assert row["height_m"] == pytest.approx(np.ptp(z), abs=1e-3)
        table = generate_tree("sapling", seed=tree.seed).cylinders
        assert row["dbh_m"] == pytest.approx(_stem_diameter_m(table, 1.3), rel=1e-12)
    assert abs(rows[0]["dbh_m"] - rows[1]["dbh_m"]) > 1e-3  # two trees, told apart


def _stem_diameter_m(table, height_m: float) -> float:
    """The stem's diameter ``height_m`` above its lowest point, read off the table's stem
    rows (branch order 0) by interpolating the radius along the row that spans it."""
    stem = table.branch_order == 0
    z0, z1 = table.start[stem, 2], (table.start + table.axis * table.length_m[:, None])[stem, 2]
    target = z0.min() + height_m
    (k,) = np.flatnonzero((np.minimum(z0, z1) <= target) & (target <= np.maximum(z0, z1)))[:1]
    t = (target - z0[k]) / (z1[k] - z0[k])
    r0, r1 = table.radius_m[stem][k], table.end_radius_m[stem][k]
    return float(2 * (r0 + t * (r1 - r0)))


@pytest.mark.parametrize("when", ["station 2/2", "tree 2"])
def test_an_interrupted_plot_scan_leaves_nothing(tmp_path, when):
    from treesim.plot.scan import plot_scan_files

    plot = _saplings([(3.0, 0.0), (-3.0, 0.0)], radius_m=5)

    def progress(fraction, message):
        if message.startswith(when):
            raise KeyboardInterrupt

    out = tmp_path / "a" / "b"
    with pytest.raises(KeyboardInterrupt):
        plot_scan_files(
            plot, out, _params(1.0), stations=[(0, 1.0, 1.5), (0, -1.0, 1.5)], progress=progress
        )
    assert not (tmp_path / "a").exists()


def test_a_station_that_sees_only_the_terrain_labels_its_points_tree_0(tmp_path):
    # the sapling stands 9 m away, beyond the 5 m range: the station's scene is the
    # terrain alone, and its points still carry tree_id (0), in memory and in the file
    from treesim.io import open_cloud_writer, read_cloud
    from treesim.plot.scan import plot_fields

    plot = _saplings([(9.0, 0.0)], radius_m=10)
    params = _params(0.5, max_range_m=5.0)
    r = scan_plot(plot, [(0.0, 0.0, 1.5)], params)
    assert len(r.cloud) > 1000 and r.loading[0]["trees_loaded"] == []
    assert r.cloud.fields["tree_id"].dtype == np.uint32
    assert not r.cloud.fields["tree_id"].any()
    with open_cloud_writer(tmp_path / "s.laz", fields=plot_fields()) as w:
        scan_plot(plot, [(0.0, 0.0, 1.5)], params, sink=w.write)
    back = read_cloud(tmp_path / "s.laz")
    assert len(back) == len(r.cloud) and not back.fields["tree_id"].any()
