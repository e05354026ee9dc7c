"""The edge beam model's inner loops, compiled (numba): a pulse's footprint against the
mesh's edges, and the walk across the surface it meets.

:mod:`treesim.scan.beam` imports this module only when the edge model runs
(``beam_sampling="edge"``): numba's import (about 0.3 s) and its first compilation stay
out of every other command. The kernels are compiled once per machine and cached: in
``NUMBA_CACHE_DIR`` where it is set, else beside this file, else in numba's user-wide cache
where this folder is read-only; where none can be written, once per process
(:func:`_cache_usable`).

The arithmetic is the numpy formulas' (:func:`treesim.scan.beam.beam_basis`, the edge
lines, the surface's range), in float64 and in numpy's order (no fast-math: no
reassociation, no fused multiply-add), but for a square root where numpy's ``hypot``
scaled and sums in the loop's order: the tests in ``tests/scan/test_edge_beam_speed.py``
hold the numbers within 1e-12 of the formulas as they stood before (signs, cross
products and the frames to the bit), and the walks to the same triangles and edges.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numba import njit


def _cache_usable() -> bool:
    """Whether numba can cache this module's kernels: it needs a folder it can write
    (``NUMBA_CACHE_DIR``, else the ``__pycache__`` beside this file, else numba's
    user-wide cache), and without one ``cache=True`` fails as the module is imported (a
    read-only install run by a user with no writable home). There the kernels are
    compiled in each process instead (:func:`treesim.scan.warmup.warm_edge_model`'s
    figure, once per process), with a warning that says how to keep them."""

    def probe(x):  # pragma: no cover - never called, only decorated
        return x

    try:
        njit(cache=True)(probe)
    except RuntimeError as exc:  # numba: "cannot cache function ...: no locator"
        logging.getLogger("treesim").warning(
            "the edge beam model's kernels cannot be cached (%s): each process compiles "
            "them on its first edge scan (tens of seconds); set NUMBA_CACHE_DIR to a "
            "folder this user can write to keep them",
            exc,
        )
        return False
    return True


#: whether the kernels are cached (:func:`_cache_usable`)
CACHE = _cache_usable()

#: how many distinct triangles a miss's neighbours hit :func:`neighbours` keeps (nearest
#: ring first): where the walk that settles the miss may start
BESIDE = 8

__all__ = [
    "approach",
    "basis",
    "box_pulses",
    "edge_lines",
    "neighbours",
    "overlaps",
    "stray_samples",
    "surface_range",
    "walk",
]


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _dot(a0, a1, a2, b, p):  # pragma: no cover - compiled
    # in the order numpy's einsum sums three products on x86-64 (two lanes: 0 and 2, 1)
    return (a0 * b[p, 0] + a2 * b[p, 2]) + a1 * b[p, 1]


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _sign(x):  # pragma: no cover - compiled
    # 0.0, -0.0 or nan, as np.sign
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else x)


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _corner(v, faces, o, th, d, e1, e2, p, t, k):  # pragma: no cover - compiled
    """Corner ``k`` of triangle ``t`` from the station (x, y, z), on pulse ``p``'s
    footprint plane (u, v in footprint radii) and whether it lies in front (1.0, 0.0)."""
    f = faces[t, k]
    a0, a1, a2 = v[f, 0] - o[0], v[f, 1] - o[1], v[f, 2] - o[2]
    ad = _dot(a0, a1, a2, d, p)
    front = ad > 1e-12 * math.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
    safe = ad if front else 1.0
    pu = _dot(a0, a1, a2, e1, p) / safe / th
    pv = _dot(a0, a1, a2, e2, p) / safe / th
    return a0, a1, a2, pu, pv, 1.0 if front else 0.0


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _edge(ca, cb, cc, th, d, e1, e2, p):  # pragma: no cover - compiled
    """The edge from corner ``ca`` to ``cb`` (:func:`_corner`; ``cc`` the third) on pulse
    ``p``'s footprint plane: (nu, nv, c, dist, sg, and the normal m0, m1, m2 of the
    plane through the station and the edge)."""
    m0 = ca[1] * cb[2] - ca[2] * cb[1]
    m1 = ca[2] * cb[0] - ca[0] * cb[2]
    m2 = ca[0] * cb[1] - ca[1] * cb[0]
    sg = _sign((m0 * cc[0] + m2 * cc[2]) + m1 * cc[1])
    la = _dot(m0, m1, m2, e1, p) * th
    lb = _dot(m0, m1, m2, e2, p) * th
    ln = max(math.sqrt(la * la + lb * lb), 1e-300)
    c = sg * _dot(m0, m1, m2, d, p) / ln
    pu, pv = ca[3], ca[4]
    du, dv = cb[3] - pu, cb[4] - pv
    s = -(pu * du + pv * dv) / max(du * du + dv * dv, 1e-300)
    s = min(max(s, 0.0), 1.0)
    x, y = pu + s * du, pv + s * dv
    dist = math.sqrt(x * x + y * y) if (ca[5] > 0.0 and cb[5] > 0.0) else abs(c)
    return sg * la / ln, sg * lb / ln, c, dist, sg, m0, m1, m2


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _lines_of(v, faces, o, th, d, e1, e2, p, t, out, m):  # pragma: no cover - compiled
    """Triangle ``t``'s edge lines along pulse ``p`` of (d, e1, e2): ``out`` (5, 3) rows
    nu, nv, c, dist, sg; ``m`` (3, 3): the normal of each edge's plane through the
    station."""
    c0 = _corner(v, faces, o, th, d, e1, e2, p, t, 0)
    c1 = _corner(v, faces, o, th, d, e1, e2, p, t, 1)
    c2 = _corner(v, faces, o, th, d, e1, e2, p, t, 2)
    g0 = _edge(c0, c1, c2, th, d, e1, e2, p)
    g1 = _edge(c1, c2, c0, th, d, e1, e2, p)
    g2 = _edge(c2, c0, c1, th, d, e1, e2, p)
    out[0, 0], out[1, 0], out[2, 0], out[3, 0], out[4, 0] = g0[0], g0[1], g0[2], g0[3], g0[4]
    out[0, 1], out[1, 1], out[2, 1], out[3, 1], out[4, 1] = g1[0], g1[1], g1[2], g1[3], g1[4]
    out[0, 2], out[1, 2], out[2, 2], out[3, 2], out[4, 2] = g2[0], g2[1], g2[2], g2[3], g2[4]
    m[0, 0], m[0, 1], m[0, 2] = g0[5], g0[6], g0[7]
    m[1, 0], m[1, 1], m[1, 2] = g1[5], g1[6], g1[7]
    m[2, 0], m[2, 1], m[2, 2] = g2[5], g2[6], g2[7]


@njit(cache=CACHE, nogil=True, error_model="numpy")
def edge_lines(v, faces, o, th, d, e1, e2, tri):  # pragma: no cover - compiled
    """:func:`treesim.scan.beam._edge_lines` of pulses (d, e1, e2) (n, 3) and their
    triangles ``tri`` (n,): nu, nv, c, dist, sg (each (n, 3)) and m (n, 3, 3)."""
    n = len(tri)
    res = np.empty((n, 5, 3))
    mm = np.empty((n, 3, 3))
    out = np.empty((5, 3))
    m = np.empty((3, 3))
    for p in range(n):
        _lines_of(v, faces, o, th, d, e1, e2, p, tri[p], out, m)
        for j in range(3):
            for i in range(5):
                res[p, i, j] = out[i, j]
            for i in range(3):
                mm[p, j, i] = m[j, i]
    return res[:, 0], res[:, 1], res[:, 2], res[:, 3], res[:, 4], mm


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _grown(a, n):  # pragma: no cover - compiled
    """``a`` with room for at least ``n`` items (twice over), its items kept."""
    if n > len(a):
        b = np.empty(max(n, 2 * len(a)), dtype=a.dtype)
        b[: len(a)] = a
        a = b
    return a


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _next_ring(cand_t, cand_e, n_cand, seen, n_seen, ring_t, ring_e):  # pragma: no cover
    """The next ring of a walk from the ``n_cand`` triangles reached (``cand_t``, each
    with the edge it was entered by, ``cand_e``): each triangle once (the first to reach
    it), none of the ``n_seen`` seen before, in the order of their indices, into
    ``ring_t``, ``ring_e`` (room for ``n_cand``). Returns its length."""
    # the candidates sorted by triangle, stably (an insertion sort: they are few)
    for i in range(1, n_cand):
        tc, ec = cand_t[i], cand_e[i]
        k = i - 1
        while k >= 0 and cand_t[k] > tc:
            cand_t[k + 1], cand_e[k + 1] = cand_t[k], cand_e[k]
            k -= 1
        cand_t[k + 1], cand_e[k + 1] = tc, ec
    n_ring = 0
    for i in range(n_cand):
        tc = cand_t[i]
        if i > 0 and cand_t[i - 1] == tc:
            continue
        known = False
        for s in range(n_seen):
            if seen[s] == tc:
                known = True
                break
        if known:
            continue
        ring_t[n_ring], ring_e[n_ring] = tc, cand_e[i]
        n_ring += 1
    return n_ring


@njit(cache=CACHE, nogil=True, error_model="numpy")
def walk(v, faces, nbr, o, th, d, e1, e2, start, steps):  # pragma: no cover - compiled
    """:func:`treesim.scan.beam._walk` of pulses (d, e1, e2) from triangles ``start``:
    ring after ring of triangles, the rings of a pulse walked in the order of their
    triangles' indices (each reached once, by the first triangle to reach it).

    Returns the silhouette lines (pulse, nu, nv, c, tri), which pulses did not finish
    within ``steps`` rings, and the trail, pulse by pulse: (2, k) pulse and triangle,
    (k, 3, 3) their edges' nu, nv, c."""
    n = len(start)
    cap = 4 * n + 16
    l_p = np.empty(cap, np.int64)
    l_t = np.empty(cap, np.int64)
    l_f = np.empty(3 * cap)
    t_p = np.empty(cap, np.int64)
    t_t = np.empty(cap, np.int64)
    t_f = np.empty(9 * cap)
    n_l = 0
    n_t = 0
    unresolved = np.zeros(n, dtype=np.bool_)
    out = np.empty((5, 3))
    m = np.empty((3, 3))
    ring_t = np.empty(64, np.int64)
    ring_e = np.empty(64, np.int64)
    cand_t = np.empty(64, np.int64)
    cand_e = np.empty(64, np.int64)
    seen = np.empty(64, np.int64)
    for p in range(n):
        ring_t[0], ring_e[0] = start[p], -1
        n_ring = 1
        seen[0] = start[p]
        n_seen = 1
        for step in range(steps + 1):
            if n_ring == 0:
                break
            if step == steps:
                unresolved[p] = True
                break
            # room for the ring's rows, once (checked row by row, the walk took a third
            # longer)
            t_p, t_t = _grown(t_p, n_t + n_ring), _grown(t_t, n_t + n_ring)
            t_f = _grown(t_f, 9 * (n_t + n_ring))
            l_p, l_t = _grown(l_p, n_l + 3 * n_ring), _grown(l_t, n_l + 3 * n_ring)
            l_f = _grown(l_f, 3 * (n_l + 3 * n_ring))
            cand_t, cand_e = _grown(cand_t, 3 * n_ring), _grown(cand_e, 3 * n_ring)
            ring_t, ring_e = _grown(ring_t, 3 * n_ring), _grown(ring_e, 3 * n_ring)
            seen = _grown(seen, n_seen + 3 * n_ring)
            n_cand = 0
            for r in range(n_ring):
                t, e_in = ring_t[r], ring_e[r]
                _lines_of(v, faces, o, th, d, e1, e2, p, t, out, m)
                t_p[n_t], t_t[n_t] = p, t
                for j in range(3):
                    t_f[9 * n_t + j] = out[0, j]
                    t_f[9 * n_t + 3 + j] = out[1, j]
                    t_f[9 * n_t + 6 + j] = out[2, j]
                n_t += 1
                for j in range(3):
                    if not (out[3, j] < 1.0) or j == e_in:
                        continue
                    nb = nbr[t, j]
                    cont = False
                    k_opp = 0
                    if nb >= 0:
                        ia, ib = faces[t, j], faces[t, (j + 1) % 3]
                        opp = faces[nb, 0] + faces[nb, 1] + faces[nb, 2] - ia - ib
                        r0, r1, r2 = v[opp, 0] - o[0], v[opp, 1] - o[1], v[opp, 2] - o[2]
                        side = _sign((m[j, 0] * r0 + m[j, 2] * r2) + m[j, 1] * r1)
                        cont = side == -out[4, j]
                        for k in range(2, -1, -1):  # the first corner that is opp
                            if faces[nb, k] == opp:
                                k_opp = k
                    if not cont:
                        l_p[n_l], l_t[n_l] = p, t
                        l_f[3 * n_l], l_f[3 * n_l + 1] = out[0, j], out[1, j]
                        l_f[3 * n_l + 2] = out[2, j]
                        n_l += 1
                    else:
                        cand_t[n_cand], cand_e[n_cand] = nb, (k_opp + 1) % 3
                        n_cand += 1
            n_ring = _next_ring(cand_t, cand_e, n_cand, seen, n_seen, ring_t, ring_e)
            for r in range(n_ring):
                seen[n_seen] = ring_t[r]
                n_seen += 1
    lines_f = l_f[: 3 * n_l].reshape(n_l, 3)
    trail = np.empty((2, n_t), np.int64)
    trail[0] = t_p[:n_t]
    trail[1] = t_t[:n_t]
    return (
        l_p[:n_l].copy(),
        lines_f[:, 0].copy(),
        lines_f[:, 1].copy(),
        lines_f[:, 2].copy(),
        l_t[:n_l].copy(),
        unresolved,
        trail,
        t_f[: 9 * n_t].copy().reshape(n_t, 3, 3),
    )


