"""A station's per-triangle set-up, made faster with the same results (issue 25).

The scene's degenerate-triangle test, the caster's welding of equal coordinates and the
triangles around each vertex are computed another way; the oracles are the plain
formulas they replaced, written out here: ``np.linalg.norm`` of ``np.cross`` and of
the rolled edges, ``np.unique`` over the vertices' 24 bytes and a stable argsort of the
corners. Hash collisions are forced by replacing the hash.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from treesim.frame import LocalFrame
from treesim.geometry import triangles_around, vertex_triangles
from treesim.scene import MeshPart, Scene

caster_module = importlib.import_module("treesim.scan.caster")
scene_module = importlib.import_module("treesim.scene")


def _stable_incidence(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    flat = np.asarray(faces).ravel()
    ptr = np.zeros(n + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(np.bincount(flat, minlength=n))
    return ptr, np.argsort(flat, kind="stable") // 3


@pytest.mark.parametrize("n_faces", [0, 1, 2, 7, 1000, 30_000])
@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.uint32])
def test_vertex_triangles_is_the_stable_argsort(n_faces, dtype):
    rng = np.random.default_rng(n_faces)
    n_vertices = max(3, n_faces // 3)  # many triangles a vertex, repeats within one
    faces = rng.integers(0, n_vertices, size=(n_faces, 3)).astype(dtype)
    if n_faces:
        faces[0] = [1, 1, 1]  # one vertex three times in one triangle
    ptr, idx = vertex_triangles(faces, n_vertices + 5)  # unused vertices at the end
    ptr0, idx0 = _stable_incidence(faces, n_vertices + 5)
    assert ptr.dtype == ptr0.dtype and idx.dtype == idx0.dtype
    np.testing.assert_array_equal(ptr, ptr0)
    np.testing.assert_array_equal(idx, idx0)


def test_vertex_triangles_of_a_strided_view_in_chunks():
    rng = np.random.default_rng(1)
    faces = rng.integers(0, 50, size=(400, 6))[:, ::2]  # not contiguous
    ptr0, idx0 = _stable_incidence(np.ascontiguousarray(faces), 50)
    for chunk in (1 << 15, 7, 1):  # one chunk, several, a triangle at a time
        ptr, idx = vertex_triangles(faces, 50, chunk=chunk)
        np.testing.assert_array_equal(ptr, ptr0)
        np.testing.assert_array_equal(idx, idx0)


def _unique_weld(v: np.ndarray) -> np.ndarray:
    key = np.ascontiguousarray(v + 0.0)
    _, weld = np.unique(key.view(np.dtype((np.void, 24))).ravel(), return_inverse=True)
    return weld.reshape(-1)


def _mesh(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """An indexed mesh: distinct positions on a half-metre grid (zeros among their
    coordinates), triangles of three of them with an area."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(*[np.arange(-2, 3) * 0.5] * 3, indexing="ij"), -1)
    pos = rng.permutation(grid.reshape(-1, 3))[:40]
    faces = rng.integers(0, 40, size=(900, 3))
    a, b, c = (pos[faces[:, k]] for k in range(3))
    return pos, faces[np.abs(np.cross(b - a, c - a)).sum(axis=1) > 0]


