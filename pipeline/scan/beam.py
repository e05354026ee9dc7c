"""Beam divergence: a pulse is a cone sampled by sub-rays; echoes become returns.

Sub-ray layout: one ray on the beam axis and the rest on a sunflower (Fibonacci)
spiral filling the cone of half-angle ``divergence / 2``. Each sub-ray carries the
energy of a Gaussian beam profile whose 1/e² radius is the cone's edge,
``w = exp(-2 (rho / half_angle)^2)``, normalised to sum to 1 per pulse.

Echoes: the sub-ray hits of one pulse are sorted by range; a gap larger than the
range resolution starts a new return. A return's range is the energy-weighted mean of
its sub-ray ranges; its point lies on the beam axis at that range (as a real scanner
records it, which is what produces "mixed pixels" at edges); its energy is the sum of
its sub-rays' weights; its label and incidence are those of its strongest sub-ray.

Adaptive sampling (:class:`AdaptiveBeam`, ``beam_sampling="adaptive"`` under
``lod="auto"``): every pulse's central ray is cast first, and only pulses whose
footprint can straddle an edge, another surface, thin geometry or a range limit get their
sub-rays; the others keep their central hit as one return.

Returns of a block of pulses are records (dicts of per-return arrays: ``pulse``,
``range_m``, ``primitive``, ``direction``, ``energy``, ``return_number``,
``number_of_returns``): :func:`single_returns` for one ray per pulse,
:func:`beam_returns` for sub-rays.
"""

from __future__ import annotations

import math
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from ..params import ScannerSpec
from .caster import Caster, RayTables, cast_central
from .occupancy import seen_sides
from .planning import StationPlan
from .rays import directions, pulse_angles


def subray_pattern(n: int, divergence_mrad: float) -> tuple[np.ndarray, np.ndarray]:
    """Angular offsets (n, 2) rad in the beam's tangent plane and weights (n,) summing to 1."""
    half = 0.5 * divergence_mrad * 1e-3
    k = np.arange(n, dtype=np.float64)
    rho = half * np.sqrt(k / max(n - 1, 1))
    golden = math.pi * (3.0 - math.sqrt(5.0))
    phi = k * golden
    offsets = np.stack([rho * np.cos(phi), rho * np.sin(phi)], axis=1)
    w = np.exp(-2.0 * (rho / half) ** 2) if half > 0 else np.ones(n)
    return offsets, w / w.sum()


def beam_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (p, 3) spanning the tangent plane of each pulse direction ``d``
    (p, 3): ``e1`` horizontal unless the pulse is near vertical, ``e2 = d × e1``."""
    up = np.where(np.abs(d[:, 2:3]) < 0.99, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(up, d)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(d, e1)


def subray_directions(d: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Sub-ray unit directions (p, s, 3) around pulse directions ``d`` (p, 3)."""
    e1, e2 = beam_basis(d)
    tu = np.tan(offsets[:, 0])[None, :, None]
    tv = np.tan(offsets[:, 1])[None, :, None]
    out = d[:, None, :] + tu * e1[:, None, :] + tv * e2[:, None, :]
    return out / np.linalg.norm(out, axis=2, keepdims=True)