@njit(cache=CACHE, nogil=True, error_model="numpy")
def _uncovered(q_r, pts, wts, sector, row):  # pragma: no cover - compiled
    """Into ``row[1:10]``: for each third of the footprint (``sector`` of each point),
    the weight of its points that no walked triangle holds (``q_r`` inf) and the one of
    them nearest their weighted centroid (the centroid of a part that is not convex may
    lie on the surface)."""
    for i in range(len(pts)):
        if not (q_r[i] < np.inf):
            sec = sector[i]
            row[1 + 3 * sec] += wts[i]
            row[2 + 3 * sec] += pts[i, 0] * wts[i]
            row[3 + 3 * sec] += pts[i, 1] * wts[i]
    for sec in range(3):
        w_s = row[1 + 3 * sec]
        if w_s > 0:
            cx, cy = row[2 + 3 * sec] / w_s, row[3 + 3 * sec] / w_s
            best = np.inf
            for i in range(len(pts)):
                if q_r[i] < np.inf or sector[i] != sec:
                    continue
                dd = (pts[i, 0] - cx) ** 2 + (pts[i, 1] - cy) ** 2
                if dd < best:
                    best = dd
                    row[2 + 3 * sec], row[3 + 3 * sec] = pts[i, 0], pts[i, 1]


