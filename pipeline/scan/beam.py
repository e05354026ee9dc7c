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
from typing import Any

import numpy as np

from ..params import ScannerSpec
from .caster import Caster, RayTables, cast_central
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
    t: np.ndarray, weights: np.ndarray, range_resolution_m: float
) -> dict[str, np.ndarray]:
    """Group sub-ray ranges of each pulse into returns.

    Parameters
    ----------
    t : (p, s) float
        Sub-ray ranges, ``inf`` where the sub-ray missed or fell outside the range limits.
    weights : (s,) float
        Sub-ray energy weights (sum 1).
    range_resolution_m : float
        Echoes closer than this merge.

    Returns
    -------
    dict with (r,) arrays: ``pulse`` (index into p), ``range_m``, ``energy``,
    ``return_number`` (1-based, by range), ``number_of_returns``, ``subray`` (index of
    the strongest sub-ray of the return).
    """
    p, s = t.shape
    order = np.argsort(t, axis=1, kind="stable")
    ts = np.take_along_axis(t, order, axis=1)
    valid = np.isfinite(ts)
    new = np.ones_like(ts, dtype=bool)
    with np.errstate(invalid="ignore"):
        new[:, 1:] = np.diff(ts, axis=1) > range_resolution_m
    cid = np.cumsum(new, axis=1) - 1
    pulse = np.broadcast_to(np.arange(p)[:, None], (p, s))[valid]
    cl = cid[valid]
    tv = ts[valid]
    sub = order[valid]
    w = weights[sub]
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
        spec, grid, caster = self.spec, self.grid, self.caster
        s = spec.rays_per_pulse
        off = self.col_offsets
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
            halo = np.setdiff1d(near, core_cols)
            hl, hc = self._pulses_of_columns(halo)
            n_core = len(lines)
            all_l = np.concatenate([lines, hl])
            all_c = np.concatenate([cols, hc])
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
            rec = _merge_records(parts)
            # pulses with returns, renumbered (records are ordered by pulse)
            fresh = np.ones(len(rec["pulse"]), dtype=bool)
            fresh[1:] = rec["pulse"][1:] != rec["pulse"][:-1]
            used = rec["pulse"][fresh]
            rec["pulse"] = np.cumsum(fresh) - 1
            d_used = self._directions(lines[used], cols[used])
            yield rec, lines[used], cols[used], d_used, n_core, n_rays
            ca = cb


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
