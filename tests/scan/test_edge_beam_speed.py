"""The edge beam model's faster helpers against the formulas they replaced.

Oracle: the helpers as they stood before (``old_edge_lines``, ``old_walk``,
``old_quad_ranges`` below, copied from ``treesim.scan.beam`` at commit dc78f01): the
new ones (compiled loops: :mod:`treesim.scan._edge_jit`) must walk the same triangles
and find the same silhouette edges, with the same numbers to 1e-12 (signs and cross
products to the bit), and the edge scan the same cloud whichever way it finds a pulse's
neighbours.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.scan.test_beam_footprint import SPEC, edge_scene
from treesim.params import ScannerSpec
from treesim.scan import Station, beam, scan
from treesim.scan.beam import (
    _edge_lines,
    _surface_range,
    _walk,
    beam_basis,
    edge_neighbours,
    subray_pattern,
)
from treesim.scan.occupancy import seen_sides

# --------------------------------------------------------------------------------------
# the old formulas (commit dc78f01), the oracle
# --------------------------------------------------------------------------------------


def old_edge_lines(
    v: np.ndarray, faces: np.ndarray, o: np.ndarray, th: float, frame: tuple, tri: np.ndarray
) -> dict[str, np.ndarray]:
    """Each edge j of triangles ``tri`` seen along pulses ``frame = (d, e1, e2)`` as a
    line ``nu·x + nv·y + c = 0`` on the footprint's plane (unit radius: tangents over
    ``th``), oriented so that the triangle is on its ``>= 0`` side; ``dist``: the
    distance from the axis to the edge's segment (the line's where a corner is behind
    the station); ``m``: the normal of the plane through the station and the edge,
    ``sg`` its sign towards the triangle. Arrays (n, 3) ((n, 3, 3) for ``m``)."""
    d, e1, e2 = frame
    a = v[faces[tri]] - o
    ad = np.einsum("mkj,mj->mk", a, d)
    front = ad > 1e-12 * np.linalg.norm(a, axis=2)
    safe = np.where(front, ad, 1.0)
    pu = np.einsum("mkj,mj->mk", a, e1) / safe / th
    pv = np.einsum("mkj,mj->mk", a, e2) / safe / th
    out = {k: np.empty(ad.shape) for k in ("nu", "nv", "c", "dist", "sg")}
    out["m"] = np.empty(a.shape)
    for j in range(3):
        j1, j2 = (j + 1) % 3, (j + 2) % 3
        m = np.cross(a[:, j], a[:, j1])
        sg = np.sign(np.einsum("ij,ij->i", m, a[:, j2]))
        la = np.einsum("ij,ij->i", m, e1) * th
        lb = np.einsum("ij,ij->i", m, e2) * th
        ln = np.maximum(np.hypot(la, lb), 1e-300)
        c = sg * np.einsum("ij,ij->i", m, d) / ln
        du, dv = pu[:, j1] - pu[:, j], pv[:, j1] - pv[:, j]
        t = np.clip(-(pu[:, j] * du + pv[:, j] * dv) / np.maximum(du * du + dv * dv, 1e-300), 0, 1)
        seg = np.hypot(pu[:, j] + t * du, pv[:, j] + t * dv)
        both = front[:, j] & front[:, j1]
        out["nu"][:, j], out["nv"][:, j], out["c"][:, j] = sg * la / ln, sg * lb / ln, c
        out["dist"][:, j] = np.where(both, seg, np.abs(c))
        out["sg"][:, j], out["m"][:, j] = sg, m
    return out


def old_walk(
    geo: tuple[np.ndarray, np.ndarray, np.ndarray],
    o: np.ndarray,
    th: float,
    frame: tuple,
    start: np.ndarray,
    quad: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The silhouette edges inside each pulse's footprint, found by walking the mesh
    from the triangle ``start`` (one per pulse, inside its footprint) across every edge
    the footprint meets, as long as the surface goes on (the triangle across the edge
    lies beyond it as seen from the station). An edge with no triangle across it, or
    whose neighbour folds back behind it, is a silhouette edge. ``geo``: vertices,
    faces, :func:`edge_neighbours`. Returns the silhouette lines (``pulse``, ``nu``,
    ``nv``, ``c`` as :func:`_edge_lines`, the surface on the ``>= 0`` side) and which
    pulses the walk did not finish within :data:`beam.EDGE_WALK_STEPS` rings. With ``quad``
    (points (k, 2) on the unit footprint, their weights (k,)), ``lines["range"]``
    holds per pulse the weighted mean range of the points on the walked surface (nan
    where none is), the surface's range over its footprint."""
    v, faces, nbr = geo
    n_t = len(faces)
    it_p = np.arange(len(start), dtype=np.int64)
    it_t = np.asarray(start, dtype=np.int64)
    it_e = np.full(len(start), -1, dtype=np.int64)
    seen = np.sort(it_p * n_t + it_t)
    lines: dict[str, list[np.ndarray]] = {k: [] for k in ("pulse", "nu", "nv", "c", "tri")}
    unresolved = np.zeros(len(start), dtype=bool)
    q_r = None if quad is None else np.full((len(start), len(quad[1])), np.inf)
    for step in range(beam.EDGE_WALK_STEPS + 1):
        if not len(it_p):
            break
        if step == beam.EDGE_WALK_STEPS:
            unresolved[it_p] = True
            break
        g = old_edge_lines(v, faces, o, th, tuple(x[it_p] for x in frame), it_t)
        if q_r is not None:
            old_quad_ranges(
                q_r, g, quad[0], (v, faces, o, th), tuple(x[it_p] for x in frame), it_p, it_t
            )
        reach = (g["dist"] < 1.0) & (np.arange(3)[None, :] != it_e[:, None])
        ii, jj = np.nonzero(reach)
        tri = it_t[ii]
        nb = nbr[tri, jj]
        ia, ib = faces[tri, jj], faces[tri, (jj + 1) % 3]
        nf = faces[np.maximum(nb, 0)]
        opp = nf.sum(axis=1) - ia - ib
        side = np.sign(np.einsum("ij,ij->i", g["m"][ii, jj], v[opp] - o))
        cont = (nb >= 0) & (side == -g["sg"][ii, jj])
        sil = ~cont
        for k in ("nu", "nv", "c"):
            lines[k].append(g[k][ii[sil], jj[sil]])
        lines["pulse"].append(it_p[ii[sil]])
        lines["tri"].append(tri[sil])
        # the walk goes on into the triangles across, each once per pulse
        np_, nt = it_p[ii[cont]], nb[cont]
        key = np_ * n_t + nt
        order = np.argsort(key, kind="stable")
        ks = key[order]
        once = np.ones(len(ks), dtype=bool)
        once[1:] = ks[1:] != ks[:-1]
        pos = np.minimum(np.searchsorted(seen, ks), max(len(seen) - 1, 0))
        fresh = once & ~((seen[pos] == ks) if len(seen) else np.zeros(len(ks), bool))
        first = order[fresh]
        seen = np.sort(np.concatenate([seen, ks[fresh]]))
        k_opp = np.argmax(nf[cont][first] == opp[cont][first][:, None], axis=1)
        it_p, it_t, it_e = np_[first], nt[first], (k_opp + 1) % 3
    out = {k: np.concatenate(x) if x else np.empty(0) for k, x in lines.items()}
    out["pulse"] = out["pulse"].astype(np.int64)
    out["tri"] = out["tri"].astype(np.int64)
    if q_r is not None:
        on = np.isfinite(q_r)
        wq = np.where(on, quad[1][None, :], 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out["range"] = (np.where(on, q_r, 0.0) * wq).sum(axis=1) / wq.sum(axis=1)
    return out, unresolved


def old_quad_ranges(q_r, g, pts, geo, frame, it_p, it_t) -> None:
    """Ranges (into ``q_r``, nearest kept) of the footprint points ``pts`` that fall
    inside the walked triangles ``it_t`` (edge lines ``g``) of pulses ``it_p``."""
    v, faces, o, th = geo
    x, y = pts[:, 0][None, None, :], pts[:, 1][None, None, :]
    val = g["nu"][:, :, None] * x + g["nv"][:, :, None] * y + g["c"][:, :, None]
    ii, kk = np.nonzero((val >= -1e-9).all(axis=1))
    if not len(ii):
        return
    d, e1, e2 = (a[ii] for a in frame)
    w = d + th * (pts[kk, :1] * e1 + pts[kk, 1:2] * e2)
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    tri = faces[it_t[ii]]
    p0 = v[tri[:, 0]]
    n = np.cross(v[tri[:, 1]] - p0, v[tri[:, 2]] - p0)
    r = np.einsum("ij,ij->i", p0 - o, n) / np.einsum("ij,ij->i", n, w)
    np.minimum.at(q_r, (it_p[ii], kk), np.where(r > 0, r, np.inf))


# --------------------------------------------------------------------------------------
# the new helpers, bit for bit
# --------------------------------------------------------------------------------------

#: beam half-angle tangents: the benchmarks' 0.3 mrad beam, and a beam ten times wider
#: (footprints over many triangles: long walks, some left unfinished)
THS = (np.tan(0.15e-3), np.tan(1.5e-3))


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """The same dtype, shape and bytes (-0.0 is not 0.0; NaN is NaN)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def close(a: np.ndarray, b: np.ndarray) -> bool:
    """The same dtype, shape, NaNs and infinities, and values within 1e-12 (relative, or
    absolute below 1): a compiled loop sums in its own order and takes a square root
    where numpy's ``hypot`` scaled first, a few units in the last place apart."""
    a, b = np.asarray(a), np.asarray(b)
    return (
        a.dtype == b.dtype
        and a.shape == b.shape
        and bool(np.allclose(a, b, rtol=1e-12, atol=1e-12, equal_nan=True))
    )


@pytest.fixture(scope="module")
def mesh():
    """(vertices, faces, edge neighbours, station) of the beam agreement tests' coffee
    tree (12 facets, 10 m away)."""
    from tests.scan.beam_agreement import coffee_window

    scene, st, _ = coffee_window()
    faces = np.asarray(scene.faces, dtype=np.int64)
    return scene.vertices, faces, edge_neighbours(faces), np.asarray(st.position_m, float)


def aim(mesh, n: int = 500, seed: int = 3) -> tuple[tuple, np.ndarray]:
    """Pulses (frames) aimed at random points of random triangles, most triangles
    twice (two pulses on one triangle), and those triangles."""
    v, faces, _, o = mesh
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(faces), n, replace=False)
    tri = np.concatenate([tri, tri[: 2 * n // 3]])
    b = rng.dirichlet(np.ones(3), len(tri))
    d = np.einsum("mk,mkj->mj", b, v[faces[tri]]) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (d, *beam_basis(d)), tri


@pytest.mark.parametrize("th", THS)
def test_edge_lines_match_the_old_formula(mesh, th):
    v, faces, _, o = mesh
    frame, tri = aim(mesh)
    old = old_edge_lines(v, faces, o, th, frame, tri)
    assert (old["dist"] < 1.0).any() and (old["dist"] >= 1.0).any()
    new = _edge_lines(v, faces, o, th, frame, tri)
    for k in ("nu", "nv", "c", "dist"):
        assert close(new[k], old[k]), k
    for k in ("sg", "m"):  # products and signs alone: the same bits
        assert same(new[k], old[k]), k


@pytest.mark.parametrize("th", THS)
def test_the_walk_and_its_surface_range_match_the_old_formula(mesh, th):
    v, faces, nbr, o = mesh
    frame, tri = aim(mesh)
    quad = subray_pattern(beam.EDGE_RANGE_POINTS, 2.0e3)
    old, old_unres = old_walk((v, faces, nbr), o, th, frame, tri, quad)
    assert len(old["pulse"]) > 100 and np.isfinite(old["range"]).mean() > 0.5
    if th > 1e-3:
        assert old_unres.any()
    every = np.arange(len(tri))
    lines, unres, trail = _walk((v, faces, nbr), o, th, frame, tri)
    assert same(unres, old_unres)
    # each pulse's silhouette lines, in the same order
    a, b = np.argsort(lines["pulse"], kind="stable"), np.argsort(old["pulse"], kind="stable")
    for k in ("pulse", "tri"):
        assert same(lines[k][a], old[k][b]), k
    for k in ("nu", "nv", "c"):
        assert close(lines[k][a], old[k][b]), k
    geo = (v, faces, o)
    assert close(_surface_range(geo, frame, th, trail, every, quad), old["range"])
    some = every[1::3]
    assert close(_surface_range(geo, frame, th, trail, some, quad), old["range"][some])


def old_stray_samples(u: np.ndarray, spec, reach: float) -> dict[str, np.ndarray]:
    """The thin-geometry boxes' samples as numpy worked them out (commit 43bc528), from
    the triangles' corner directions ``u`` (n, 3, 3)."""
    ua, ub, length, width = seen_sides(u)
    vres = math.radians(spec.vertical_resolution_deg)
    hres = math.radians(spec.horizontal_resolution_deg)
    n_s = np.ceil(1.2 * length / min(vres, hres)).astype(np.int64) + 1
    k = np.repeat(np.arange(len(u)), n_s)
    f = (np.arange(int(n_s.sum())) - np.repeat(np.cumsum(n_s) - n_s, n_s)) / np.maximum(
        n_s[k] - 1, 1
    )
    d = (1.0 - f)[:, None] * ua[k] + f[:, None] * ub[k]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    el = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
    radius = reach + 1.01 * width[k] + 0.6 * length[k] / np.maximum(n_s[k] - 1, 1)
    cos_el = np.cos(np.minimum(np.abs(el) + radius, math.pi / 2))
    line = (el - math.radians(spec.vertical_fov_deg[0])) / vres
    az = np.arctan2(d[:, 1], d[:, 0]) - math.radians(spec.horizontal_fov_deg[0])
    col = (az % (2 * math.pi)) / hres
    rc = radius / (hres * cos_el)
    return {
        "l_lo": np.ceil(line - radius / vres).astype(np.int64),
        "l_hi": np.floor(line + radius / vres).astype(np.int64),
        "c_lo": np.ceil(col - rc).astype(np.int64),
        "c_hi": np.floor(col + rc).astype(np.int64),
        "tri": k,
        "line": line,
        "col": col,
        "rl": radius / vres,
        "rc": rc,
        "cos_el": cos_el,
    }


def test_the_compiled_thin_geometry_boxes_match_the_old_formula():
    # twig-like triangles all round the station (long and narrow, some crossing the
    # azimuth's wrap behind it), at 0.02 degrees: the same samples, boxes and reaches
    rng = np.random.default_rng(11)
    n = 3000
    c = rng.normal(size=(n, 3)) * [6.0, 6.0, 3.0]
    c[::17, 1] = rng.normal(size=len(c[::17])) * 1e-3  # near azimuth 0 / 180
    c[::17, 0] = -np.abs(c[::17, 0])
    along = rng.normal(size=(n, 3))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    tri = np.stack([c, c + 0.2 * along, c + 0.003 * rng.normal(size=(n, 3))], axis=1)
    spec = ScannerSpec(horizontal_resolution_deg=0.02, vertical_resolution_deg=0.02)
    reach = 2e-4
    old = old_stray_samples(tri / np.linalg.norm(tri, axis=2, keepdims=True), spec, reach)
    assert (old["cos_el"] >= 1e-3).all() and len(old["tri"]) > 10 * n
    new = beam._stray_samples(tri, spec, reach)
    for k in ("l_lo", "l_hi", "c_lo", "c_hi", "tri"):
        assert same(new[k], old[k]), k
    for k in ("line", "col", "rl", "rc"):
        assert close(new[k], old[k]), k
    # a triangle near the zenith: a box would reach the pole, and there are none
    up = np.array([[[0.0, 1e-4, 10.0], [1e-4, 0.0, 10.0], [0.0, 0.0, 10.0]]])
    assert all(len(x) == 0 for x in beam._stray_samples(up, spec, reach).values())


def test_the_compiled_frames_are_beam_basis_to_the_bit():
    # the edge model's pulse frames (compiled) against the numpy basis the other beams
    # use: directions all round, some near vertical (the other "up"), some exactly in a
    # coordinate plane (signed zeros)
    rng = np.random.default_rng(5)
    d = rng.normal(size=(20000, 3))
    d[::7, 2] *= 300.0
    d[::11, 1] = 0.0
    d[::13, :2] = 0.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert (np.abs(d[:, 2]) >= 0.99).sum() > 1000
    for got, want in zip(beam._jit().basis(d), beam_basis(d), strict=True):
        assert same(got, want)


def test_a_miss_lists_the_triangles_its_neighbours_hit_nearest_ring_first():
    # a 9 x 7 grid, one block (every pulse core), k = 2 steps: per miss, the distinct
    # triangles of its neighbours' hits, those of the nearer ring first, at most BESIDE
    from treesim.scan import _edge_jit as J

    rng = np.random.default_rng(5)
    n_az, n_lines, k = 9, 7, 2
    cols, lines = (a.ravel() for a in np.meshgrid(np.arange(n_az), np.arange(n_lines)))
    n = len(cols)
    t = np.where(rng.random(n) < 0.5, 5.0 + rng.random(n), np.inf)
    prim = np.where(np.isfinite(t), rng.integers(0, 30, n), -1)
    table = np.full((n_az, n_lines), -1, dtype=np.int32)
    table[cols, lines] = np.arange(n)
    none = np.empty(0, np.int64)
    lookup = (table, np.arange(n_az), 0, none, none)
    hits = np.flatnonzero(np.isfinite(t))
    at = np.full(n, -1, dtype=np.int64)
    at[hits] = np.arange(len(hits))
    faces = np.zeros((30, 3), dtype=np.int64)
    planes = (np.zeros((1, 3)), faces, np.tile([1.0, 0.0, 0.0], (30, 1)), prim)
    near, _, _, _, tri = J.neighbours(
        lines,
        cols,
        n,
        t,
        (np.zeros((len(hits), 3)), at, prim),
        planes,
        np.zeros(3),
        (n_az, n_lines, False),
        lookup,
        k,
        1e-3,
    )
    # a row of triangles for each miss with a neighbour's hit, in order
    assert tri.shape == (int(near.sum()), J.BESIDE)
    row = dict(zip(np.flatnonzero(near).tolist(), tri, strict=True))
    for i in np.flatnonzero(~np.isfinite(t)):
        ring = {}
        for q in range(n):
            r = max(abs(int(cols[q] - cols[i])), abs(int(lines[q] - lines[i])))
            if 0 < r <= k and np.isfinite(t[q]):
                ring[prim[q]] = min(ring.get(prim[q], k + 1), r)
        assert near[i] == bool(ring)
        if not ring:
            continue
        got = [x for x in row[i] if x >= 0]
        assert len(got) == len(set(got)) == min(len(ring), J.BESIDE)
        assert set(got) <= set(ring) and [ring[x] for x in got] == sorted(ring[x] for x in got)
        # a triangle left out (more than BESIDE) lies no nearer than every one listed
        assert all(ring[x] >= max(ring[y] for y in got) for x in set(ring) - set(got))
    assert not near[np.isfinite(t)].any()
    assert max(len(x[x >= 0]) for x in tri) == J.BESIDE  # some misses had more


def test_the_edge_scan_is_the_same_whichever_way_it_finds_neighbours(monkeypatch):
    spec = SPEC.with_(beam_sampling="edge", vertical_fov_deg=(-0.06, 0.06))
    st = [Station(position_m=(0.0, 0.0, 0.0))]
    table = scan(edge_scene(True), st, spec).cloud
    monkeypatch.setattr(beam, "_DENSE_NEIGHBOUR_CELLS", 0)  # search the sorted keys
    search = scan(edge_scene(True), st, spec).cloud
    assert len(table) > 20 and (table.fields["number_of_returns"] == 2).any()
    assert same(table.points, search.points)
    for k, val in table.fields.items():
        assert same(val, search.fields[k]), k


def test_the_warm_up_compiles_every_kernel():
    # a fresh interpreter (no kernel called yet): after warm_edge_model() every compiled
    # kernel the edge model calls has a compiled (or cached) signature, so that the docker
    # image and scripts/setup.sh, which call it, leave no compilation to a user's scan
    import json
    import subprocess
    import sys

    code = (
        "import json; from treesim.scan import _edge_jit as J; "
        "from treesim.scan.warmup import warm_edge_model; warm_edge_model(); "
        "print(json.dumps({k: len(getattr(J, k).signatures) for k in J.__all__}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    signatures = json.loads(out.stdout.strip().splitlines()[-1])
    assert set(signatures) == {"approach", "basis", "box_pulses", "edge_lines", "neighbours"} | {
        "overlaps",
        "stray_samples",
        "surface_range",
        "walk",
    }
    assert all(n >= 1 for n in signatures.values()), signatures


def test_the_kernels_run_where_numba_cannot_cache_them():
    # a read-only install run by a user with no writable home: every folder numba could
    # cache in refuses a file (numba's own check made to fail), which once made importing
    # the kernels fail ("no locator available"); they now compile in the process, with a
    # warning, and give beam_basis's frames to the bit
    import json
    import subprocess
    import sys

    code = (
        "import json, numpy as np; import numba.core.caching as C\n"
        "def refuse(self): raise PermissionError('read-only')\n"
        "C._CacheLocator.ensure_cache_path = refuse\n"
        "from treesim.scan import _edge_jit as J; from treesim.scan.beam import beam_basis\n"
        "d = np.random.default_rng(3).normal(size=(50, 3))\n"
        "d /= np.linalg.norm(d, axis=1, keepdims=True)\n"
        "e1, e2 = J.basis(d); r1, r2 = beam_basis(d)\n"
        "print(json.dumps([J.CACHE, bool((e1 == r1).all() and (e2 == r2).all())]))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [False, True]
    assert "cannot be cached" in out.stderr and "NUMBA_CACHE_DIR" in out.stderr