@njit(cache=CACHE, nogil=True, error_model="numpy")
def surface_range(
    v, faces, o, th, d, e1, e2, trail, lines, pulses, pts, wts, cut, cut_at, full
):  # pragma: no cover - compiled
    """:func:`treesim.scan.beam._surface_range`: for each walked pulse ``pulses[q]``
    (frames (d, e1, e2)), the weighted mean range of the footprint points ``pts`` (k, 2)
    (weights ``wts``) that fall inside the triangles of its trail (``trail`` (2, n):
    pulse, triangle, pulse by pulse; ``lines`` (n, 3, 3): their edges' nu, nv, c), the
    nearest where several hold one; nan where none does. ``cut`` (m, 3): lines nu, nv,
    c of pulse ``q`` at rows ``cut_at[q]:cut_at[q + 1]``, beyond any of which a point is
    not looked at (all looked at where ``cut_at`` is empty).

    Returns the ranges, the nearest and farthest range of the covered points (n, 2; nan
    where none) and, with ``full``, per pulse (10 columns) the covered weight, then for
    each third of the footprint (by angle) the uncovered weight and the uncovered point
    nearest the third's uncovered centroid (x, y) (:func:`_uncovered`)."""
    n_trail = trail.shape[1]
    k = len(pts)
    out = np.empty(len(pulses))
    ext = np.full((len(pulses), 2), np.nan)
    cover = np.zeros((len(pulses) if full else 0, 10))
    sector = np.empty(k, np.int64)  # each point's third of the footprint, by angle
    for i in range(k):
        a = math.atan2(pts[i, 1], pts[i, 0]) % (2.0 * math.pi)
        sector[i] = min(int(a / (2.0 * math.pi / 3.0)), 2)
    q_r = np.empty(k)
    look = np.empty(k, dtype=np.bool_)
    w = np.empty((k, 3))
    nrm = np.empty((1, 3))
    rel = np.empty((1, 3))
    for q in range(len(pulses)):
        p = pulses[q]
        # the pulse's trail rows (the trail goes pulse by pulse)
        lo, hi = 0, n_trail
        while lo < hi:
            mid = (lo + hi) // 2
            if trail[0, mid] < p:
                lo = mid + 1
            else:
                hi = mid
        for i in range(k):
            q_r[i] = np.inf
            look[i] = True
            if len(cut_at):
                for r in range(cut_at[q], cut_at[q + 1]):
                    if cut[r, 0] * pts[i, 0] + cut[r, 1] * pts[i, 1] + cut[r, 2] < -1e-9:
                        look[i] = False
                        break
            # the point's ray: (d + th (x e1 + y e2)) / norm
            for j in range(3):
                w[i, j] = (pts[i, 0] * e1[p, j] + pts[i, 1] * e2[p, j]) * th + d[p, j]
            s = math.sqrt((w[i, 0] * w[i, 0] + w[i, 1] * w[i, 1]) + w[i, 2] * w[i, 2])
            for j in range(3):
                w[i, j] /= s
        r = lo
        while r < n_trail and trail[0, r] == p:
            t = trail[1, r]
            have = False
            for i in range(k):
                if not look[i]:
                    continue
                inside = True
                for j in range(3):
                    val = lines[r, 0, j] * pts[i, 0] + lines[r, 1, j] * pts[i, 1]
                    if not (val + lines[r, 2, j] >= -1e-9):
                        inside = False
                        break
                if not inside:
                    continue
                if not have:  # the triangle's plane, once
                    f0, f1, f2 = faces[t, 0], faces[t, 1], faces[t, 2]
                    for j in range(3):
                        rel[0, j] = v[f0, j] - o[j]
                    a0, a1, a2 = v[f1, 0] - v[f0, 0], v[f1, 1] - v[f0, 1], v[f1, 2] - v[f0, 2]
                    b0, b1, b2 = v[f2, 0] - v[f0, 0], v[f2, 1] - v[f0, 1], v[f2, 2] - v[f0, 2]
                    nrm[0, 0] = a1 * b2 - a2 * b1
                    nrm[0, 1] = a2 * b0 - a0 * b2
                    nrm[0, 2] = a0 * b1 - a1 * b0
                    num = _dot(nrm[0, 0], nrm[0, 1], nrm[0, 2], rel, 0)
                    have = True
                rng = num / _dot(nrm[0, 0], nrm[0, 1], nrm[0, 2], w, i)
                if rng > 0 and rng < q_r[i]:
                    q_r[i] = rng
            r += 1
        tot, wt = 0.0, 0.0
        r_lo, r_hi = np.inf, -np.inf
        for i in range(k):
            if q_r[i] < np.inf:
                tot += q_r[i] * wts[i]
                wt += wts[i]
                r_lo = min(r_lo, q_r[i])
                r_hi = max(r_hi, q_r[i])
        out[q] = tot / wt if wt > 0 else np.nan
        if wt > 0:
            ext[q, 0], ext[q, 1] = r_lo, r_hi
        if full:
            cover[q, 0] = wt
            _uncovered(q_r, pts, wts, sector, cover[q])
    return out, ext, cover


