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
"""

from __future__ import annotations

import math

import numpy as np


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