def group_returns(
    t: np.ndarray,
    weights: np.ndarray,
    range_resolution_m: float,
    extent: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Group sub-ray ranges of each pulse into returns.

    Parameters
    ----------
    t : (p, s) float
        Sub-ray ranges, ``inf`` where the sub-ray missed or fell outside the range limits.
    weights : (s,) or (p, s) float
        Sub-ray energy weights (sum 1), the same for every pulse or one row per pulse
        (the edge model's parts of a footprint).
    range_resolution_m : float
        Echoes closer than this merge.
    extent : ((p, s), (p, s)) float, optional
        The nearest and farthest range of each part (the edge model's surface across the
        covered part of a footprint, which may span a range): parts merge where one
        begins within ``range_resolution_m`` of the farthest range of those before it,
        as the sub-rays across such a surface would chain. Without it each part is a
        point at its range.

    Returns
    -------
    dict with (r,) arrays: ``pulse`` (index into p), ``range_m``, ``energy``,
    ``return_number`` (1-based, by range), ``number_of_returns``, ``subray`` (index of
    the strongest sub-ray of the return).
    """
    p, s = t.shape
    new = np.ones(t.shape, dtype=bool)
    if extent is None:
        order = np.argsort(t, axis=1, kind="stable")
        ts = np.take_along_axis(t, order, axis=1)
        with np.errstate(invalid="ignore"):
            new[:, 1:] = np.diff(ts, axis=1) > range_resolution_m
    else:
        lo = np.where(np.isfinite(t), extent[0], np.inf)
        order = np.argsort(lo, axis=1, kind="stable")
        ts = np.take_along_axis(t, order, axis=1)
        far = np.maximum.accumulate(np.take_along_axis(extent[1], order, axis=1), axis=1)
        with np.errstate(invalid="ignore"):
            new[:, 1:] = np.take_along_axis(lo, order, axis=1)[:, 1:] - far[:, :-1] > (
                range_resolution_m
            )
    valid = np.isfinite(ts)
    cid = np.cumsum(new, axis=1) - 1
    pulse = np.broadcast_to(np.arange(p)[:, None], (p, s))[valid]
    cl = cid[valid]
    tv = ts[valid]
    sub = order[valid]
    w = weights[sub] if weights.ndim == 1 else weights[pulse, sub]
    # groups are runs: rows in order, echo clusters in range order within a row
    key = pulse.astype(np.int64) * s + cl
    starts = np.ones(len(key), dtype=bool)
    starts[1:] = key[1:] != key[:-1]
    inv = np.cumsum(starts) - 1
    uniq = key[starts]
    energy = np.bincount(inv, weights=w)
    rng = np.bincount(inv, weights=w * tv) / energy
    # strongest sub-ray per group: the first (in range order) of its largest weight
    if len(w):
        w_max = np.maximum.reduceat(w, np.flatnonzero(starts))
        top = np.flatnonzero(w == w_max[inv])
        first = np.ones(len(top), dtype=bool)
        first[1:] = inv[top][1:] != inv[top][:-1]
        strongest = sub[top[first]]
    else:
        strongest = np.empty(0, dtype=np.int64)
    g_pulse = (uniq // s).astype(np.int64)
    g_cl = (uniq % s).astype(np.int64)
    n_per_pulse = np.bincount(g_pulse, minlength=p)
    return {
        "pulse": g_pulse,
        "range_m": rng,
        "energy": energy,
        "return_number": g_cl + 1,
        "number_of_returns": n_per_pulse[g_pulse],
        "subray": strongest,
    }


def select_returns(groups: dict[str, np.ndarray], mode: str) -> np.ndarray:
    """Boolean mask over returns kept by a return mode (first, last, strongest, all)."""
    rn, nr = groups["return_number"], groups["number_of_returns"]
    if mode == "all":
        return np.ones(len(rn), dtype=bool)
    if mode == "first":
        return rn == 1
    if mode == "last":
        return rn == nr
    # strongest: highest energy of its pulse (first one on ties)
    pulse, energy = groups["pulse"], groups["energy"]
    order = np.lexsort((-energy, pulse))
    keep = np.zeros(len(rn), dtype=bool)
    first = np.ones(len(order), dtype=bool)
    first[1:] = pulse[order][1:] != pulse[order][:-1]
    keep[order[first]] = True
    return keep


def in_range(spec: ScannerSpec, t: np.ndarray) -> np.ndarray:
    """Which ranges ``t`` the scanner records: finite and within its range limits."""
    return np.isfinite(t) & (t >= spec.min_range_m) & (t <= spec.max_range_m)


def single_returns(spec: ScannerSpec, t: np.ndarray, prim: np.ndarray) -> dict[str, Any]:
    """The return record of pulses cast as one ray each (ranges ``t``, triangles
    ``prim``): one return of full energy per pulse that hit within range."""
    keep = in_range(spec, t) & (prim >= 0)
    idx = np.flatnonzero(keep)
    one = np.ones(len(idx), dtype=np.int64)
    return {
        "pulse": idx,
        "range_m": t[idx],
        "primitive": prim[idx],
        "direction": None,  # the pulse direction
        "energy": np.ones(len(idx)),
        "return_number": one,
        "number_of_returns": one,
    }


def beam_returns(
    spec: ScannerSpec, t: np.ndarray, prim: np.ndarray, sd: np.ndarray, weights: np.ndarray
) -> dict[str, Any]:
    """The return record of pulses cast with sub-rays: ranges ``t`` and triangles ``prim``
    (p, s), sub-ray directions ``sd`` (p × s, 3) and their ``weights`` (s,); echoes within
    range grouped (:func:`group_returns`) and kept by the return mode
    (:func:`select_returns`), each with its strongest sub-ray's triangle and direction."""
    p, s = t.shape
    t = np.where(in_range(spec, t) & (prim >= 0), t, np.inf)
    g = group_returns(t, weights, spec.range_resolution_m)
    keep = select_returns(g, spec.return_mode)
    pulse = g["pulse"][keep]
    sub = g["subray"][keep]
    flat = pulse * s + sub
    return {
        "pulse": pulse,
        "range_m": g["range_m"][keep],
        "primitive": prim.reshape(-1)[flat],
        "direction": sd[flat],
        "energy": g["energy"][keep],
        "return_number": g["return_number"][keep],
        "number_of_returns": g["number_of_returns"][keep],
    }


#: A neighbour's hit farther than this from the plane of a pulse's hit triangle means a
#: different surface may lie inside the pulse's footprint (adaptive beam sampling).
ADAPTIVE_PLANE_TOL_M = 1e-3
#: Largest dense neighbour table (cells) adaptive sampling builds per block of columns.
_DENSE_NEIGHBOUR_CELLS = 1 << 23
#: Hits within this fraction of a range limit get sub-rays (the beam may straddle it).
_RANGE_LIMIT_FRACTION = 0.02


class AdaptiveBeam:
    """Beam divergence at the price of one ray where one ray is enough.

    Every pulse's central ray is cast first. A pulse gets its sub-rays (the same
    sub-rays, cast the same way, as ``beam_sampling="full"``) only where its footprint
    can straddle an edge: a neighbour within ``k`` steps (``k`` from the beam's
    half-angle over the angular step) missed while it hit, or hit while it missed, or hit
    another part label, or hit a point farther than :data:`ADAPTIVE_PLANE_TOL_M` from the
    plane of this pulse's triangle (another surface in front or behind); or its range is
    near a range limit. Elsewhere every sub-ray would hit the same plane: the pulse keeps
    its central hit as one return of full energy, which differs from the full model's
    energy-weighted range by the beam's first moment on that plane (microns; the manual,
    docs/validation.md, states the measured agreement).

    Work goes column by column so that neighbours are known: each block of columns is
    cast with a halo of ``k`` columns on each side (cast again by the next block).
    """

    def __init__(
        self,
        caster: Caster,
        spec: ScannerSpec,
        plan: StationPlan,
        tables: RayTables,
        station_index: int,
    ) -> None:
        self.caster, self.spec, self.tables = caster, spec, tables
        self.grid, self.thin, self.o, self.t0 = plan.grid, plan.thin, plan.o, plan.t0
        self.k_station = station_index
        half = 0.5 * spec.beam_divergence_mrad * 1e-3
        step = math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
        self.k = int(min(3, max(1, math.ceil(1.01 * half / step))))
        self.n_lines = spec.n_elevation
        self.n_az = spec.n_azimuth
        self.full_turn = spec.full_turn
        self.col_offsets = self.grid.offsets
        #: pulses given sub-rays, by the first reason that applied
        self.reasons = {"edge": 0, "surface": 0, "thin": 0, "range_limit": 0}

    def _column_blocks(self, per_chunk: int):
        """Yield (lines, cols, all_lines, all_cols) per block of columns of about
        ``per_chunk`` rays: the block's pulses, then those with the ``k`` neighbouring
        columns either side (its halo) appended."""
        grid, off = self.grid, self.col_offsets
        n_cols = len(grid.columns)
        ca = 0
        while ca < n_cols:
            cb = int(np.searchsorted(off, off[ca] + per_chunk, side="right")) - 1
            cb = max(ca + 1, min(cb, n_cols))
            lines, cols = grid.indices(int(off[ca]), int(off[cb]))
            core_cols = grid.columns[ca:cb]
            near = (core_cols[:, None] + np.arange(-self.k, self.k + 1)[None, :]).reshape(-1)
            if self.full_turn:
                near = near % self.n_az
            hl, hc = self._pulses_of_columns(np.setdiff1d(near, core_cols))
            yield lines, cols, np.concatenate([lines, hl]), np.concatenate([cols, hc])
            ca = cb

    def _renumbered(self, rec: dict, lines: np.ndarray, cols: np.ndarray):
        """(records, lines, cols, directions) of the pulses with returns, renumbered
        0.. in order (records are ordered by pulse)."""
        fresh = np.ones(len(rec["pulse"]), dtype=bool)
        fresh[1:] = rec["pulse"][1:] != rec["pulse"][:-1]
        used = rec["pulse"][fresh]
        rec["pulse"] = np.cumsum(fresh) - 1
        return rec, lines[used], cols[used], self._directions(lines[used], cols[used])

    def _pulses_of_columns(self, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lines, columns) the grid casts in the given columns (any, present or not)."""
        gc = self.grid.columns
        pos = np.searchsorted(gc, columns)
        ok = pos < len(gc)
        ok[ok] = gc[pos[ok]] == columns[ok]
        parts_l, parts_c = [], []
        for p in pos[ok]:
            ln, cl = self.grid.indices(int(self.col_offsets[p]), int(self.col_offsets[p + 1]))
            parts_l.append(ln)
            parts_c.append(cl)
        if not parts_l:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        return np.concatenate(parts_l), np.concatenate(parts_c)

    def _directions(self, lines: np.ndarray, cols: np.ndarray) -> np.ndarray:
        spec = self.spec
        if spec.angular_jitter_sd_deg > 0:
            az, el = pulse_angles(spec, self.k_station, lines, cols)
            return directions(az, el) @ self.tables.rot.T
        return self.tables.directions(lines, cols)

    def _central(self, lines: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Central ray of each pulse: (t, primitive), inf / -1 on a miss."""
        if self.spec.angular_jitter_sd_deg > 0:
            return self.caster.cast(self.o, self._directions(lines, cols))
        t = np.full(len(lines), np.inf)
        prim = np.full(len(lines), -1, dtype=np.int64)
        hidx, th, pr, _ = cast_central(self.caster, self.tables, lines, cols, self.o, self.t0)
        t[hidx], prim[hidx] = th, pr
        return t, prim

    def _neighbour_finder(self, lines: np.ndarray, cols: np.ndarray, key: np.ndarray):
        """A function (columns, lines, ok) -> index of that pulse among ``lines``/``cols``
        or -1: a dense table over the block's columns and lines where it is small, a
        search in the sorted keys otherwise."""
        ucols = np.unique(cols)
        lmin = int(lines.min())
        height = int(lines.max()) - lmin + 1
        if len(ucols) * height <= _DENSE_NEIGHBOUR_CELLS:
            colpos = np.full(self.n_az, -1, dtype=np.int64)
            colpos[ucols] = np.arange(len(ucols))
            table = np.full((len(ucols), height), -1, dtype=np.int32)
            table[colpos[cols], lines - lmin] = np.arange(len(lines), dtype=np.int32)

            def dense(qc: np.ndarray, ql: np.ndarray, ok: np.ndarray) -> np.ndarray:
                pc = colpos[qc]
                row = ql - lmin
                ok = ok & (pc >= 0) & (row >= 0) & (row < height)
                out = table[np.where(ok, pc, 0), np.where(ok, row, 0)].astype(np.int64)
                return np.where(ok, out, -1)

            return dense
        order = np.argsort(key, kind="stable")
        skey = key[order]

        def search(qc: np.ndarray, ql: np.ndarray, ok: np.ndarray) -> np.ndarray:
            qkey = qc * self.n_lines + ql
            pos = np.minimum(np.searchsorted(skey, qkey), len(skey) - 1)
            return np.where(ok & (skey[pos] == qkey), order[pos], -1)

        return search

    def _flags(
        self,
        lines: np.ndarray,
        cols: np.ndarray,
        t: np.ndarray,
        prim: np.ndarray,
        n_core: int,
    ) -> np.ndarray:
        """Which of the first ``n_core`` pulses need sub-rays (see the class notes)."""
        spec, caster = self.spec, self.caster
        key = cols * self.n_lines + lines
        find = self._neighbour_finder(lines, cols, key)
        hit = np.isfinite(t)
        d_hit = np.zeros((len(t), 3))
        d_hit[hit] = self._directions(lines[hit], cols[hit])
        x = self.o + np.where(hit, t, 0.0)[:, None] * d_hit
        cl, cc = lines[:n_core], cols[:n_core]
        hit_p = hit[:n_core]
        pp = np.where(hit_p, prim[:n_core], 0)
        n_p = caster.normal[pp]
        v0_p = caster.v0[pp]
        lab_p = caster.label[pp]
        flag = np.zeros(n_core, dtype=bool)
        surface = np.zeros(n_core, dtype=bool)
        k = self.k
        for dc in range(-k, k + 1):
            qc = cc + dc
            if self.full_turn:
                qc = qc % self.n_az
                col_ok = np.ones(n_core, dtype=bool)
            else:
                col_ok = (qc >= 0) & (qc < self.n_az)
            for dl in range(-k, k + 1):
                if dc == 0 and dl == 0:
                    continue
                ql = cl + dl
                ok = col_ok & (ql >= 0) & (ql < self.n_lines)
                q = find(np.where(ok, qc, 0), ql, ok)
                found = q >= 0
                q = np.maximum(q, 0)
                q_hit = found & hit[q]
                # a hit beside a miss, or a miss beside a hit
                flag |= hit_p != q_hit
                both = hit_p & q_hit
                if both.any():
                    qb = q[both]
                    other = caster.label[prim[qb]] != lab_p[both]
                    dev = np.abs(np.einsum("ij,ij->i", x[qb] - v0_p[both], n_p[both]))
                    surface[both] |= other | (dev > ADAPTIVE_PLANE_TOL_M)
        tc = t[:n_core]
        near_limit = hit_p & (
            (np.abs(tc - spec.max_range_m) < _RANGE_LIMIT_FRACTION * spec.max_range_m)
            | (np.abs(tc - spec.min_range_m) < _RANGE_LIMIT_FRACTION * max(spec.min_range_m, 1.0))
        )
        thin = np.zeros(n_core, dtype=bool)
        if self.thin is None:  # no mask (the whole window, or too large): all are near
            thin[:] = True
        elif len(self.thin):
            ck = key[:n_core]
            pos = np.minimum(np.searchsorted(self.thin, ck), len(self.thin) - 1)
            thin = self.thin[pos] == ck
        st = self.reasons
        st["edge"] += int(flag.sum())
        st["surface"] += int((surface & ~flag).sum())
        st["thin"] += int((thin & ~flag & ~surface).sum())
        st["range_limit"] += int((near_limit & ~flag & ~surface & ~thin).sum())
        return flag | surface | thin | near_limit

    def _plane_range(
        self, d: np.ndarray, prim: np.ndarray, offsets: np.ndarray, weights: np.ndarray
    ) -> np.ndarray:
        """The full model's range of pulses (directions ``d``) whose every sub-ray meets
        the plane of triangle ``prim``: the weighted mean of the sub-rays' ranges to it
        (the sunflower pattern is not symmetric, so this differs from the central range
        by the pattern's first moment times the incidence's tangent)."""
        caster = self.caster
        n = caster.normal[prim]
        num = np.einsum("ij,ij->i", caster.v0[prim] - self.o, n)
        # n · (sub-ray direction), without building the sub-rays: they are
        # (d + tan(u) e1 + tan(v) e2) / sqrt(1 + tan²u + tan²v) on the beam's orthonormal
        # basis (:func:`subray_directions`)
        e1, e2 = beam_basis(d)
        tu, tv = np.tan(offsets[:, 0]), np.tan(offsets[:, 1])
        norm = np.sqrt(1.0 + tu * tu + tv * tv)
        nd = np.einsum("ij,ij->i", n, d)[:, None]
        n1 = np.einsum("ij,ij->i", n, e1)[:, None]
        n2 = np.einsum("ij,ij->i", n, e2)[:, None]
        den = (nd + tu[None, :] * n1 + tv[None, :] * n2) / norm[None, :]
        return (num[:, None] / den) @ weights / weights.sum()

    def blocks(self, per_chunk: int, offsets: np.ndarray, weights: np.ndarray):
        """Yield (records, lines, cols, directions, pulses, rays) per block of columns."""
        spec, caster = self.spec, self.caster
        s = spec.rays_per_pulse
        for lines, cols, all_l, all_c in self._column_blocks(per_chunk):
            n_core = len(lines)
            t, prim = self._central(all_l, all_c)
            n_rays = len(all_l)
            flag = self._flags(all_l, all_c, t, prim, n_core)
            t, prim = t[:n_core], prim[:n_core]
            # pulses whose footprint lies on one plane: one return of full energy, at
            # the range the full model gives there (its sub-rays' weighted mean range)
            single = np.flatnonzero(~flag & in_range(spec, t) & (prim >= 0))
            cand = np.flatnonzero(flag)
            step = max(1, per_chunk // s)
            r_single = np.empty(len(single))
            for a in range(0, len(single), step):
                sp = single[a : a + step]
                r_single[a : a + step] = self._plane_range(
                    self._directions(lines[sp], cols[sp]), prim[sp], offsets, weights
                )
            parts = [
                {
                    "pulse": single,
                    "range_m": r_single,
                    "primitive": prim[single],
                    "direction": None,
                    "energy": np.ones(len(single)),
                    "return_number": np.ones(len(single), np.int64),
                    "number_of_returns": np.ones(len(single), np.int64),
                }
            ]
            for a in range(0, len(cand), step):
                cp = cand[a : a + step]
                d = self._directions(lines[cp], cols[cp])
                sd = subray_directions(d, offsets).reshape(-1, 3)
                ts, ps = caster.cast(self.o, sd)
                n_rays += len(sd)
                rec = beam_returns(spec, ts.reshape(-1, s), ps.reshape(-1, s), sd, weights)
                rec["pulse"] = cp[rec["pulse"]]
                parts.append(rec)
            rec, lu, cu, d_used = self._renumbered(_merge_records(parts), lines, cols)
            yield rec, lu, cu, d_used, n_core, n_rays


def _merge_records(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Concatenate return records and order them by pulse, then return number."""
    out: dict[str, Any] = {}
    n = sum(len(p["pulse"]) for p in parts)
    for name in ("pulse", "range_m", "primitive", "energy", "return_number", "number_of_returns"):
        out[name] = np.concatenate([p[name] for p in parts]) if n else np.empty(0)
    dirs = [p["direction"] for p in parts]
    if any(d is not None for d in dirs):
        out["direction"] = np.concatenate(
            [
                d if d is not None else np.full((len(p["pulse"]), 3), np.nan)
                for p, d in zip(parts, dirs, strict=True)
            ]
        )
    else:
        out["direction"] = None
    order = np.lexsort((out["return_number"], out["pulse"]))
    for name, v in out.items():
        if v is not None:
            out[name] = v[order]
    out["pulse"] = out["pulse"].astype(np.int64)
    out["primitive"] = out["primitive"].astype(np.int64)
    return out


# --------------------------------------------------------------------------------------
# The edge model (``beam_sampling="edge"``): the footprint's coverage from the mesh
# --------------------------------------------------------------------------------------

#: Fine grid of the profile tables (the footprint's unit disc, offsets -1 to 1).
_TABLE_POINTS = 8001
#: Triangles the edge model walks from a pulse's first triangle across its footprint
#: (rings of neighbours) before it gives the pulse its sub-rays instead.
EDGE_WALK_STEPS = 6
#: The same for a miss's walk from the surface its neighbours hit: a sliver whose surface
#: goes on for rings is often beside another surface.
EDGE_MISS_WALK_STEPS = 4
#: Steps across edges a miss beside a hit takes from the triangle its neighbours hit
#: towards its own axis (round a twig to the silhouette) before it decides that surface
#: stays out of its footprint (:func:`treesim.scan._edge_jit.approach`).
EDGE_APPROACH_STEPS = 8
#: A miss whose neighbours' surface comes within this many footprint radii of its axis
#: but that the steps do not bring into its footprint casts :data:`EDGE_RIM_PROBES` rays
#: on its footprint's rim at :data:`EDGE_RIM_RHO` of its radius; one that meets
#: something (a part the surface's edges do not join) gives it the sub-rays. Three
#: rays, a third of a turn apart: measured on the coffee window of
#: ``tests/scan/test_beam_edge.py``, its unmatched intensity 1.46e-5 against 1.41e-5
#: with six and 2.1e-5 with two (the brute force's 3.6e-5); on the aspen one such miss
#: in 200 meets something.
EDGE_PROBE_GAP = 2.0
EDGE_RIM_PROBES = 3
EDGE_RIM_RHO = 0.95
#: Returns carrying less than this share of a pulse's energy are not recorded by the
#: edge model: a sliver the 127-sub-ray reference meets with at most one of its outer
#: sub-rays (each ~0.25 % of the energy), where whether it has a return is the chance of
#: its sampling.
EDGE_MIN_ENERGY = 0.0025
#: Points of the footprint (the sub-ray layout) whose ranges on the walked surface give
#: a cut pulse's range (the surface curves across a footprint: facets of a branch).
EDGE_RANGE_POINTS = 19
#: The same for a footprint its surface covers whole (no silhouette crosses it): the
#: surface's curvature across it alone (facets of a branch).
EDGE_WHOLE_RANGE_POINTS = 12
#: How far (footprint radii) inside a sliver the point that gives its return's triangle
#: lies from the silhouette line nearest the axis (about the spacing of the reference's
#: sub-rays, whose strongest hit there is the return's).
EDGE_SLIVER_INSET = 0.05
#: The same for a sliver of a footprint (a miss's beside a hit, thin geometry's).
EDGE_SLIVER_RANGE_POINTS = 61
#: A neighbour's hit farther than this from the plane of a pulse's triangle may be
#: another surface inside its footprint, one the mesh walk cannot reach.
EDGE_PLANE_TOL_M = 2e-3
#: Rays cast beyond a silhouette line: at the far part's centroid and along the line,
#: in shares of the far part's half-chord there.
EDGE_FAR_PROBES = (0.0, 0.6, -0.6)
#: Points of the footprint on which a corner's covered share, range and uncovered parts
#: are worked out (the walked triangles that hold each; the footprint reference's count).
EDGE_CORNER_POINTS = 127
#: Blocks of columns the edge model works on at a time (threads; each holds its block's
#: arrays): two keep a 2-core machine busy, one block's compiled walks and numpy beside
#: the other's casts (Open3D's own threads).
EDGE_THREADS = 2
#: A station's pulses go in at least this many blocks a thread (blocks no larger than
#: the scan's chunks, ``chunk_rays``): a small scan still keeps every thread busy, and
#: the threads finish together (each block casts a halo of ``k`` columns again).
EDGE_BLOCKS_PER_THREAD = 2
#: Largest neighbourhood (steps each way) the edge model looks in for hits beside a miss.
EDGE_MAX_NEIGHBOUR_STEPS = 8


def _profile_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets ``x`` on [-1, 1] and the footprint's energy ``G(x)`` and first moment
    ``H(x)`` on the side ``X < x`` of a straight line (unit disc, profile
    ``exp(-2 r²)``, total energy 1)."""
    from scipy.special import erf

    x = np.linspace(-1.0, 1.0, _TABLE_POINTS)
    g = (
        np.exp(-2.0 * x * x)
        * math.sqrt(math.pi / 2.0)
        * erf(np.sqrt(2.0 * np.maximum(1.0 - x * x, 0.0)))
    )
    dx = x[1] - x[0]
    cg = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * dx)])
    xg = x * g
    ch = np.concatenate([[0.0], np.cumsum(0.5 * (xg[1:] + xg[:-1]) * dx)])
    return x, cg / cg[-1], ch / cg[-1]


_TABLES: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []


def footprint_share(offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Energy and first moment (along the line's normal, in footprint radii) of the
    part of a pulse's footprint beyond a straight line at signed ``offset`` (footprint
    radii; > 0: the axis is on the near side, so less than half is beyond). The line
    is ``n·u + c = 0`` on the footprint's plane of unit radius with ``n`` its unit
    normal pointing to the near side and ``c`` the offset; the moment is along ``n``.

    Examples
    --------
    >>> import numpy as np
    >>> e, m = footprint_share(np.array([0.0, 1.0, -1.0]))
    >>> np.round(e, 3).tolist()
    [0.5, 0.0, 1.0]
    """
    if not _TABLES:
        _TABLES.append(_profile_tables())
    x, cg, ch = _TABLES[0]
    # the line n·u + c = 0 with the near side n·u + c >= 0: beyond is n·u < -c
    t = -np.asarray(offset, dtype=np.float64)
    return np.interp(t, x, cg, left=0.0, right=1.0), np.interp(t, x, ch, left=0.0, right=0.0)


def edge_neighbours(faces: np.ndarray) -> np.ndarray:
    """The triangle across each edge (i, j) -> (faces[i, j], faces[i, (j + 1) % 3]) of a
    mesh, (n, 3), -1 on a boundary edge (one of them where more than two meet).

    Examples
    --------
    >>> import numpy as np
    >>> edge_neighbours(np.array([[0, 1, 2], [2, 1, 3]])).tolist()
    [[-1, 1, -1], [0, -1, -1]]
    """
    f = np.asarray(faces, dtype=np.int64)
    a = f.reshape(-1)
    b = f[:, [1, 2, 0]].reshape(-1)
    key = np.minimum(a, b) * (int(f.max(initial=0)) + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    i = np.flatnonzero(key[order][1:] == key[order][:-1])
    out = np.full(len(a), -1, dtype=np.int64)
    out[order[i]] = order[i + 1] // 3
    out[order[i + 1]] = order[i] // 3
    return out.reshape(-1, 3)


def _jit():
    """The compiled kernels (:mod:`treesim.scan._edge_jit`), imported on first use: numba
    and its compilation cost only the scans that run the edge model."""
    from . import _edge_jit

    return _edge_jit


def _edge_lines(
    v: np.ndarray, faces: np.ndarray, o: np.ndarray, th: float, frame: tuple, tri: np.ndarray
) -> dict[str, np.ndarray]:
    """Each edge j of triangles ``tri`` seen along pulses ``frame = (d, e1, e2)`` as a
    line ``nu·x + nv·y + c = 0`` on the footprint's plane (unit radius: tangents over
    ``th``), oriented so that the triangle is on its ``>= 0`` side; ``dist``: the
    distance from the axis to the edge's segment (the line's where a corner is behind
    the station); ``sg``: the sign towards the triangle of the normal ``m`` (n, 3, 3) of
    the plane through the station and the edge. Arrays (n, 3) but ``m``. Compiled
    (:func:`treesim.scan._edge_jit.edge_lines`)."""
    d, e1, e2 = (np.ascontiguousarray(x, dtype=np.float64) for x in frame)
    out = _jit().edge_lines(
        v, faces, np.asarray(o, np.float64), float(th), d, e1, e2, np.asarray(tri, np.int64)
    )
    return dict(zip(("nu", "nv", "c", "dist", "sg", "m"), out, strict=True))


def _walk(
    geo: tuple[np.ndarray, np.ndarray, np.ndarray],
    o: np.ndarray,
    th: float,
    frame: tuple,
    start: np.ndarray,
    steps: int = EDGE_WALK_STEPS,
) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray]]:
    """The silhouette edges inside each pulse's footprint, found by walking the mesh
    from the triangle ``start`` (one per pulse, inside its footprint) across every edge
    the footprint meets, as long as the surface goes on (the triangle across the edge
    lies beyond it as seen from the station). An edge with no triangle across it, or
    whose neighbour folds back behind it, is a silhouette edge. ``geo``: vertices,
    faces, :func:`edge_neighbours`. Returns the silhouette lines (``pulse``, ``nu``,
    ``nv``, ``c`` as :func:`_edge_lines`, the surface on the ``>= 0`` side, ``tri``),
    which pulses the walk did not finish within ``steps`` rings, and the
    triangles walked (``pulse``, ``tri`` and their edge lines ``nu``, ``nv``, ``c``
    (n, 3)), for :func:`_surface_range`: pulse by pulse, ring after ring (compiled:
    :func:`treesim.scan._edge_jit.walk`)."""
    v, faces, nbr = geo
    d, e1, e2 = (np.ascontiguousarray(x, dtype=np.float64) for x in frame)
    out = _jit().walk(
        v,
        faces,
        nbr,
        np.asarray(o, np.float64),
        float(th),
        d,
        e1,
        e2,
        np.asarray(start, np.int64),
        int(steps),
    )
    lines = dict(zip(("pulse", "nu", "nv", "c", "tri"), out[:5], strict=True))
    idx, edges = out[6], out[7]
    trail = {"pulse": idx[0], "tri": idx[1], "nu": edges[:, 0], "nv": edges[:, 1]}
    trail.update(c=edges[:, 2], packed=(idx, edges))
    return lines, out[5], trail


def _surface_range(
    geo: tuple[np.ndarray, np.ndarray, np.ndarray],
    frame: tuple,
    th: float,
    trail: dict[str, np.ndarray],
    pulses: np.ndarray,
    quad: tuple[np.ndarray, np.ndarray],
    cut: tuple[np.ndarray, ...] | None = None,
    full: bool = False,
    extent: bool = False,
) -> Any:
    """The walked surface's range over the footprints of ``pulses`` (indices into the
    walk's pulses, frames ``frame``): the weighted mean range of the footprint points
    ``quad`` (points (k, 2) on the unit footprint, their weights (k,)) that fall inside
    the triangles the walk crossed (``trail``, :func:`_walk`), the nearest where several
    hold one; nan where none does. ``geo``: vertices, faces, the station. ``cut``: the
    silhouette lines of the covered parts (``pulse``, index into ``pulses``; ``nu``,
    ``nv``, ``c``), points beyond any of which are not looked at (a sliver's are few).
    ``full``: also the covered weight and the uncovered parts (10 columns a pulse, see
    :func:`treesim.scan._edge_jit.surface_range`); ``extent``: also the nearest and
    farthest range of the covered points ((n, 2), nan where none), before them.
    Compiled."""
    v, faces, o = geo
    d, e1, e2 = (np.ascontiguousarray(x, dtype=np.float64) for x in frame)
    idx, edges = trail["packed"]
    if cut is None:
        lines, at = np.empty((0, 3)), np.empty(0, np.int64)
    else:
        order = np.argsort(cut[0], kind="stable")
        lines = np.stack([x[order] for x in cut[1:]], axis=1)
        at = np.searchsorted(cut[0][order], np.arange(len(pulses) + 1))
    pts, wts = quad
    rng, ext, covered = _jit().surface_range(
        v,
        faces,
        np.asarray(o, np.float64),
        float(th),
        d,
        e1,
        e2,
        idx,
        edges,
        np.asarray(pulses, np.int64),
        np.ascontiguousarray(pts, np.float64),
        np.asarray(wts, np.float64),
        lines,
        at,
        bool(full),
    )
    head = (rng, ext) if extent else (rng,)
    out = (*head, covered) if full else head
    return out if len(out) > 1 else out[0]


def _coverage(n: int, lines: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The surface's share of each of ``n`` pulses' footprints bounded by its silhouette
    ``lines`` (:func:`_walk`): ``ok`` where at most two lines cut it without crossing
    inside it and their far sides do not overlap; ``energy`` and ``centroid`` (x, y on
    the unit footprint) of the covered part; per line its far side's ``far_energy`` and
    ``far_centroid``."""
    p = lines["pulse"]
    count = np.bincount(p, minlength=n)
    ok = count <= 2
    nu, nv, c = lines["nu"], lines["nv"], lines["c"]
    eb, hm = footprint_share(c)
    far_c = np.stack([nu, nv], axis=1) * (hm / np.maximum(eb, 1e-300))[:, None]
    energy = 1.0 - np.bincount(p, weights=eb, minlength=n)
    mom = -np.stack(
        [
            np.bincount(p, weights=nu * hm, minlength=n),
            np.bincount(p, weights=nv * hm, minlength=n),
        ],
        axis=1,
    )
    two = np.flatnonzero(count[p] == 2)
    if len(two):
        order = two[np.argsort(p[two], kind="stable")]
        a, b = order[0::2], order[1::2]
        det = nu[a] * nv[b] - nv[a] * nu[b]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (-c[a] * nv[b] + c[b] * nv[a]) / det
            y = (-nu[a] * c[b] + nu[b] * c[a]) / det
        crossing = np.abs(det) > 1e-12
        crossing &= x * x + y * y < 1.0
        # nested far sides: the deepest point of one far side lies beyond the other
        nested = (nu[b] * -nu[a] + nv[b] * -nv[a] + c[b] < 0) | (
            nu[a] * -nu[b] + nv[a] * -nv[b] + c[a] < 0
        )
        ok[p[a][crossing | nested]] = False
    ok &= energy > -1e-9
    cen = mom / np.maximum(energy, 1e-300)[:, None]
    return {
        "ok": ok,
        "energy": np.maximum(energy, 0.0),
        "centroid": cen,
        "far_energy": eb,
        "far_centroid": far_c,
    }


#: Samples along a thin triangle's longest side are this many angular steps apart (each
#: sample's box of pulses widened by half of it).
EDGE_STRAY_SPACING_STEPS = 1.0
#: Most samples (about 80 bytes each) a station's thin-geometry index holds; beyond, the
#: edge model does without it (thin geometry between central rays is not seen).
_STRAY_MAX_SAMPLES = 1 << 23


def _stray_samples(tri: np.ndarray, spec: ScannerSpec, reach: float) -> dict[str, np.ndarray]:
    """Boxes of pulses whose footprint thin triangles may reach: each triangle of ``tri``
    (n, 3, 3; the scanner frame, the station at the origin) is sampled along its longest
    side (:data:`EDGE_STRAY_SPACING_STEPS` apart), and each sample's box is widened by
    the triangle's angular width, half the sample spacing (and a tenth more, the chord's
    samples being uneven on the arc) and ``reach`` (the footprint's angular radius plus
    pointing slack). Returns per box its first and last ``line`` and ``col`` (``col``
    unwrapped: taken modulo the turn, or past the end back to the start of the field of
    view, by the caller) and ``tri`` (index into ``tri``); empty where a box would reach
    a pole or the samples would be more than :data:`_STRAY_MAX_SAMPLES`. The samples are
    compiled (:func:`treesim.scan._edge_jit.stray_samples`)."""
    keys = ("l_lo", "l_hi", "c_lo", "c_hi", "tri", "line", "col", "rl", "rc")
    if not len(tri):
        return {k: np.empty(0, np.int64) for k in keys}
    u = tri / np.linalg.norm(tri, axis=2, keepdims=True)
    ua, ub, length, width = seen_sides(u)
    vres = math.radians(spec.vertical_resolution_deg)
    hres = math.radians(spec.horizontal_resolution_deg)
    # a chord's samples: evenly spaced on the chord, at most the spacing apart on the arc
    n_s = np.ceil(1.2 * length / (EDGE_STRAY_SPACING_STEPS * min(vres, hres))).astype(np.int64) + 1
    if int(n_s.sum()) > _STRAY_MAX_SAMPLES:  # its memory: thin geometry stays unseen
        return {k: np.empty(0, np.int64) for k in keys}
    fov0 = (math.radians(spec.vertical_fov_deg[0]), math.radians(spec.horizontal_fov_deg[0]))
    ints, floats, ok = _jit().stray_samples(
        (ua, ub, length, width), n_s, float(reach), (vres, hres), fov0
    )
    if not ok:  # a box reaches a pole
        return {k: np.empty(0, np.int64) for k in keys}
    return dict(zip(keys, (*ints, *floats), strict=True))


def _pairs_within(pairs: tuple[np.ndarray, np.ndarray], members: np.ndarray) -> tuple:
    """The (pulse, triangle) ``pairs`` whose pulse is one of ``members`` (distinct pulse
    indices), their pulse given as its index into ``members``."""
    rep, tri = pairs
    n = int(max(rep.max(initial=-1), members.max(initial=-1))) + 1
    pos = np.full(n, -1, dtype=np.int64)
    pos[members] = np.arange(len(members))
    at = pos[rep]
    s = np.flatnonzero(at >= 0)
    return at[s], tri[s]


class EdgeBeam(AdaptiveBeam):
    """The footprint at the price of about one ray a pulse (``beam_sampling="edge"``).

    Every pulse's central ray is cast (column blocks with a halo of neighbours, as
    :class:`AdaptiveBeam`). Then, from the mesh itself:

    * a hit whose footprint lies inside its triangle (the axis farther than the
      footprint's radius from each edge, seen from the station) is one return of full
      energy at the central range;
    * otherwise the mesh is walked from that triangle across every edge the footprint
      meets (:func:`_walk`) while the surface goes on; the edges where it ends (a
      boundary, or a neighbour folding back: the silhouette) are straight lines across
      the footprint. With one, or two that do not cross inside it, the surface's share of
      the energy is analytic (:func:`footprint_share`, the profile integrated once into
      a table) and its range the walked surface's over the footprint points it covers;
      beyond each line :data:`EDGE_FAR_PROBES` rays find what lies behind, each group of
      them within the range resolution a return with its share of the far part's energy
      (:meth:`_far_probes`); parts merge as the footprint's sub-rays would chain them,
      within the range resolution of the covered surface's span of ranges
      (:func:`group_returns`' ``extent``);
    * a miss beside a hit (a neighbour within ``k`` steps hit) starts the same walk
      from the triangles its neighbours hit that overlap its footprint, or from where
      up to :data:`EDGE_APPROACH_STEPS` steps across their edges towards its axis lead
      (round a twig to its silhouette; :func:`treesim.scan._edge_jit.approach`), and
      the covered share is the sliver's energy; its range is the walked surface's over
      :data:`EDGE_SLIVER_RANGE_POINTS` points of the footprint. Where a sliver was
      found, and where that surface comes near (:data:`EDGE_PROBE_GAP`) but is not
      reached, it casts :data:`EDGE_RIM_PROBES` rays on the footprint's rim: one that
      meets something beyond the sliver's span of ranges (another surface no
      neighbour's central ray met: a stem behind the twigs they hit), or anything where
      no sliver was found (a part the edges do not join), gives it the sub-rays;
    * thin geometry (the occupancy cull's rule,
      :func:`~treesim.scan.occupancy.thin_triangles`: twigs thinner than
      :data:`~treesim.scan.occupancy.THIN_STEPS` angular steps, leaves), which every
      central ray of a pulse's neighbourhood can miss, is indexed once per station by
      the pulses whose footprint it may reach (:func:`_stray_samples`): a miss that
      nothing else settled walks from the nearest thin triangle its footprint overlaps
      (a twig between central rays), and a hit with thin geometry in front of it inside
      its footprint gets the sub-rays;
    * a hit whose walk ends in a corner (two silhouette lines crossing inside the
      footprint, or more than two; :meth:`_corners`) takes its covered share and range
      from the walked triangles that hold each of :data:`EDGE_CORNER_POINTS` points of
      the footprint, and what lies beyond from one ray in each third of the footprint,
      at its uncovered point nearest the third's uncovered centroid;
    * returns under :data:`EDGE_MIN_ENERGY` of the pulse's energy are not recorded;
    * pulses the walk cannot settle (probes on several surfaces or disagreeing with
      the walk, a walk longer than :data:`EDGE_WALK_STEPS` rings,
      ranges near a range limit), hits with a neighbour's hit in front of their
      triangle's plane (another surface may hide part of the footprint), misses whose
      neighbours' hits lie farther apart than the range resolution (two echoes may
      share the footprint), and thin geometry that the walk from one thin triangle does
      not account for get the sub-rays, as ``beam_sampling="full"`` does.

    Not seen: a thick surface in front of part of a footprint whose central ray, and
    its neighbours', meet a triangle behind it; what lies beyond a silhouette where the
    far probes miss it (a twig behind, a few counts of intensity).

    The walk, the edge lines, the surface's range, the neighbour test and the
    thin-geometry index are compiled loops (:mod:`treesim.scan._edge_jit`, numba;
    :func:`treesim.scan.warmup.warm_edge_model` compiles them
    ahead), and :data:`EDGE_THREADS` blocks of
    columns are worked on at a time (:meth:`blocks`).
    """

    def __init__(self, caster, spec, plan, tables, station_index) -> None:  # noqa: D107
        super().__init__(caster, spec, plan, tables, station_index)
        # every neighbour a footprint reaches (a miss's sliver needs a hit to be seen)
        step = math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
        half = 0.5 * spec.beam_divergence_mrad * 1e-3
        self.k = int(min(EDGE_MAX_NEIGHBOUR_STEPS, max(1, math.ceil(1.01 * half / step))))
        self.th = math.tan(0.5 * spec.beam_divergence_mrad * 1e-3)
        faces = np.ascontiguousarray(caster.faces, dtype=np.int64)
        v = np.ascontiguousarray(caster.v, dtype=np.float64)
        self.geo = (v, faces, edge_neighbours(faces))
        q_off, q_w = subray_pattern(EDGE_RANGE_POINTS, 2.0e3)
        #: the points (unit footprint) and weights of the walked surface's mean range
        self.quad = (q_off, q_w)
        #: a denser one for slivers (a miss beside a hit, thin geometry): a few of the
        #: points of the walked surface's mean range fall in a narrow part
        self.quad_sliver = subray_pattern(EDGE_SLIVER_RANGE_POINTS, 2.0e3)
        #: a denser one for corners (the covered share and the uncovered parts too)
        self.quad_corner = subray_pattern(EDGE_CORNER_POINTS, 2.0e3)
        #: and a sparser one where the surface covers the footprint whole
        self.quad_whole = subray_pattern(EDGE_WHOLE_RANGE_POINTS, 2.0e3)
        ang = 2.0 * math.pi * np.arange(EDGE_RIM_PROBES) / EDGE_RIM_PROBES
        #: the rim probes' points (unit footprint): :meth:`_beside`
        self.rim = EDGE_RIM_RHO * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        self.reasons = {
            "corner or several surfaces": 0,
            "another surface beside": 0,
            "range_limit": 0,
        }
        self.reasons["thin geometry"] = 0
        self._stray: dict[str, np.ndarray] | None = None
        self._facing_all: np.ndarray | None = None
        self.station = plan.station

    def _ray(self, frame: tuple, xy: np.ndarray) -> np.ndarray:
        """Unit directions at footprint-plane points ``xy`` (unit radius) of pulses."""
        d, e1, e2 = frame
        w = d + self.th * (xy[:, :1] * e1 + xy[:, 1:2] * e2)
        return w / np.linalg.norm(w, axis=1, keepdims=True)

    def _plane_range(self, w: np.ndarray, prim: np.ndarray) -> np.ndarray:  # type: ignore[override]
        """Range along unit directions ``w`` to the plane of triangle ``prim``."""
        n = self.caster.normal[prim]
        num = np.einsum("ij,ij->i", self.caster.v0[prim] - self.o, n)
        return num / np.einsum("ij,ij->i", n, w)

    def _surface_range(
        self,
        frame: tuple,
        trail: dict,
        pulses: np.ndarray,
        sliver: dict | None = None,
        quad: tuple[np.ndarray, np.ndarray] | None = None,
        extent: bool = False,
    ) -> Any:
        """:func:`_surface_range` of walked ``pulses`` (frames ``frame``, walk ``trail``),
        on the points ``quad`` (default: :data:`EDGE_RANGE_POINTS`; ``extent``: also the
        covered points' nearest and farthest range); where the covered part is a sliver,
        on the denser points that lie inside its silhouette lines ``sliver``
        (:func:`_walk`)."""
        geo = (self.geo[0], self.geo[1], self.o)
        if sliver is None:
            q = quad or self.quad
            return _surface_range(geo, frame, self.th, trail, pulses, q, extent=extent)
        pos = np.full(len(frame[0]), -1, dtype=np.int64)
        pos[pulses] = np.arange(len(pulses))
        at = pos[sliver["pulse"]]
        s = at >= 0
        cut = (at[s], sliver["nu"][s], sliver["nv"][s], sliver["c"][s])
        return _surface_range(
            geo, frame, self.th, trail, pulses, self.quad_sliver, cut, extent=extent
        )

    def _lookup(self, lines: np.ndarray, cols: np.ndarray) -> tuple:
        """How the compiled loops find a pulse of the block (``lines``, ``cols``) by its
        column and line (:func:`treesim.scan._edge_jit._search`): a dense table over the
        block's columns and lines where it holds at most
        :data:`_DENSE_NEIGHBOUR_CELLS`, else the sorted keys."""
        ucols = np.unique(cols)
        lmin = int(lines.min()) if len(lines) else 0
        height = int(lines.max()) - lmin + 1 if len(lines) else 0
        none = np.empty(0, np.int64)
        if len(ucols) * height <= _DENSE_NEIGHBOUR_CELLS:
            colpos = np.full(self.n_az, -1, dtype=np.int64)
            colpos[ucols] = np.arange(len(ucols))
            table = np.full((len(ucols), height), -1, dtype=np.int32)  # 4 B a cell
            table[colpos[cols], lines - lmin] = np.arange(len(lines), dtype=np.int32)
            return table, colpos, lmin, none, none
        key = cols * self.n_lines + lines
        order = np.argsort(key, kind="stable")
        return np.empty((0, 0), np.int32), none, 0, key[order], order

    def _grid(self) -> tuple[int, int, bool]:
        """(columns, lines, a full turn) of the station's grid, for the compiled loops."""
        return int(self.n_az), int(self.n_lines), bool(self.full_turn)

    def _neighbours(self, lines, cols, t, prim, n_core, lookup) -> tuple:
        """Core pulses whose central ray missed while a neighbour within k steps hit
        (with the nearest and farthest such hit of each and the first
        :data:`treesim.scan._edge_jit.BESIDE` distinct triangles of those hits, nearest
        ring first: ``beside``, (lo, hi, tri)), and
        core hits with a neighbour hit in front of the plane of their triangle (on
        the station's side) by more than :data:`EDGE_PLANE_TOL_M`: another surface may
        hide part of the footprint. A neighbour's hit behind the plane cannot: where the
        walk finds the footprint covered by the pulse's surface, whatever lies behind
        that surface is hidden (the other side of a branch, the ground beyond it).
        Compiled (:func:`treesim.scan._edge_jit.neighbours`); ``lookup``:
        :meth:`_lookup` of the block."""
        hits = np.flatnonzero(np.isfinite(t))
        at = np.full(len(t), -1, dtype=np.int64)
        at[hits] = np.arange(len(hits))
        d_hit = self._directions(lines[hits], cols[hits])
        normal = self.caster.normal
        if isinstance(normal, np.ndarray):  # held: each core hit's row is its triangle
            n_at = prim[:n_core]
        else:  # gathered: the core hits' normals, in order
            hc = hits[hits < n_core]
            normal, n_at = normal[prim[hc]], at[:n_core]
        near, lo, hi, jump, tri = _jit().neighbours(
            lines,
            cols,
            n_core,
            t,
            (d_hit, at, prim),
            (self.geo[0], self.geo[1], normal, n_at),
            self.o,
            self._grid(),
            lookup,
            self.k,
            EDGE_PLANE_TOL_M,
        )
        mc = np.flatnonzero(near)
        return mc, jump, (lo[mc], hi[mc], tri)

    def _cast(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cast rays ``w`` from the station: (range, triangle), inf / -1 where nothing
        the scanner records (a miss, or out of its range limits)."""
        t, p = self.caster.cast(self.o, w)
        keep = in_range(self.spec, t) & (p >= 0)
        return np.where(keep, t, np.inf), np.where(keep, p, -1)

    def _hits(self, frame: tuple, t: np.ndarray, prim: np.ndarray, jump: np.ndarray):
        """Parts (ranges, energies, triangles; (m, 1 + 2 k): the hit surface, then the k
        groups of far rays (:meth:`_far_probes`) beyond each of up to two silhouette
        lines) and their spans of ranges (:func:`group_returns`' ``extent``) of pulses
        (frames ``frame``: :meth:`_frame`; central ranges ``t``, triangles ``prim``) whose
        central ray hit, and the indices of those left to the sub-rays; plus the rays
        cast and how many were left for another surface beside. ``jump``: pulses with a
        neighbour on another surface, left to the sub-rays unless a silhouette edge inside
        their footprint accounts for it."""
        m = len(t)
        g = _edge_lines(self.geo[0], self.geo[1], self.o, self.th, frame, prim)
        inside = (g["c"] >= 1.0).all(axis=1)
        cut = np.flatnonzero(~inside)
        sub = tuple(x[cut] for x in frame)
        lines, unres, trail = _walk(self.geo, self.o, self.th, sub, prim[cut])
        cov = _coverage(len(cut), lines)
        alone = jump[cut]
        fb = unres | ~cov["ok"] | alone
        n_beside = int(alone.sum() + (jump & inside).sum())
        n_far = len(EDGE_FAR_PROBES)
        tt = np.full((m, 1 + 2 * n_far), np.inf)
        ww = np.zeros((m, 1 + 2 * n_far))
        pp = np.full((m, 1 + 2 * n_far), -1, dtype=np.int64)
        tt[:, 0], ww[:, 0], pp[:, 0] = t, 1.0, prim
        gi = np.flatnonzero(~fb)
        good = cut[gi]
        ww[good, 0] = cov["energy"][gi]
        w0 = self._ray(tuple(x[gi] for x in sub), cov["centroid"][gi])
        # a footprint the surface covers whole: its curvature alone, on fewer points
        whole = np.bincount(lines["pulse"], minlength=len(cut))[gi] == 0
        r_quad = np.empty(len(gi))
        r_quad[whole] = self._surface_range(sub, trail, gi[whole], quad=self.quad_whole)
        r_quad[~whole], ext = self._surface_range(sub, trail, gi[~whole], extent=True)
        tt[good, 0] = np.where(np.isfinite(r_quad), r_quad, self._plane_range(w0, prim[good]))
        corners = self._corners(sub, trail, cut, prim[cut], (unres, cov["ok"], alone))
        lp = lines["pulse"]
        li = np.flatnonzero(~fb[lp] & (cov["far_energy"] >= EDGE_MIN_ENERGY))
        li = li[np.argsort(lp[li], kind="stable")]
        rank = np.arange(len(li)) - np.searchsorted(lp[li], lp[li], side="left")
        tf, pf, share, f_span = self._far_probes(tuple(x[lp[li]] for x in sub), lines, cov, li)
        rows = cut[lp[li]]
        col = 1 + rank[:, None] * n_far + np.arange(n_far)[None, :]
        ww[rows[:, None], col] = cov["far_energy"][li][:, None] * share
        tt[rows[:, None], col], pp[rows[:, None], col] = tf, pf
        # each part's span of ranges where parts lie beyond a silhouette: the covered
        # part's (a surface seen at a slant) and each far group's: parts within the range
        # resolution of one another's ends merge, as the sub-rays that meet the ranges
        # between would chain them
        span = (tt.copy(), tt.copy())
        cut_rows = good[~whole]
        span[0][cut_rows, 0] = np.fmin(ext[:, 0], tt[cut_rows, 0])
        span[1][cut_rows, 0] = np.fmax(ext[:, 1], tt[cut_rows, 0])
        span[0][rows[:, None], col], span[1][rows[:, None], col] = f_span
        settled = np.zeros(len(cut), dtype=bool)
        settled[corners[0]] = True
        fall = np.concatenate([cut[fb & ~settled], np.flatnonzero(jump & inside)])
        n_rays = len(li) * len(EDGE_FAR_PROBES) + corners[-1]
        corners = (cut[corners[0]], *corners[1:-1])
        return (tt, ww, pp, span), fall, n_rays, n_beside, corners

    def _corners(self, sub, trail, cut, prim, why):
        """Walked hits (``cut``; frames ``sub``, walks ``trail``) whose silhouette the
        analytic share cannot take (more than two lines, or two crossing inside the
        footprint), their walk finished and no other surface beside (``why``: unfinished,
        analytic ok, another surface beside; ``prim``: the central rays' triangles, the
        covered part's): the covered share and range from the
        walked triangles that hold each of :data:`EDGE_CORNER_POINTS` points of the
        footprint; what lies beyond from one ray in each third of the footprint, at its
        uncovered point nearest the third's uncovered centroid, with that third's
        uncovered share (a third under :data:`EDGE_MIN_ENERGY` casts no ray). Returns the
        pulses settled (indices into ``cut``; the rest keep the sub-rays), their parts
        (ranges, energies, triangles; (n, 4): the surface, then each third's) and the
        rays cast."""
        unres, ok, alone = why
        corner = np.flatnonzero(~unres & ~ok & ~alone)
        geo = (self.geo[0], self.geo[1], self.o)
        r, ext, cv = _surface_range(
            geo, sub, self.th, trail, corner, self.quad_corner, full=True, extent=True
        )
        good = np.isfinite(r) & (cv[:, 0] >= EDGE_MIN_ENERGY)
        corner, r, cv, ext = corner[good], r[good], cv[good], ext[good]
        tt = np.full((len(corner), 4), np.inf)
        ww = np.zeros((len(corner), 4))
        pp = np.full((len(corner), 4), -1, dtype=np.int64)
        tt[:, 0], ww[:, 0], pp[:, 0] = r, cv[:, 0], prim[corner]
        for sec in range(3):
            ww[:, 1 + sec] = cv[:, 1 + 3 * sec]
            s = np.flatnonzero(ww[:, 1 + sec] >= EDGE_MIN_ENERGY)  # a third worth a ray
            w = self._ray(tuple(x[corner[s]] for x in sub), cv[s, 2 + 3 * sec : 4 + 3 * sec])
            tt[s, 1 + sec], pp[s, 1 + sec] = self._cast(w)
        span = (tt.copy(), tt.copy())
        span[0][:, 0], span[1][:, 0] = np.fmin(ext[:, 0], r), np.fmax(ext[:, 1], r)
        rays = int(np.count_nonzero(ww[:, 1:] >= EDGE_MIN_ENERGY))
        return corner, tt, ww, pp, span, rays

    def _far_probes(self, frame, lines, cov, li):
        """What lies beyond silhouette lines ``li``: rays at the far part's centroid
        and beside it along the line (:data:`EDGE_FAR_PROBES`), grouped as sub-rays would
        be (each within the range resolution of the next). Per line (n, k) each: first
        the group of the central ray that hits (else the first), at that ray's range and
        triangle, then each other group at its nearest ray's; the share of the rays in
        each group (the share of the far part's energy it carries; 0 past the groups),
        and each group's nearest and farthest range."""
        nu, nv = lines["nu"][li], lines["nv"][li]
        fc = cov["far_centroid"][li]
        depth = fc[:, 0] * nu + fc[:, 1] * nv
        half_chord = np.sqrt(np.maximum(1.0 - depth * depth, 0.0))
        along = np.stack([-nv, nu], axis=1)
        n, k = len(li), len(EDGE_FAR_PROBES)
        pts = fc[:, None, :] + np.asarray(EDGE_FAR_PROBES)[None, :, None] * (
            half_chord[:, None, None] * along[:, None, :]
        )
        rep = np.repeat(np.arange(n), k)
        tf, pf = self._cast(self._ray(tuple(x[rep] for x in frame), pts.reshape(-1, 2)))
        tf, pf = tf.reshape(n, k), pf.reshape(n, k)
        fin = np.isfinite(tf)
        rows = np.arange(n)
        pick = np.argmax(fin, axis=1)
        order = np.argsort(tf, axis=1, kind="stable")
        ts = np.take_along_axis(tf, order, axis=1)
        link = np.zeros(ts.shape, dtype=np.int64)
        with np.errstate(invalid="ignore"):
            link[:, 1:] = np.cumsum(np.diff(ts, axis=1) > self.spec.range_resolution_m, axis=1)
        group = np.empty_like(link)
        np.put_along_axis(group, order, link, axis=1)  # each ray's group
        main = group[rows, pick]
        # groups renumbered: the main one first, the others in range order
        rank = np.where(group == main[:, None], 0, group + (group < main[:, None]))
        rank = np.where(fin, rank, k)
        t_g = np.full((n, k), np.inf)
        p_g = np.full((n, k), -1, dtype=np.int64)
        share = np.zeros((n, k))
        lo, hi = np.full((n, k), np.inf), np.full((n, k), -np.inf)
        for j in range(k - 1, -1, -1):  # the nearest ray of a group last (the main: pick)
            ok = np.flatnonzero(fin[rows, order[:, j]])
            r = rank[ok, order[ok, j]]
            t_g[ok, r], p_g[ok, r] = ts[ok, j], pf[ok, order[ok, j]]
            share[ok, r] += 1.0 / k
            lo[ok, r] = np.minimum(lo[ok, r], ts[ok, j])
            hi[ok, r] = np.maximum(hi[ok, r], ts[ok, j])
        has = fin.any(axis=1)
        t_g[has, 0], p_g[has, 0] = tf[has, pick[has]], pf[has, pick[has]]
        return t_g, p_g, share, (lo, np.where(np.isfinite(t_g), hi, np.inf))

    def _stray_boxes(self) -> dict[str, np.ndarray]:
        """This station's boxes of pulses thin triangles may reach
        (:func:`_stray_samples`), once: of open parts (leaves) and of the sides of thin
        closed parts (twigs) that face the station."""
        if self._stray is None:
            from .occupancy import thin_triangles

            spec, caster = self.spec, self.caster
            tri = ((caster.v - self.o) @ self.station.rotation)[self.geo[1]]
            centroid = tri.mean(axis=1)
            dist = np.linalg.norm(centroid, axis=1)
            thick = caster.thickness_m()
            # a closed part's normals point outwards (``thickness_m`` looks inwards): of
            # a twig, only the sides that face the station
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            facing = np.einsum("ij,ij->i", n, centroid) < 0
            thin = thin_triangles(tri, thick, spec) & (facing | ~np.isfinite(thick))
            idx = np.flatnonzero(thin & (dist <= spec.max_range_m * 1.01))
            jitter = 6.0 * math.sqrt(2.0) * math.radians(spec.angular_jitter_sd_deg)
            reach = 1.01 * math.atan(self.th) + jitter + 1e-6
            box = _stray_samples(tri[idx], spec, reach)
            box["tri"] = idx[box["tri"]]  # a triangle's boxes together, in its order
            self._stray = box
            #: each thin triangle's farthest corner from the station (0 for the others:
            #: only thin ones are looked up)
            far = np.zeros(len(tri))
            far[idx] = np.linalg.norm(tri[idx], axis=2).max(axis=1)
            self._stray["far"] = far
        return self._stray

    def _stray_pairs(self, lines: np.ndarray, cols: np.ndarray, n_core: int, lookup):
        """(pulse, triangle) pairs: the block's core pulses (the first ``n_core`` of
        ``lines``, ``cols``; ``lookup``: :meth:`_lookup` of the block) whose footprint a
        thin triangle may reach (:meth:`_stray_boxes`), each once. Compiled
        (:func:`treesim.scan._edge_jit.box_pulses`)."""
        box = self._stray_boxes()
        none = np.empty(0, np.int64)
        if not n_core or not len(box["tri"]):
            return none, none
        n_az, cols = self.n_az, cols[:n_core]
        want = np.zeros(n_az + 1, dtype=bool)
        want[cols] = True
        cum = np.concatenate([[0], np.cumsum(want[:n_az])])
        c_lo, c_hi = box["c_lo"], box["c_hi"]
        if self.full_turn:
            lo, hi = c_lo % n_az, c_hi % n_az
            wrap = hi < lo
            any_ = np.where(wrap, cum[-1] - cum[lo] + cum[hi + 1], cum[hi + 1] - cum[lo]) > 0
        else:
            lo, hi = np.clip(c_lo, 0, n_az - 1), np.clip(c_hi, 0, n_az - 1)
            any_ = (cum[hi + 1] - cum[lo] > 0) & (c_hi >= 0) & (c_lo < n_az)
        ints = tuple(box[k] for k in ("l_lo", "l_hi", "c_lo", "c_hi", "tri"))
        floats = tuple(np.asarray(box[k], np.float64) for k in ("line", "col", "rl", "rc"))
        return _jit().box_pulses((ints, floats), np.flatnonzero(any_), n_core, self._grid(), lookup)

    def _frame(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pulse directions ``d`` and their :func:`beam_basis` (compiled, the same
        numbers): (d, e1, e2)."""
        d = np.ascontiguousarray(d, dtype=np.float64)
        return (d, *_jit().basis(d))

    def _overlapping(self, frame: tuple, rep: np.ndarray, tri: np.ndarray):
        """The pairs (``rep``: index into pulses of frames ``frame``, triangle ``tri``; each
        pair once, as :meth:`_stray_pairs` gives them) whose triangle overlaps the pulse's
        footprint (as seen; compiled: :func:`treesim.scan._edge_jit.overlaps`), in their
        order."""
        v, faces, _ = self.geo
        over = _jit().overlaps(v, faces, self.o, self.th, *frame, rep, tri)
        return rep[over], tri[over]

    def _thin_in_front(self, pairs, hit: np.ndarray, frame: tuple, t: np.ndarray):
        """Which hits (core indices ``hit``, frames ``frame``, ranges ``t``) have thin
        geometry in front of their surface inside their footprint (``pairs``:
        :meth:`_stray_pairs`): a twig before a branch that the central ray passed by."""
        k, tri = _pairs_within(pairs, hit)
        s = np.flatnonzero(self._stray["far"][tri] < t[k] - EDGE_PLANE_TOL_M)
        rep, _ = self._overlapping(frame, k[s], tri[s])
        front = np.zeros(len(hit), dtype=bool)
        front[rep] = True
        return front

    def _sliver(self, sub, gi, start, lines, trail, cov):
        """The range and triangle of the covered part of walked footprints ``gi`` (a
        sliver: frames ``sub``, walks from ``start`` with silhouette ``lines``, ``trail``
        and coverage ``cov``): the range over the sliver's points; the triangle (its
        incidence, its label) the walked one that holds the sliver's point nearest the
        axis (:data:`EDGE_SLIVER_INSET` inside), else that of its silhouette line with
        the largest offset; and the nearest and farthest range of the sliver's points."""
        lp = lines["pulse"]
        order = np.lexsort((-lines["c"], lp))
        first = np.ones(len(order), dtype=bool)
        first[1:] = lp[order][1:] != lp[order][:-1]
        tri = start.copy()
        tri[lp[order][first]] = lines["tri"][order][first]
        # the sliver's point nearest the axis, just inside the line that parts them: the
        # walked triangle there, where one holds it (an edge-on face is passed over)
        order = np.lexsort((lines["c"], lp))
        first = np.ones(len(order), dtype=bool)
        first[1:] = lp[order][1:] != lp[order][:-1]
        o1 = order[first]
        n1 = np.stack([lines["nu"][o1], lines["nv"][o1]], axis=1)
        q = np.zeros((len(start), 2))
        q[lp[o1]] = (EDGE_SLIVER_INSET - np.minimum(lines["c"][o1], 0.0))[:, None] * n1
        tp = trail["pulse"]
        val = trail["nu"] * q[tp, :1] + trail["nv"] * q[tp, 1:2] + trail["c"]
        under = np.flatnonzero((val >= -1e-9).all(axis=1))
        tri[tp[under]] = trail["tri"][under]
        cen = cov["centroid"]
        w = self._ray(tuple(x[gi] for x in sub), cen[gi])
        r_quad, ext = self._surface_range(sub, trail, gi, sliver=lines, extent=True)
        rng = np.where(np.isfinite(r_quad), r_quad, self._plane_range(w, tri[gi]))
        return rng, tri[gi], (np.fmin(ext[:, 0], rng), np.fmax(ext[:, 1], rng))

    def _facing(self, tri: np.ndarray) -> np.ndarray:
        """Whether triangles ``tri`` turn their front (their normal's side) to the
        station (worked out for every triangle once per station, a byte each)."""
        if self._facing_all is None:
            v, faces, _ = self.geo
            a0 = v[faces[:, 0]] - self.o
            nrm = np.cross(v[faces[:, 1]] - self.o - a0, v[faces[:, 2]] - self.o - a0)
            self._facing_all = np.einsum("ij,ij->i", nrm, a0) < 0
        return self._facing_all[tri]

    def _unwalked(self, idx, start, trail, thin, frame: tuple | None = None):
        """Which walks (pulses ``idx``, from triangles ``start``, their ``trail``:
        :func:`_walk`) leave out a thin triangle that overlaps their footprint (``thin``:
        pairs (pulse, triangle), overlapping or, given the pulses' frames ``frame``, to be
        tested: :meth:`_overlapping`) and faces the station as the start does: another
        twig inside the footprint."""
        k, tri = _pairs_within(thin, idx)
        out = np.zeros(len(idx), dtype=bool)
        if not len(k):
            return out
        n_t = len(self.geo[1])
        walked = np.sort(trail["pulse"] * n_t + trail["tri"])
        same = self._facing(tri) == self._facing(start)[k]
        ck = k * n_t + tri
        at = np.minimum(np.searchsorted(walked, ck), max(len(walked) - 1, 0))
        seen = (walked[at] == ck) if len(walked) else np.zeros(len(ck), dtype=bool)
        k, tri = k[same & ~seen], tri[same & ~seen]
        if frame is not None:  # the few left out overlap the footprint?
            k, _ = self._overlapping(tuple(x[idx] for x in frame), k, tri)
        out[k] = True
        return out

    def _strays(
        self,
        frame: tuple,
        rep: np.ndarray,
        tri: np.ndarray,
        *,
        steps: int = EDGE_WALK_STEPS,
        thin: tuple | None = None,
        tested: bool = False,
    ):
        """The sliver of the footprints of pulses (frames ``frame``: :meth:`_frame`) whose
        central ray missed, from candidate triangles ``tri`` of each (``rep``: their index;
        ``tested``: all known to overlap the footprint): thin geometry
        (:meth:`_stray_pairs`) where the neighbours saw nothing, or the surface the
        neighbours hit (:meth:`_beside`). The nearest candidate that the footprint
        overlaps starts the walk (at most ``steps`` rings), and its surface's share is
        the return. (range, energy, triangle) per pulse (energy 0: none), the
        indices of those left to the sub-rays (a walk that does not settle, or that
        leaves out another candidate facing the station as its start does, or a thin
        triangle of ``thin`` (pairs as ``rep``, ``tri``, to be tested) that overlaps the
        footprint), and the nearest and farthest range of each sliver's points."""
        m = len(frame[0])
        r, e, p = np.full(m, np.inf), np.zeros(m), np.full(m, -1, dtype=np.int64)
        span = (np.full(m, np.inf), np.full(m, -np.inf))
        if not len(rep):
            return (r, e, p), np.empty(0, np.int64), span
        if not tested:
            rep, tri = self._overlapping(frame, rep, tri)
        v, faces, _ = self.geo
        a = v[faces[tri]] - self.o
        near = np.linalg.norm(a.mean(axis=1), axis=1)
        order = np.lexsort((tri, near, rep))
        first = np.ones(len(order), dtype=bool)
        first[1:] = rep[order][1:] != rep[order][:-1]
        idx = rep[order][first]
        start = tri[order][first]
        sub = tuple(x[idx] for x in frame)
        lines, unres, trail = _walk(self.geo, self.o, self.th, sub, start, steps=steps)
        cov = _coverage(len(idx), lines)
        lp = lines["pulse"]
        # the central ray missed: the footprint's centre lies beyond some silhouette line
        centre_out = np.zeros(len(idx), dtype=bool)
        np.logical_or.at(centre_out, lp, lines["c"] < 0.0)
        fb = unres | ~cov["ok"] | ~centre_out
        fb |= self._unwalked(idx, start, trail, (rep, tri))
        if thin is not None:
            fb |= self._unwalked(idx, start, trail, thin, frame)
        gi = np.flatnonzero(~fb)
        r[idx[gi]], p[idx[gi]], (span[0][idx[gi]], span[1][idx[gi]]) = self._sliver(
            sub, gi, start, lines, trail, cov
        )
        e[idx[gi]] = cov["energy"][gi]
        return (r, e, p), idx[fb], span

    def _beside(self, frame, cand, lo, hi, thin):
        """The slivers of misses beside a hit (frames ``frame``; ``cand``, ``lo``, ``hi``:
        the triangles their neighbours hit and those hits' nearest and farthest range,
        within the range resolution): that surface reached
        (:func:`treesim.scan._edge_jit.approach`) and walked (:meth:`_strays`; ``thin``:
        :meth:`_stray_pairs` of these misses). (range, energy, triangle) per miss (energy
        0: none), the indices of those left to the sub-rays and the rays cast: a sliver
        on another surface than the neighbours' hits; a sliver where one of
        :data:`EDGE_RIM_PROBES` rays on the footprint's rim meets something farther than
        :data:`EDGE_PLANE_TOL_M` outside the sliver's span of ranges (another surface in
        the footprint that no neighbour's central ray met: a stem behind the twigs they
        hit, a branch's end); and a miss where that surface came within
        :data:`EDGE_PROBE_GAP` footprint radii but the steps across its edges did not
        bring it into the footprint and one of those rays meets something (another part
        the edges do not join: a QSM's next cylinder)."""
        v, faces, nbr = self.geo
        over, reach, gap = _jit().approach(
            v, faces, nbr, self.o, self.th, *frame, cand, EDGE_APPROACH_STEPS
        )
        start = np.concatenate([cand, reach], axis=1)
        over = np.concatenate([over, reach >= 0], axis=1)
        rep = np.repeat(np.arange(len(cand)), start.shape[1])
        (r, e, p), fb, span = self._strays(
            frame,
            rep[over.ravel()],
            start[over],
            steps=EDGE_MISS_WALK_STEPS,
            thin=thin,
            tested=True,
        )
        res = self.spec.range_resolution_m
        other = np.isfinite(r) & (e > 0) & ((r < lo - res) | (r > hi + res))
        # the rim rays: where the surface came near but was not reached, and where a
        # sliver was found (a ray beyond the sliver's span of ranges meets another surface)
        q = np.flatnonzero((~over.any(axis=1) & (gap < EDGE_PROBE_GAP)) | ((e > 0) & ~other))
        k = len(self.rim)
        sub = tuple(x[np.repeat(q, k)] for x in frame)
        t_rim, _ = self._cast(self._ray(sub, np.tile(self.rim, (len(q), 1))))
        t_rim = t_rim.reshape(-1, k)
        tol = EDGE_PLANE_TOL_M
        off = (t_rim < span[0][q, None] - tol) | (t_rim > span[1][q, None] + tol)
        probed = q[(np.isfinite(t_rim) & np.where((e[q] > 0)[:, None], off, True)).any(axis=1)]
        fb = np.union1d(fb, np.concatenate([np.flatnonzero(other), probed]))
        e[fb] = 0.0
        return (r, e, p), fb, len(q) * k

    def _miss_parts(self, lines, cols, t, miss, n_core, pairs, beside):
        """Returns of the block's core pulses whose central ray missed: the slivers of
        those beside a hit (``beside``: their neighbours' nearest and farthest hits and
        the triangles of those hits; :meth:`_neighbours`) from the surface their
        neighbours hit (:meth:`_beside`), then thin geometry (:meth:`_strays`,
        ``pairs``: :meth:`_stray_pairs`) in the footprints of the rest; the records, the
        pulses left to the sub-rays (beside a hit, thin) and the rays cast."""
        spec = self.spec
        lo, hi, cand = beside
        # a miss whose neighbours' hits lie farther apart than the range resolution
        # may have two echoes in its footprint: the sub-rays
        apart = hi - lo > spec.range_resolution_m
        near = np.flatnonzero(~apart)
        f_near = self._frame(self._directions(lines[miss[near]], cols[miss[near]]))
        r, e, p = np.full(len(miss), np.inf), np.zeros(len(miss)), np.full(len(miss), -1)
        (r[near], e[near], p[near]), fb, n_probe = self._beside(
            f_near, cand[near], lo[near], hi[near], _pairs_within(pairs, miss[near])
        )
        fb = np.union1d(near[fb], np.flatnonzero(apart))
        e[fb] = 0.0
        seen = np.zeros(n_core, dtype=bool)
        seen[miss[fb]] = True
        found = (e >= EDGE_MIN_ENERGY) & in_range(spec, r)
        seen[miss[found]] = True
        # the rest of the misses that thin geometry may reach
        near_thin = np.zeros(n_core, dtype=bool)
        near_thin[pairs[0]] = True
        empty = np.flatnonzero(~np.isfinite(t[:n_core]) & ~seen & near_thin)
        f_empty = self._frame(self._directions(lines[empty], cols[empty]))
        (r2, e2, p2), fb2, _ = self._strays(f_empty, *_pairs_within(pairs, empty))
        parts = []
        for pulses, rr, ee, pp in ((miss, r, e, p), (empty, r2, e2, p2)):
            ok = np.flatnonzero((ee >= EDGE_MIN_ENERGY) & in_range(spec, rr))
            one = np.ones(len(ok), dtype=np.int64)
            parts.append(
                {
                    "pulse": pulses[ok],
                    "range_m": rr[ok],
                    "primitive": pp[ok],
                    "direction": None,
                    "energy": ee[ok],
                    "return_number": one,
                    "number_of_returns": one,
                }
            )
        return parts, [miss[fb], empty[fb2]], n_probe

    def _resolved(self, lines, cols, t, prim, n_core):
        """What the edge model settles of one block's core pulses (central rays cast):
        the return records, the pulses left to the sub-rays, the rays cast beyond the
        central ones and how many pulses were left to the sub-rays for each reason."""
        spec = self.spec
        tc, pc = t[:n_core], prim[:n_core]
        hit = np.flatnonzero(in_range(spec, tc) & (pc >= 0))
        lim = _RANGE_LIMIT_FRACTION
        near_limit = (np.abs(tc[hit] - spec.max_range_m) < lim * spec.max_range_m) | (
            np.abs(tc[hit] - spec.min_range_m) < lim * max(spec.min_range_m, 1.0)
        )
        fall = [hit[near_limit]]
        hit = hit[~near_limit]
        lookup = self._lookup(lines, cols)
        miss, jump, beside = self._neighbours(lines, cols, t, prim, n_core, lookup)
        f_hit = self._frame(self._directions(lines[hit], cols[hit]))
        pairs = self._stray_pairs(lines, cols, n_core, lookup)
        front = self._thin_in_front(pairs, hit, f_hit, tc[hit])
        fall.append(hit[front])
        hit, f_hit = hit[~front], tuple(x[~front] for x in f_hit)
        (tt, ww, pp, span), fb, n_rays, n_beside, corners = self._hits(
            f_hit, tc[hit], pc[hit], jump[hit]
        )
        fall.append(hit[fb])
        keep = (ww >= EDGE_MIN_ENERGY) & in_range(spec, tt) & (pp >= 0)
        keep[fb] = False
        keep[corners[0]] = False
        rows, ct, cw, cp, c_span = corners
        ck = (cw >= EDGE_MIN_ENERGY) & in_range(spec, ct) & (cp >= 0)
        parts = [
            self._grouped(hit, (tt, ww, pp), keep, span),
            self._grouped(hit[rows], (ct, cw, cp), ck, c_span),
        ]
        miss_parts, miss_fall, n_probe = self._miss_parts(
            lines, cols, t, miss, n_core, pairs, beside
        )
        cand = np.sort(np.concatenate(fall + miss_fall))
        n_thin = int(front.sum()) + len(miss_fall[1])
        n_limit = int(near_limit.sum())
        tally = {
            "corner or several surfaces": len(cand) - n_limit - n_beside - n_thin,
            "another surface beside": n_beside,
            "range_limit": n_limit,
            "thin geometry": n_thin,
        }
        return parts + miss_parts, cand, n_rays + n_probe, tally

    def _grouped(self, pulses, part, keep, span) -> dict[str, np.ndarray]:
        """Return records of ``pulses`` from their parts (``part``: ranges, energies,
        triangles, each (m, c); ``keep``: the parts recorded; ``span``: each part's
        nearest and farthest range), echoes within the range resolution merged
        (:func:`group_returns`)."""
        spec = self.spec
        tt, ww, pp = part
        g = group_returns(np.where(keep, tt, np.inf), ww, spec.range_resolution_m, span)
        sel = select_returns(g, spec.return_mode)
        return {
            "pulse": pulses[g["pulse"][sel]],
            "range_m": g["range_m"][sel],
            "primitive": pp[g["pulse"][sel], g["subray"][sel]],
            "direction": None,
            "energy": g["energy"][sel],
            "return_number": g["return_number"][sel],
            "number_of_returns": g["number_of_returns"][sel],
        }

    def _block(self, block: tuple, offsets: np.ndarray, weights: np.ndarray, step: int):
        """One block of columns (:meth:`_column_blocks`): its central rays cast, what the
        edge model settles (:meth:`_resolved`), the rest given the sub-rays. Returns
        what :meth:`blocks` yields, and the block's count of pulses given sub-rays by
        reason."""
        lines, cols, all_l, all_c = block
        n_core = len(lines)
        t, prim = self._central(all_l, all_c)
        parts, cand, n_rays, tally = self._resolved(all_l, all_c, t, prim, n_core)
        spec, s = self.spec, len(weights)
        for a in range(0, len(cand), step):
            cp = cand[a : a + step]
            d = self._directions(all_l[cp], all_c[cp])
            sd = subray_directions(d, offsets).reshape(-1, 3)
            ts, ps = self.caster.cast(self.o, sd)
            n_rays += len(sd)
            rec = beam_returns(spec, ts.reshape(-1, s), ps.reshape(-1, s), sd, weights)
            rec["pulse"] = cp[rec["pulse"]]
            parts.append(rec)
        rec, lu, cu, d_used = self._renumbered(_merge_records(parts), lines, cols)
        return (rec, lu, cu, d_used, n_core, n_rays + len(all_l)), tally

    def blocks(self, per_chunk: int, offsets: np.ndarray, weights: np.ndarray):
        """Yield (records, lines, cols, directions, pulses, rays) per block of columns,
        in order; :data:`EDGE_THREADS` blocks are worked on at a time (the compiled
        loops and numpy's larger steps let go of the interpreter's lock: one block's
        walks run beside the other's casts), so that up to that many blocks' arrays are
        held at once. The answers do not depend on it."""
        step = max(1, per_chunk // self.spec.rays_per_pulse)
        # what every block reads, made before they start
        _jit()
        self._stray_boxes()
        self._facing(np.empty(0, dtype=np.int64))
        with ThreadPoolExecutor(max(1, EDGE_THREADS)) as pool:
            pending: deque = deque()
            size = -(-self.grid.n_pulses // (EDGE_BLOCKS_PER_THREAD * EDGE_THREADS))
            for block in self._column_blocks(max(1, min(per_chunk, size))):
                pending.append(pool.submit(self._block, block, offsets, weights, step))
                if len(pending) >= EDGE_THREADS:
                    yield self._counted(pending.popleft().result())
            while pending:
                yield self._counted(pending.popleft().result())

    def _counted(self, done: tuple) -> tuple:
        """A block's answer (:meth:`_block`), its counts added to :attr:`reasons`."""
        out, tally = done
        for k, n in tally.items():
            self.reasons[k] += n
        return out