@njit(cache=CACHE, nogil=True, error_model="numpy")
def _search(key, skey, order):  # pragma: no cover - compiled
    """The pulse of ``key`` among the sorted keys ``skey`` (``order``: their pulses), -1
    where none.

    The loops find a pulse at column ``qc``, line ``ql`` from
    :meth:`treesim.scan.beam.EdgeBeam._lookup`'s tuple (``look``, ``colpos``, ``lmin``,
    ``skey``, ``order``): in the dense table ``look`` (a column's row ``colpos``, a
    line's column ``line - lmin``), or where that is empty here, with the key
    ``qc * n_lines + ql``. They do so in their own body: as a function, inlined or not,
    the lookup made the loops around it ten times slower (numba 0.68)."""
    lo, hi = 0, len(skey)
    while lo < hi:
        mid = (lo + hi) // 2
        if skey[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    if lo < len(skey) and skey[lo] == key:
        return order[lo]
    return -1


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _column(qc, n_az, full_turn):  # pragma: no cover - compiled
    """Column ``qc`` on the grid (wrapped on a full turn), -1 off it."""
    if full_turn:
        return qc % n_az
    return qc if 0 <= qc < n_az else -1


@njit(cache=CACHE, nogil=True, error_model="numpy")
def neighbours(lines, cols, n_core, t, hit, planes, o, grid, lookup, k, tol):  # pragma: no cover
    """:meth:`treesim.scan.beam.EdgeBeam._neighbours` of a block's pulses (``lines``,
    ``cols``, the first ``n_core`` its core; central ranges ``t``, inf on a miss; ``hit``:
    the hits' directions (m, 3), each pulse's row in them (-1 on a miss) and its triangle;
    ``planes``: the vertices, the faces, triangles' normals and each core pulse's row in
    them, -1 on a miss), looking ``k`` steps each way, nearest ring first: per core
    pulse, whether a neighbour hit (``near``), the nearest and farthest such hit (``lo``,
    ``hi``), for a hit whether a neighbour's hit lies in front of its triangle's plane
    (towards the station) by more than ``tol`` (``jump``), and for each miss with a
    neighbour's hit, in order, the first :data:`BESIDE` distinct triangles those hits
    met (``tri``, (misses, BESIDE), -1 past them). ``grid``: (n_az, n_lines, full_turn);
    ``lookup``: see :func:`_search`."""
    n_az, n_lines, full_turn = grid
    d_hit, at, prim = hit
    v, faces, normal, n_at = planes
    look, colpos, lmin, skey, order = lookup
    near = np.empty(n_core, dtype=np.bool_)
    jump = np.empty(n_core, dtype=np.bool_)
    lo = np.empty(n_core)
    hi = np.empty(n_core)
    tri = np.empty(BESIDE * 1024, dtype=np.int64)
    n_near = 0
    for i in range(n_core):
        is_hit = t[i] < np.inf
        n0, n1, n2, p0, p1, p2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if is_hit:
            r = n_at[i]
            n0, n1, n2 = normal[r, 0], normal[r, 1], normal[r, 2]
            f0 = faces[prim[i], 0]
            p0, p1, p2 = v[f0, 0], v[f0, 1], v[f0, 2]
            # the plane's normal turned towards the station
            if (((o[0] - p0) * n0 + (o[2] - p2) * n2) + (o[1] - p1) * n1) < 0:
                n0, n1, n2 = -n0, -n1, -n2
        nr, jp, t_lo, t_hi, n_tri = False, False, np.inf, -np.inf, 0
        row = BESIDE * n_near
        if not is_hit:  # a row for the miss, kept if a neighbour hit
            tri = _grown(tri, row + BESIDE)
            for j in range(BESIDE):
                tri[row + j] = -1
        for r in range(1, k + 1):
            for dc in range(-r, r + 1):
                qc = _column(cols[i] + dc, n_az, full_turn)
                if qc < 0:
                    continue
                for dl in range(-r, r + 1):
                    ql = lines[i] + dl
                    if (abs(dc) < r and abs(dl) < r) or ql < 0 or ql >= n_lines:
                        continue
                    if look.shape[0] > 0:
                        pc, rw = colpos[qc], ql - lmin
                        q = -1 if (pc < 0 or rw < 0 or rw >= look.shape[1]) else look[pc, rw]
                    else:
                        q = _search(qc * n_lines + ql, skey, order)
                    if q < 0 or not (t[q] < np.inf):
                        continue
                    if not is_hit:
                        nr = True
                        t_lo = min(t_lo, t[q])
                        t_hi = max(t_hi, t[q])
                        seen = n_tri >= BESIDE
                        for j in range(n_tri):
                            seen = seen or tri[row + j] == prim[q]
                        if not seen:
                            tri[row + n_tri] = prim[q]
                            n_tri += 1
                    elif not jp:
                        a = at[q]
                        x0 = o[0] + t[q] * d_hit[a, 0]
                        x1 = o[1] + t[q] * d_hit[a, 1]
                        x2 = o[2] + t[q] * d_hit[a, 2]
                        r0, r1, r2 = x0 - p0, x1 - p1, x2 - p2
                        jp = (r0 * n0 + r2 * n2) + r1 * n1 > tol
        near[i], jump[i], lo[i], hi[i] = nr, jp, t_lo, t_hi
        if nr:
            n_near += 1
    return near, lo, hi, jump, tri[: BESIDE * n_near].copy().reshape(n_near, BESIDE)


@njit(cache=CACHE, nogil=True, error_model="numpy")
def box_pulses(box, sel, n_core, grid, lookup):  # pragma: no cover - compiled
    """(pulse, triangle) pairs of the thin-geometry boxes ``sel``: each box's pulses
    (among the first ``n_core`` the lookup knows) within its sample's reach, an ellipse
    in lines and columns. ``box``: (l_lo, l_hi, c_lo, c_hi, tri) integers and (line,
    col, rl, rc) floats of :func:`treesim.scan.beam._stray_samples`, a triangle's boxes
    one after another: each pair once (a triangle's boxes overlap)."""
    l_lo, l_hi, c_lo, c_hi, tri = box[0]
    line, col, rl, rc = box[1]
    n_az, n_lines, full_turn = grid
    look, colpos, lmin, skey, order = lookup
    mark = np.full(n_core, -1, np.int64)  # the last triangle paired with each pulse
    out_p = np.empty(1024, np.int64)
    out_t = np.empty(1024, np.int64)
    n = 0
    for b in sel:
        for qc0 in range(c_lo[b], c_hi[b] + 1):
            for ql in range(l_lo[b], l_hi[b] + 1):
                a = (ql - line[b]) / rl[b]
                c = (qc0 - col[b]) / rc[b]
                if a * a + c * c > 1.0 or ql < 0 or ql >= n_lines:
                    continue
                qc = _column(qc0, n_az, full_turn)
                if qc < 0:
                    continue
                if look.shape[0] > 0:
                    pc, row = colpos[qc], ql - lmin
                    q = -1 if (pc < 0 or row < 0 or row >= look.shape[1]) else look[pc, row]
                else:
                    q = _search(qc * n_lines + ql, skey, order)
                if q < 0 or q >= n_core or mark[q] == tri[b]:
                    continue
                mark[q] = tri[b]
                out_p = _grown(out_p, n + 1)
                out_t = _grown(out_t, n + 1)
                out_p[n], out_t[n] = q, tri[b]
                n += 1
    return out_p[:n].copy(), out_t[:n].copy()


@njit(cache=CACHE, nogil=True, error_model="numpy")
def stray_samples(sides, n_s, reach, res, fov0):  # pragma: no cover - compiled
    """The samples of :func:`treesim.scan.beam._stray_samples` and their boxes, its numpy
    formulas sample by sample: ``sides`` (ua, ub, length, width) of
    :func:`treesim.scan.occupancy.seen_sides`, ``n_s`` samples per triangle, ``reach``
    (rad), ``res`` (vertical, horizontal step, rad), ``fov0`` (the field of view's first
    elevation and azimuth, rad). Returns (l_lo, l_hi, c_lo, c_hi, tri) integers and
    (line, col, rl, rc) floats, each (samples,), and False where a box reaches a pole
    (cosine of its elevation under 1e-3: then nothing else is filled)."""
    ua, ub, length, width = sides
    vres, hres = res
    el0, az0 = fov0
    total = 0
    for i in range(len(n_s)):
        total += n_s[i]
    ints = np.empty((5, total), np.int64)
    floats = np.empty((4, total))
    two_pi = 2.0 * math.pi
    s = 0
    for i in range(len(n_s)):
        den = max(n_s[i] - 1, 1)
        radius = reach + 1.01 * width[i] + 0.6 * length[i] / den
        for j in range(n_s[i]):
            f = j / den
            d0 = (1.0 - f) * ua[i, 0] + f * ub[i, 0]
            d1 = (1.0 - f) * ua[i, 1] + f * ub[i, 1]
            d2 = (1.0 - f) * ua[i, 2] + f * ub[i, 2]
            nn = math.sqrt((d0 * d0 + d1 * d1) + d2 * d2)
            d0, d1, d2 = d0 / nn, d1 / nn, d2 / nn
            el = math.asin(min(max(d2, -1.0), 1.0))
            cos_el = math.cos(min(abs(el) + radius, math.pi / 2))
            if cos_el < 1e-3:
                return ints, floats, False
            line = (el - el0) / vres
            col = ((math.atan2(d1, d0) - az0) % two_pi) / hres
            rl = radius / vres
            rc = radius / (hres * cos_el)
            ints[0, s] = math.ceil(line - rl)
            ints[1, s] = math.floor(line + rl)
            ints[2, s] = math.ceil(col - rc)
            ints[3, s] = math.floor(col + rc)
            ints[4, s] = i
            floats[0, s], floats[1, s], floats[2, s], floats[3, s] = line, col, rl, rc
            s += 1
    return ints, floats, True


@njit(cache=CACHE, nogil=True, error_model="numpy")
def basis(d):  # pragma: no cover - compiled
    """:func:`treesim.scan.beam.beam_basis` of directions ``d`` (n, 3), numpy's
    operations in numpy's order: (e1, e2)."""
    n = len(d)
    e1 = np.empty((n, 3))
    e2 = np.empty((n, 3))
    for p in range(n):
        x, y, z = d[p, 0], d[p, 1], d[p, 2]
        if abs(z) < 0.99:  # up = (0, 0, 1)
            a0, a1, a2 = 0.0 * z - 1.0 * y, 1.0 * x - 0.0 * z, 0.0 * y - 0.0 * x
        else:  # up = (1, 0, 0)
            a0, a1, a2 = 0.0 * z - 0.0 * y, 0.0 * x - 1.0 * z, 1.0 * y - 0.0 * x
        s = math.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
        a0, a1, a2 = a0 / s, a1 / s, a2 / s
        e1[p, 0], e1[p, 1], e1[p, 2] = a0, a1, a2
        e2[p, 0] = y * a2 - z * a1
        e2[p, 1] = z * a0 - x * a2
        e2[p, 2] = x * a1 - y * a0
    return e1, e2


@njit(cache=CACHE, nogil=True, error_model="numpy")
def overlaps(v, faces, o, th, d, e1, e2, rep, tri):  # pragma: no cover - compiled
    """Whether triangle ``tri[i]`` overlaps the footprint of pulse ``rep[i]`` (frames
    (d, e1, e2)), as seen: an edge within the footprint, or the axis inside it."""
    n = len(tri)
    ok = np.empty(n, dtype=np.bool_)
    out = np.empty((5, 3))
    m = np.empty((3, 3))
    for i in range(n):
        _lines_of(v, faces, o, th, d, e1, e2, rep[i], tri[i], out, m)
        near = out[3, 0] < 1.0 or out[3, 1] < 1.0 or out[3, 2] < 1.0
        ok[i] = near or (out[2, 0] >= 0.0 and out[2, 1] >= 0.0 and out[2, 2] >= 0.0)
    return ok


@njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _reach(v, faces, o, th, d, e1, e2, p, t, out, m):  # pragma: no cover - compiled
    """How far triangle ``t`` lies from pulse ``p``'s axis, as seen, in footprint radii:
    0 with the axis inside it, else its nearest edge's distance (under 1: it overlaps
    the footprint, as :func:`overlaps` says)."""
    _lines_of(v, faces, o, th, d, e1, e2, p, t, out, m)
    if out[2, 0] >= 0.0 and out[2, 1] >= 0.0 and out[2, 2] >= 0.0:
        return 0.0
    return min(out[3, 0], min(out[3, 1], out[3, 2]))


@njit(cache=CACHE, nogil=True, error_model="numpy")
def approach(v, faces, nbr, o, th, d, e1, e2, cand, steps):  # pragma: no cover - compiled
    """Where pulses (d, e1, e2) whose central ray missed meet the surface their
    neighbours' central rays hit (``cand``: each pulse's triangles of those hits, -1 past
    them). Where no candidate overlaps the footprint, from each in turn (nearest the
    axis first, as seen) at most ``steps`` steps across its edges, each to the
    neighbour nearest the axis while that comes no farther (round a corner that several
    triangles share, never back), until one overlaps the footprint: round a twig to its
    silhouette; a candidate on one branch may lead nowhere while another's does.
    Returns which candidates overlap the footprint (as :func:`overlaps`; (n, c)), per
    pulse the distinct triangles the steps reached ((n, c), -1 past them) and how near
    the steps came to the axis (footprint radii; inf where none were taken)."""
    n, c = cand.shape
    start = np.full((n, c), -1, dtype=np.int64)
    gap = np.full(n, np.inf)
    over = np.zeros((n, c), dtype=np.bool_)
    been = np.empty(steps + 1, dtype=np.int64)
    dist = np.empty(c)
    out = np.empty((5, 3))
    m = np.empty((3, 3))
    for p in range(n):
        n_c, any_over, n_r = 0, False, 0
        for j in range(c):
            t = cand[p, j]
            if t < 0:
                break
            dist[j] = _reach(v, faces, o, th, d, e1, e2, p, t, out, m)
            over[p, j] = dist[j] < 1.0
            any_over = any_over or over[p, j]
            n_c += 1
        for _ in range(n_c if not any_over else 0):
            # the nearest candidate not yet tried
            jj, far = -1, np.inf
            for j in range(n_c):
                if dist[j] < far:
                    jj, far = j, dist[j]
            if jj < 0:
                break
            best = cand[p, jj]
            dist[jj] = np.inf
            s = 0
            been[0] = best
            while not (far < 1.0) and s < steps:
                nxt, nearer = -1, far
                for k in range(3):
                    u = nbr[best, k]
                    if u < 0:
                        continue
                    fresh = True
                    for j in range(s + 1):
                        fresh = fresh and been[j] != u
                    if not fresh:
                        continue
                    r = _reach(v, faces, o, th, d, e1, e2, p, u, out, m)
                    if r < nearer or (r == nearer and nxt < 0):
                        nxt, nearer = u, r
                if nxt < 0:
                    break
                best, far = nxt, nearer
                s += 1
                been[s] = best
            gap[p] = min(gap[p], far)
            if far < 1.0:
                reached = True
                for j in range(n_r):
                    reached = reached and start[p, j] != best
                if reached:
                    start[p, n_r] = best
                    n_r += 1
    return over, start, gap
