"""Each procedural tree of a plot is generated once (issue 25): a tree the plot dropped
(between stations, after the scan) is meshed again from the cylinder table its first
build made, not generated again, and that mesh is the generated one, bit for bit.

The oracles: the number of trees, and the meshes of a fresh plot that generates every tree
itself (counted by a spy on ``treesim.models.generate_tree``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import treesim.models as models
from treesim.params import ScanParams
from treesim.plot import Plot, PlotTree
from treesim.plot.scan import scan_plot, tree_figures
from treesim.scan import ScannerSpec, Station

STATIONS = [Station(position_m=(0.0, -2.0, 1.5)), Station(position_m=(9.0, 0.0, 1.5))]


def _plot(leaves: bool | None = False) -> Plot:
    pos = [(3.0, 0.0), (-3.0, 1.0), (12.0, 1.0)]
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i, leaves=leaves)
        for i, (x, y) in enumerate(pos)
    ]
    return Plot(trees, facets=8, radius_m=14)


def _params() -> ScanParams:
    spec = ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5, max_range_m=8.0)
    return replace(ScanParams(), scanner=spec)


@pytest.fixture
def generated(monkeypatch) -> list[int]:
    """The seeds of the trees ``generate_tree`` makes while the test runs."""
    seeds: list[int] = []
    real = models.generate_tree

    def spy(*args, **kw):
        seeds.append(int(kw["seed"]))
        return real(*args, **kw)

    monkeypatch.setattr(models, "generate_tree", spy)
    return seeds


@pytest.mark.parametrize("cache", [0, 10**9])
def test_a_plot_scan_and_its_figures_generate_each_tree_once(generated, cache):
    plot = _plot()
    res = scan_plot(plot, STATIONS, _params(), cache_triangles=cache)
    # no cache: the trees both stations record are dropped after the first and built again
    rebuilt = [t for ld in res.loading[1:] for t in ld["trees_built"]]
    assert rebuilt if cache == 0 else not rebuilt  # the case means something
    assert plot.loaded == []  # the scan dropped every tree: the figures build them again
    rows = tree_figures(plot, res.cloud)
    assert sum(r["points"] for r in rows) > 0
    assert sorted(generated) == sorted(t.seed for t in plot.trees)


def test_a_tree_built_again_is_the_generated_one_bit_for_bit(generated):
    plot = _plot()
    first = {t: plot.tree_parts(t) for t in plot.tree_ids}
    plot.release()
    n = len(generated)
    again = {t: plot.tree_parts(t) for t in plot.tree_ids}
    assert len(generated) == n == len(plot.trees)  # built again without generating
    fresh = _plot()  # generates every tree itself
    for t in plot.tree_ids:
        for a, b, c in zip(again[t], first[t], fresh.tree_parts(t), strict=True):
            for x in (b, c):
                assert (a.label, a.name, a.tree_id) == (x.label, x.name, x.tree_id)
                np.testing.assert_array_equal(a.vertices, x.vertices, strict=True)
                np.testing.assert_array_equal(a.faces, x.faces, strict=True)
        assert plot.truth(t) == fresh.truth(t)
    assert len(generated) == 2 * len(plot.trees)


def test_a_leafy_tree_is_generated_again_for_its_leaves(generated):
    plot = _plot(leaves=True)
    first = plot.tree_parts(1)
    assert "leaf" in [p.label for p in first]
    plot.release()
    again = plot.tree_parts(1)
    assert generated == [plot.tree(1).seed] * 2
    for a, b in zip(again, first, strict=True):
        assert a.label == b.label
        np.testing.assert_array_equal(a.vertices, b.vertices, strict=True)
