"""The bounded-memory paths of reconstruction (issue 13 §3) give the answers of the plain
ones: each is checked against the straightforward computation it replaced, on small
clouds whose answer is known or computed the plain way here."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from tests.reconstruct.shapes import stem_on_ground, tube
from treesim.geometry import point_spacing
from treesim.reconstruct.preprocess import (
    PrepareParams,
    nearest_neighbors,
    prepare,
    statistical_outliers,
)
from treesim.reconstruct.qsm import _bridge, _knn_graph, fit_qsm

# `treesim.reconstruct` the package, not the function `treesim.reconstruct`
_edge_watertight = importlib.import_module("treesim.reconstruct")._edge_watertight
_neighbours = importlib.import_module("treesim.reconstruct.neighbours")
_qsm = importlib.import_module("treesim.reconstruct.qsm")
#: The modules that read preparation's chunk size (each binds its own name).
_PREPARE_CHUNKED = [
    importlib.import_module(f"treesim.reconstruct.{name}")
    for name in ("neighbours", "outliers", "normals", "leaf_measure")
]


@pytest.fixture(params=["one chunk", "chunks of 97"])
def chunks(request, monkeypatch):
    """Run a test with the default chunk size and with chunks small enough to split the
    test clouds, so the code that carries state across chunks is exercised too."""
    if request.param != "one chunk":
        for module in _PREPARE_CHUNKED:
            monkeypatch.setattr(module, "_CHUNK", 97)
        monkeypatch.setattr(_qsm, "_CHUNK", 97)
    return request.param


@pytest.fixture(scope="module")
def clumpy() -> np.ndarray:
    """1,500 points in clumps of different density: k-nearest-neighbour relations that
    are often one-sided."""
    rng = np.random.default_rng(3)
    centres = rng.uniform(0.0, 1.0, (15, 3))
    spread = rng.uniform(0.005, 0.05, 15)
    return np.concatenate(
        [c + rng.normal(scale=s, size=(100, 3)) for c, s in zip(centres, spread, strict=True)]
    )


def plain_knn_graph(p: np.ndarray, k: int, link_m: float) -> sparse.csr_matrix:
    """The graph as the QSM built it before: one-sided kNN edges, then A.maximum(A.T)."""
    n = len(p)
    d, idx = cKDTree(p).query(p, k=k + 1)
    rows = np.repeat(np.arange(n), k)
    w, cols = d[:, 1:].ravel(), idx[:, 1:].ravel()
    keep = w <= link_m
    a = sparse.coo_matrix(
        (np.maximum(w[keep], 1e-9), (rows[keep], cols[keep])), shape=(n, n)
    ).tocsr()
    return a.maximum(a.T).tocsr()


@pytest.mark.parametrize("link_m", [0.01, 0.03, 1.0])
def test_knn_graph_equals_the_symmetric_maximum_of_the_one_sided_graph(clumpy, link_m, chunks):
    nb, _ = nearest_neighbors(clumpy, 24)
    g = _knn_graph(clumpy, nb, 10, link_m)
    ref = plain_knn_graph(clumpy, 10, link_m)
    assert g.nnz > 0
    assert np.array_equal(g.indptr, ref.indptr)
    assert np.array_equal(g.indices, ref.indices)
    assert np.array_equal(g.data, ref.data)  # same lengths, bit for bit
    assert g.indices.dtype == np.int32


def test_the_test_cloud_has_one_sided_neighbours(clumpy):
    # the mirrored edges of _knn_graph are exercised only if some are one-sided
    d, idx = cKDTree(clumpy).query(clumpy, k=11)
    a = sparse.coo_matrix(
        (d[:, 1:].ravel() + 1, (np.repeat(np.arange(1500), 10), idx[:, 1:].ravel()))
    )
    assert (a != a.T).nnz > 100


def test_directed_dijkstra_on_the_symmetric_graph_equals_undirected(clumpy):
    nb, _ = nearest_neighbors(clumpy, 24)
    g = _knn_graph(clumpy, nb, 10, 1.0)
    src = np.flatnonzero(clumpy[:, 2] <= clumpy[:, 2].min() + 0.05)
    d1, p1, _ = dijkstra(g, directed=True, indices=src, min_only=True, return_predecessors=True)
    d2, p2, _ = dijkstra(g, directed=False, indices=src, min_only=True, return_predecessors=True)
    assert np.array_equal(d1, d2) and np.array_equal(p1, p2)


def test_bridges_are_the_shortest_gaps(chunks):
    # three rows of points 1 cm apart along x; gaps of 5 cm and 8 cm between the rows'
    # nearest ends: two bridges with exactly those lengths, and one component after
    x = np.arange(50) * 0.01
    a = np.c_[x, np.zeros(50), np.zeros(50)]
    b = a + [0.49 + 0.05, 0.0, 0.0]
    c = a + [2 * 0.49 + 0.05 + 0.08, 0.0, 0.0]
    p = np.concatenate([a, b, c])
    nb, _ = nearest_neighbors(p, 24)
    g = _knn_graph(p, nb, 10, 0.015)
    assert connected_components(g, directed=False)[0] == 3
    joined, n_bridges = _bridge(p, g, nb, 0)
    assert n_bridges == 2
    assert connected_components(joined, directed=False)[0] == 1
    added = (joined - g).tocoo()
    assert sorted(np.round(added.data, 9).tolist()) == [0.05, 0.05, 0.08, 0.08]


def test_fit_qsm_with_and_without_the_prepared_neighbours_agree(chunks):
    # prepare's neighbours, as reconstruct() hands them over: outliers removed, so they
    # are derived from the whole cloud's search, not searched again as fit_qsm does
    pts, _ = tube(radius=0.05, height=0.6, n=3000, noise_m=0.0005, seed=1)
    scatter = np.random.default_rng(4).uniform(-0.3, 0.9, (30, 3))
    prep = prepare(np.vstack([pts, scatter]), PrepareParams(voxel_size_m=None), normals=False)
    assert prep.steps[1]["removed"] > 0
    own = fit_qsm(prep.points, spacing_m=prep.spacing_m)
    given = fit_qsm(prep.points, spacing_m=prep.spacing_m, neighbors=prep.neighbors)
    assert own.table.n_cylinders > 3
    for name in ("start", "axis", "length_m", "radius_m", "parent"):
        assert np.array_equal(getattr(own.table, name), getattr(given.table, name)), name


def test_fit_qsm_in_chunks_equals_fit_qsm_in_one_chunk(monkeypatch):
    # the graph, the bridges and the within-slice graph carry state across chunks: split
    # into chunks of 97 points, the fit must not change
    pts, _ = tube(radius=0.05, height=0.6, n=3000, noise_m=0.0005, seed=1)
    spacing = point_spacing(pts, distinct=False)
    whole = fit_qsm(pts, spacing_m=spacing)
    monkeypatch.setattr(_qsm, "_CHUNK", 97)
    split = fit_qsm(pts, spacing_m=spacing)
    assert whole.table.n_cylinders > 3
    assert whole.table.identical(split.table)


def test_prepare_without_normals_measures_the_same(chunks):
    pts, _ = tube(radius=0.1, height=0.8, n=5000, noise_m=0.001, seed=2)
    with_normals = prepare(pts)
    without = prepare(pts, normals=False)
    assert with_normals.normals is not None and without.normals is None
    assert np.array_equal(with_normals.points, without.points)
    assert with_normals.spacing_m == without.spacing_m
    assert with_normals.leaf_fraction == without.leaf_fraction
    # the kept neighbours are a plain k-d tree search, itself first
    _, idx = cKDTree(without.points).query(without.points, k=24)
    assert np.array_equal(without.neighbors, idx)
    assert without.neighbors.dtype == np.int32
    assert without.spacing_m == point_spacing(without.points, distinct=False)


@pytest.mark.parametrize("searched", ["by itself", "by prepare (knn)"])
def test_outlier_removal_in_chunks_keeps_the_plain_rule(clumpy, chunks, searched):
    rng = np.random.default_rng(5)
    p = np.concatenate([clumpy, rng.uniform(-2.0, 3.0, (40, 3))])
    knn = nearest_neighbors(p, 24)[0] if searched == "by prepare (knn)" else None
    keep = statistical_outliers(p, 16, 2.0, knn=knn)
    dist, idx = cKDTree(p).query(p, k=17)
    mean_d = dist[:, 1:].mean(axis=1)
    local = np.median(mean_d[idx[:, 1:]], axis=1)
    plain = (mean_d <= mean_d.mean() + 2.0 * mean_d.std()) | (
        (mean_d <= 3.0 * local) & (mean_d <= 30.0 * np.median(mean_d))
    )
    assert np.array_equal(keep, plain)
    assert (~keep[-40:]).sum() >= 30  # most far scatter goes


def test_watertight_check():
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    assert _edge_watertight(tet)
    flipped = tet.copy()
    flipped[0] = flipped[0, ::-1]
    assert not _edge_watertight(flipped)
    assert not _edge_watertight(tet[:3])  # open
    assert not _edge_watertight(np.vstack([tet, tet[:1]]))  # a face twice
    assert not _edge_watertight(np.zeros((0, 3), dtype=np.int64))
    two = np.vstack([tet, tet + 4])  # two closed pieces
    assert _edge_watertight(two)


def test_prepare_params_default_neighbours_cover_the_qsm():
    # the QSM reuses the prepared neighbours when they have enough columns
    from treesim.reconstruct import QSMParams
    from treesim.reconstruct.preprocess import KEPT_NEIGHBORS
    from treesim.reconstruct.qsm import BRIDGE_NEIGHBORS

    assert KEPT_NEIGHBORS >= max(QSMParams().neighbors + 1, BRIDGE_NEIGHBORS)
    assert PrepareParams().normals_neighbors <= KEPT_NEIGHBORS


@pytest.mark.parametrize("kept_share", [0.9, 0.3])
def test_neighbours_of_the_kept_points_are_those_of_a_new_search(clumpy, kept_share, chunks):
    keep = np.random.default_rng(7).random(len(clumpy)) < kept_share
    tree = cKDTree(clumpy)
    nb, _ = nearest_neighbors(clumpy, 24, tree)
    got = _neighbours._neighbors_of_kept(clumpy, nb, keep, 24, tree)
    _, plain = cKDTree(clumpy[keep]).query(clumpy[keep], k=24)
    assert np.array_equal(got, plain)


def test_prepare_with_outliers_removed_keeps_a_plain_search_of_what_is_left(clumpy):
    rng = np.random.default_rng(5)
    p = np.concatenate([clumpy, rng.uniform(-2.0, 3.0, (40, 3))])
    prep = prepare(p, PrepareParams(voxel_size_m=None), normals=False)
    assert prep.steps[1]["removed"] > 0
    _, plain = cKDTree(prep.points).query(prep.points, k=24)
    assert np.array_equal(prep.neighbors, plain)
    assert prep.spacing_m == point_spacing(prep.points, distinct=False)


def test_prepare_with_the_ground_removed_keeps_a_plain_search_of_what_is_left(chunks):
    pts, _ = stem_on_ground()
    prep = prepare(pts, PrepareParams(voxel_size_m=None, remove_ground=True), normals=False)
    assert prep.steps[2]["removed"] > 10000
    _, plain = cKDTree(prep.points).query(prep.points, k=24)
    assert np.array_equal(prep.neighbors, plain)
    assert prep.spacing_m == point_spacing(prep.points, distinct=False)


@pytest.mark.parametrize("link_m", [0.01, 0.03])
def test_components_of_the_symmetric_graph_are_numbered_as_scipy_numbers_them(clumpy, link_m):
    nb, _ = nearest_neighbors(clumpy, 24)
    g = _knn_graph(clumpy, nb, 10, link_m)
    m, labels = _qsm._components(g)
    m_ref, labels_ref = connected_components(g, directed=False)
    assert m == m_ref > 1
    assert np.array_equal(labels, labels_ref)