def _soup(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh as a triangle soup: each triangle its own three vertices (many equal),
    a zero coordinate -0.0 in some of them, and unused vertices equal to used ones."""
    rng = np.random.default_rng(seed)
    pos, faces = _mesh(seed)
    v = np.concatenate([pos[faces.ravel()], pos[:7]])
    flip = (v == 0) & (rng.random(v.shape) < 0.5)
    v[flip] = -0.0
    assert flip.any()
    return v, np.arange(3 * len(faces)).reshape(-1, 3)


def _same_labelling(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether labels ``a`` and ``b`` group the rows alike (a one-to-one relabelling)."""
    pairs = np.unique(np.stack([a, b], axis=1), axis=0)
    return len(pairs) == len(np.unique(a)) == len(np.unique(b))


def _hash_zero(words: np.ndarray) -> np.ndarray:
    return np.zeros(len(words), dtype=np.uint64)


def _hash_x(words: np.ndarray) -> np.ndarray:
    return words[:, 0].copy()


@pytest.mark.parametrize("row_hash", [None, _hash_zero, _hash_x])
@pytest.mark.parametrize("seed", [0, 1])
def test_the_weld_groups_equal_coordinates_as_np_unique(monkeypatch, row_hash, seed):
    if row_hash is not None:  # every row, or those with equal x, collide
        monkeypatch.setattr(caster_module, "_row_hash", row_hash)
    v, _ = _soup(seed)
    oracle = _unique_weld(v)
    weld, n = caster_module._weld(v, np.zeros(3))
    assert weld is not None and n == oracle.max() + 1
    assert weld.min() == 0 and weld.max() == n - 1
    assert _same_labelling(weld, oracle)
    # -0.0 and 0.0 are one vertex: their bytes alone would tell more vertices apart
    raw = np.unique(v.view(np.dtype((np.void, 24))).ravel())
    assert len(raw) > n


def test_distinct_coordinates_weld_to_themselves(monkeypatch):
    rng = np.random.default_rng(2)
    v = rng.normal(size=(5000, 3))
    assert caster_module._weld(v, np.zeros(3)) == (None, 5000)
    # a collision among distinct rows: the labels still tell every row apart
    monkeypatch.setattr(caster_module, "_row_hash", _hash_zero)
    weld, n = caster_module._weld(v, np.zeros(3))
    assert n == 5000 and _same_labelling(weld, np.arange(5000))


def _fans_oracle(v: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    weld = _unique_weld(v)
    corners = weld[faces]
    ptr, inc = _stable_incidence(corners, int(weld.max()) + 1)
    return triangles_around(ptr, inc, corners.ravel())


@pytest.mark.parametrize("row_hash", [None, _hash_zero, _hash_x])
@pytest.mark.parametrize("soup", [True, False])
@pytest.mark.parametrize("shift", [False, True])
def test_the_casters_fans_are_the_unique_welds(monkeypatch, row_hash, soup, shift):
    """What the caster's float64 re-test reads: the triangles around each corner of
    each triangle, in order, the same as through np.unique's weld (-0.0 reaches the
    caster's local vertices unshifted)."""
    if row_hash is not None:
        monkeypatch.setattr(caster_module, "_row_hash", row_hash)
    v, faces = _soup(3) if soup else _mesh(3)
    origin = np.array([1e5, -2e5, 0.0]) if shift else np.zeros(3)
    scene = Scene([MeshPart(vertices=v + origin if shift else v, faces=faces, label="wood")])
    assert scene.dropped_degenerate == 0
    if soup and not shift:
        assert (np.signbit(caster_v := scene.vertices - origin) & (caster_v == 0)).any()
    caster = caster_module.Caster(scene, LocalFrame(origin=tuple(origin)), nthreads=1)
    corners, ptr, inc = caster._fans()
    assert corners.dtype == np.int32 and inc.dtype == np.int32
    owner, cand = triangles_around(ptr, inc, corners.ravel())
    owner0, cand0 = _fans_oracle(caster.v, scene.faces)
    np.testing.assert_array_equal(owner, owner0)
    np.testing.assert_array_equal(cand, cand0)
    # the corners of a slice are the indexed rows, moved into the local frame
    f = scene.faces[5:40]
    for got, k in zip(caster.corners(slice(5, 40)), range(3), strict=True):
        np.testing.assert_array_equal(got, scene.vertices[f[:, k]] - caster._origin)


def _non_degenerate_oracle(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    tri = v[f]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    return area2 > 1e-12 * np.maximum(edge, 1e-300) ** 2


@pytest.mark.parametrize("scale", [1e-150, 1e-3, 1.0, 1e5, 1e150])
def test_non_degenerate_is_the_norm_of_the_cross_product(monkeypatch, scale):
    monkeypatch.setattr(scene_module, "_CHECK_CHUNK", 97)  # several chunks, a short last
    rng = np.random.default_rng(int(np.log10(scale)) + 200)
    v = rng.normal(size=(3000, 3)) * scale + rng.normal(size=3) * 100 * scale
    f = rng.integers(0, 3000, size=(5000, 3))
    f[:100, 2] = f[:100, 1]  # a repeated corner
    # slivers: the third corner on (or within rounding of) the line of the first two
    t = rng.uniform(-1, 2, size=(400, 1))
    w = v[f[100:500, 0]] + t * (v[f[100:500, 1]] - v[f[100:500, 0]])
    w[::2] += rng.normal(size=(200, 3)) * scale * 10.0 ** rng.uniform(-13, -3, size=(200, 1))
    v = np.concatenate([v, w])
    f[100:500, 2] = 3000 + np.arange(400)
    with np.errstate(over="ignore"):  # 1e150: squares overflow (in both)
        keep = scene_module._non_degenerate(v, f)
        oracle = _non_degenerate_oracle(v, f)
    np.testing.assert_array_equal(keep, oracle)
    assert not keep[:100].any()
    if 1e-3 <= scale <= 1e5:  # (beyond, the squares underflow or overflow: all dropped)
        assert keep[500:].mean() > 0.99 and 0 < keep[100:500].sum() < 400


def test_non_degenerate_decides_as_the_oracle_at_its_threshold():
    """Triangles (0, d, h u) whose h the oracle bisects to its threshold (1e-12 of the
    longest edge squared) to the last bit: each pair, one side kept, the other dropped,
    tells apart figures rounded differently (summing the cross product's squares in
    another order flips about 5 % of them)."""
    rng = np.random.default_rng(7)
    n = 2000
    d, u = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))

    def triangles(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = np.concatenate([np.zeros((n, 3)), d, h[:, None] * u])
        return v, np.arange(3 * n).reshape(3, n).T

    lo, hi = np.zeros(n), np.full(n, 1e-9)
    for _ in range(80):
        mid = (lo + hi) / 2
        kept = _non_degenerate_oracle(*triangles(mid))
        lo, hi = np.where(kept, lo, mid), np.where(kept, mid, hi)
    for h, oracle in ((lo, False), (hi, True)):
        assert (_non_degenerate_oracle(*triangles(h)) == oracle).all()
        np.testing.assert_array_equal(scene_module._non_degenerate(*triangles(h)), oracle)
