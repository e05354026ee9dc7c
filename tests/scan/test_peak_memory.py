"""What a station holds at its peaks, lowered with the same results (issue 25).

While Open3D builds its BVH the scene's arrays live in a temporary file
(:meth:`Scene.spilled`): they come back the same bits, the file goes (also on an
exception), and neither the scene nor the caster holds the arrays themselves meanwhile.
The caster's edge fans are built a chunk at a time
(:func:`treesim.geometry.vertex_triangles`' ``chunk``, the caster's :func:`_weld`): the
oracles are a stable argsort of the corners and ``np.unique`` of the vertices' bytes.
"""

from __future__ import annotations

import gc
import importlib
import os
import tempfile
import weakref

import numpy as np
import pytest

from treesim.frame import LocalFrame
from treesim.geometry import vertex_triangles
from treesim.scene import MeshPart, Scene

caster_module = importlib.import_module("treesim.scan.caster")


def _grid_mesh(n: int, seed: int, z0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A bumpy n x n height field over [0, 10]^2: its vertices and triangles."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 10, n), np.linspace(0, 10, n))
    v = np.stack([x.ravel(), y.ravel(), z0 + 0.3 * rng.normal(size=n * n)], axis=1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _scene(soup: bool = False, tree_ids: bool = True) -> Scene:
    """Two labelled sheets, one above the other; ``soup``: the upper one as a triangle
    soup (every triangle its own corners: equal coordinates the caster welds)."""
    v1, f1 = _grid_mesh(40, 1)
    v2, f2 = _grid_mesh(30, 2, z0=5.0)
    if soup:
        v2, f2 = v2[f2].reshape(-1, 3), np.arange(3 * len(f2)).reshape(-1, 3)
    parts = [
        MeshPart(v1, f1, "ground", name="ground"),
        MeshPart(v2, f2, "leaf", name="crown", tree_id=7 if tree_ids else 0),
    ]
    return Scene(parts)


def _arrays(scene: Scene) -> dict:
    return {k: getattr(scene, k) for k in Scene.SPILLED}


def _assert_same_bits(got: dict, want: dict) -> None:
    assert got.keys() == want.keys()
    for k, a in want.items():
        if a is None:
            assert got[k] is None, k
            continue
        b = got[k]
        assert type(b) is np.ndarray and b.flags.writeable, k
        assert b.dtype == a.dtype and b.shape == a.shape, k
        assert b.tobytes() == a.tobytes(), k


@pytest.mark.parametrize("tree_ids", [True, False])
def test_a_spilled_scene_reads_back_the_same_bits_and_the_file_goes(tmp_path, tree_ids):
    scene = _scene(tree_ids=tree_ids)
    scene.vertices[0, 2] = -0.0  # the sign of a zero comes back too
    want = {k: None if a is None else a.copy() for k, a in _arrays(scene).items()}
    assert (want["face_tree"] is None) == (not tree_ids)
    with scene.spilled(str(tmp_path)):
        inside = _arrays(scene)
        folder = os.listdir(tmp_path)
        assert len(folder) == 1  # one folder of .npy files while spilled
        for k, a in inside.items():
            assert (a is None) == (want[k] is None)
            if a is not None:
                assert isinstance(a, np.memmap) and not a.flags.writeable
                assert a.tobytes() == want[k].tobytes()  # readable meanwhile
        assert scene.used_vertices.shape == (scene._used.sum(), 3)
    _assert_same_bits(_arrays(scene), want)
    assert os.listdir(tmp_path) == []
    assert np.signbit(scene.vertices[0, 2])


def test_an_exception_inside_reads_back_too_and_the_file_goes(tmp_path):
    scene = _scene()
    want = {k: a.copy() for k, a in _arrays(scene).items()}
    with pytest.raises(KeyError, match="inside"), scene.spilled(str(tmp_path)):
        assert isinstance(scene.faces, np.memmap)
        raise KeyError("inside")
    _assert_same_bits(_arrays(scene), want)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("fail_at", [0, 2])
def test_no_room_for_the_files_keeps_the_arrays_in_memory(monkeypatch, tmp_path, fail_at):
    scene = _scene()
    want = {k: a.copy() for k, a in _arrays(scene).items()}
    save, calls = np.save, []

    def full_disk(path, a, **kw):
        calls.append(path)
        if len(calls) > fail_at:
            raise OSError(28, "No space left on device")
        save(path, a, **kw)

    monkeypatch.setattr(np, "save", full_disk)
    with scene.spilled(str(tmp_path)):
        _assert_same_bits(_arrays(scene), want)  # in memory meanwhile
    _assert_same_bits(_arrays(scene), want)
    assert len(calls) == fail_at + 1 and os.listdir(tmp_path) == []


def test_spilling_lets_go_of_the_arrays(tmp_path):
    """Meanwhile nothing of the scene keeps its arrays alive: no second copy in memory."""
    scene = _scene()
    refs = [weakref.ref(a) for a in _arrays(scene).values()]
    with scene.spilled(str(tmp_path)):
        gc.collect()
        assert [r() for r in refs] == [None] * len(refs)
    assert scene.array_bytes == sum(a.nbytes for a in _arrays(scene).values())


def _cast_all(caster, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays from ``o`` over a grid of directions: (t, primitive)."""
    el, az = np.meshgrid(np.radians(np.linspace(-80, 10, 120)), np.radians(np.arange(0, 360, 2)))
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    return caster.cast(o, d)


@pytest.mark.parametrize("soup", [False, True])
@pytest.mark.parametrize("keep", [False, True])
def test_a_caster_that_spills_casts_the_same(monkeypatch, tmp_path, soup, keep):
    """A caster built with its scene spilled (every scene here, SPILL_BYTES 0) casts the
    same hits as one built without, holds the arrays read back, leaves no file, and
    during Open3D's build neither it nor the scene held the arrays themselves."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    frame = LocalFrame(origin=(5.0, 5.0, 2.0))
    scene = _scene(soup=soup)
    mask = None
    if keep:
        mask = np.ones(scene.n_triangles, dtype=bool)
        mask[::7] = False
    o = np.array([0.3, -0.2, 0.1])
    monkeypatch.setattr(caster_module, "SPILL_BYTES", 1 << 62)
    want = _cast_all(caster_module.Caster(scene, frame, 1, mask), o)
    assert os.listdir(tmp_path) == []

    refs = [weakref.ref(a) for a in _arrays(scene).values()]
    seen = []
    cast = caster_module.Caster.cast

    def spying_cast(self, *args):
        if not seen:  # the first cast builds the BVH
            gc.collect()
            seen.append(([r() for r in refs], isinstance(scene.vertices, np.memmap)))
            seen.append(len(os.listdir(tmp_path)))
        return cast(self, *args)

    monkeypatch.setattr(caster_module.Caster, "cast", spying_cast)
    monkeypatch.setattr(caster_module, "SPILL_BYTES", 0)
    caster = caster_module.Caster(scene, frame, 1, mask)
    assert seen[0] == ([None] * len(refs), True) and seen[1] == 1
    assert os.listdir(tmp_path) == []
    assert type(caster._sv) is np.ndarray and type(scene.faces) is np.ndarray
    assert caster.spill_s >= 0.0 and caster.build_s >= 0.0
    got = _cast_all(caster, o)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert np.isfinite(got[0]).sum() > 1000


@pytest.mark.parametrize("chunk", [1, 2, 7, 1 << 15])
@pytest.mark.parametrize("n_faces, n_vertices", [(0, 3), (1, 3), (50, 10), (3000, 900)])
@pytest.mark.parametrize("subset", [False, True])
def test_the_fans_incidence_in_chunks_is_vertex_triangles(chunk, n_faces, n_vertices, subset):
    rng = np.random.default_rng(n_faces + chunk)
    faces = rng.integers(0, n_vertices, size=(n_faces, 3)).astype(np.int32)
    # the oracle: a stable argsort of the corners (two unused vertices at the end)
    ptr0 = np.zeros(n_vertices + 3, dtype=np.int64)
    ptr0[1:] = np.cumsum(np.bincount(faces.ravel(), minlength=n_vertices + 2))
    idx0 = np.argsort(faces.ravel(), kind="stable") // 3
    rows = faces
    if subset:  # the faces as a caster's loaded rows of a larger scene's
        big = np.concatenate([faces[::-1], faces]) if n_faces else faces
        rows = caster_module._Subset(big, np.arange(n_faces, 2 * n_faces, dtype=np.int32))
    for index in (np.int32, np.int64):
        ptr, idx = vertex_triangles(rows, n_vertices + 2, index, chunk=chunk)
        assert ptr.dtype == np.int64 and idx.dtype == index
        np.testing.assert_array_equal(ptr, ptr0)
        np.testing.assert_array_equal(idx, idx0)


@pytest.mark.parametrize("chunk", [1, 3, 1 << 15])
@pytest.mark.parametrize("case", ["distinct", "equal", "signed-zero", "empty", "one"])
def test_the_chunked_weld_is_the_weld(monkeypatch, chunk, case):
    monkeypatch.setattr(caster_module, "FAN_CHUNK", chunk)
    rng = np.random.default_rng(5)
    origin = np.array([1.5, -2.0, 3.0])
    local = {
        "distinct": rng.normal(size=(500, 3)) * 1e3,
        "equal": np.round(rng.normal(size=(500, 3)), 1)[rng.integers(0, 500, 800)],
        "signed-zero": np.vstack([np.zeros((2, 3)), -np.zeros((1, 3)), rng.normal(size=(4, 3))]),
        "empty": np.zeros((0, 3)),
        "one": rng.normal(size=(1, 3)),
    }[case]
    sv = local + origin
    weld0, n0 = _unique_weld(sv - origin)
    weld, n = caster_module._weld(sv, origin)
    assert n == n0
    assert (weld is None) == (weld0 is None) == (case in ("distinct", "empty", "one"))
    if weld is not None:  # the same vertices together (labels may be numbered otherwise)
        assert len(set(zip(weld.tolist(), weld0.tolist(), strict=True))) == n


def _unique_weld(local: np.ndarray) -> tuple[np.ndarray | None, int]:
    """np.unique's labels of the rows' bytes (-0.0 made 0.0), None where every row
    differs, and their number."""
    if not len(local):
        return None, 0
    key = np.ascontiguousarray(local + 0.0).view(np.dtype((np.void, 24))).ravel()
    _, inv = np.unique(key, return_inverse=True)
    inv = inv.reshape(-1)
    n = int(inv.max()) + 1
    return (None if n == len(local) else inv), n
