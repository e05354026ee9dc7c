"""The beam's contract: a pulse's returns with its energy integrated over its footprint.

A beam model (:mod:`treesim.scan.beam`) samples each pulse's footprint, the cone of
half-angle ``beam_divergence_mrad / 2`` weighted by the Gaussian profile
``exp(-2 (rho / half_angle)^2)`` truncated at the cone's edge. Any finite sampling
(the brute force's ``subrays``, adaptive sampling, the shared model) is an
approximation of the integral over that footprint. The **reference** is the same
footprint sampled densely: :data:`REFERENCE_SUBRAYS` sub-rays on the model's own
sunflower layout with the model's own weights (:func:`reference_spec`), every pulse.
Its own sampling error is measured by comparing it with a denser one (the benchmark
prints it).

:func:`footprint_errors` compares a simulated cloud with the reference's cloud of the
same scan, pulse by pulse (pulses are keyed by station, scan line and scan column).
Returns are matched within a pulse: where both have the same number of returns, by
return number (returns are numbered in range order); otherwise each return of the one
with fewer is paired with the unpaired return of the other nearest in range (closest
pairs first), and the rest stay unmatched. The figures:

``pulses``
    pulses with a return in either cloud;
``count_mismatch``
    the share of those whose number of returns differs;
``multi_share`` / ``multi_share_ref`` / ``multi_share_error``
    the share of pulses with two or more returns in the model, in the reference, and
    the absolute difference;
``range_mean_m``, ``range_p99_m``, ``range_max_m``
    absolute range differences of matched returns;
``position_mean_m``, ``position_p99_m``
    distances between matched returns' points;
``intensity_mean``, ``intensity_p99``
    absolute intensity differences of matched returns (counts of 65535);
``unmatched_intensity``
    the intensity of unmatched returns (either side) over the reference's total
    intensity: energy put on a return the reference does not have, or lost.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..params import ScannerSpec

#: Sub-rays of the reference footprint (the issue's contract: >= 127).
REFERENCE_SUBRAYS = 127
#: The error figures, in the order reports print them, and whether larger is worse.
ERROR_NAMES = (
    "count_mismatch",
    "multi_share_error",
    "range_mean_m",
    "range_p99_m",
    "position_mean_m",
    "position_p99_m",
    "intensity_mean",
    "intensity_p99",
    "unmatched_intensity",
)


def reference_spec(spec: ScannerSpec, subrays: int = REFERENCE_SUBRAYS) -> ScannerSpec:
    """The reference beam of ``spec``: the same footprint (divergence, profile, range
    resolution, return mode) sampled by ``subrays`` sub-rays for every pulse.

    Examples
    --------
    >>> from treesim.params import ScannerSpec
    >>> ref = reference_spec(ScannerSpec(beam_divergence_mrad=0.3, subrays=19))
    >>> ref.subrays, ref.beam_sampling
    (127, 'full')
    """
    return spec.with_(subrays=int(subrays), beam_sampling="full")


def window_spec(
    spec: ScannerSpec, azimuth_deg: tuple[float, float], elevation_deg: tuple[float, float]
) -> ScannerSpec:
    """``spec`` swept over a window only (the reference of a large scan on part of it):
    the field of view snapped outward to ``spec``'s pulse grid and clipped to its
    elevation range. Pulses keep their directions (to rounding) but their scan columns
    and lines count from the window's corner, so compare scans of one window only.

    Examples
    --------
    >>> from treesim.params import ScannerSpec
    >>> spec = ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5)
    >>> w = window_spec(spec, (10.2, 11.1), (0.1, 0.9))
    >>> w.horizontal_fov_deg, w.vertical_fov_deg
    ((10.0, 11.5), (0.0, 1.0))
    """
    h0, v0 = spec.horizontal_fov_deg[0], spec.vertical_fov_deg[0]
    rh, rv = spec.horizontal_resolution_deg, spec.vertical_resolution_deg
    a0, a1 = (float(a) for a in azimuth_deg)
    if a0 < h0:
        a0, a1 = a0 + 360.0, a1 + 360.0
    c0, c1 = math.floor((a0 - h0) / rh + 1e-9), math.ceil((a1 - h0) / rh - 1e-9)
    e0 = max(float(elevation_deg[0]), v0)
    e1 = min(float(elevation_deg[1]), spec.vertical_fov_deg[1])
    l0, l1 = math.floor((e0 - v0) / rv + 1e-9), math.ceil((e1 - v0) / rv - 1e-9)
    return spec.with_(
        horizontal_fov_deg=(h0 + c0 * rh, h0 + max(c1, c0 + 1) * rh),
        vertical_fov_deg=(v0 + l0 * rv, min(v0 + max(l1, l0 + 1) * rv, 90.0)),
    )


def pulse_keys(fields: dict[str, np.ndarray]) -> np.ndarray:
    """One int64 key per point: its pulse (station, scan column, scan line)."""
    return (
        fields["station"].astype(np.int64) << 50
        | fields["scan_column"].astype(np.int64) << 25
        | fields["scan_line"].astype(np.int64)
    )


def returns_per_pulse(
    keys_a: np.ndarray, keys_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pulse with a return in either cloud (sorted keys, :func:`pulse_keys`) and
    its number of returns in each.

    Examples
    --------
    >>> keys, na, nb = returns_per_pulse(np.array([5, 5, 7]), np.array([7, 9]))
    >>> keys.tolist(), na.tolist(), nb.tolist()
    ([5, 7, 9], [2, 1, 0], [0, 1, 1])
    """
    ua, ca = np.unique(keys_a, return_counts=True)
    ub, cb = np.unique(keys_b, return_counts=True)
    keys = np.union1d(ua, ub)
    na = np.zeros(len(keys), np.int64)
    nb = np.zeros(len(keys), np.int64)
    na[np.searchsorted(keys, ua)] = ca
    nb[np.searchsorted(keys, ub)] = cb
    return keys, na, nb


def _by_pulse(keys: np.ndarray, rn: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Order (pulse, return number), the pulses and each pulse's first index and count."""
    order = np.lexsort((rn, keys))
    k = keys[order]
    uniq, first, count = np.unique(k, return_index=True, return_counts=True)
    return order, uniq, np.stack([first, count], axis=1)


def match_returns(
    keys_a: np.ndarray,
    range_a: np.ndarray,
    rn_a: np.ndarray,
    keys_b: np.ndarray,
    range_b: np.ndarray,
    rn_b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (ia, ib) of matched returns of two clouds (indices into each).

    Within a pulse: by return number where both have as many returns, else nearest
    ranges first (see the module notes). Pulses present in one cloud only match none.

    Examples
    --------
    >>> import numpy as np
    >>> ia, ib = match_returns(
    ...     np.array([7, 7]), np.array([10.0, 12.0]), np.array([1, 2]),
    ...     np.array([7]), np.array([11.9]), np.array([1]))
    >>> ia.tolist(), ib.tolist()
    ([1], [0])
    """
    oa, ua, sa = _by_pulse(keys_a, rn_a)
    ob, ub, sb = _by_pulse(keys_b, rn_b)
    common, pa, pb = np.intersect1d(ua, ub, return_indices=True)
    fa, ca = sa[pa, 0], sa[pa, 1]
    fb, cb = sb[pb, 0], sb[pb, 1]
    same = ca == cb
    # equal counts: pair return j with return j
    n = ca[same]
    rep = np.repeat(np.arange(len(n)), n)
    j = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    ia = [oa[fa[same][rep] + j]]
    ib = [ob[fb[same][rep] + j]]
    for f1, c1, f2, c2 in zip(fa[~same], ca[~same], fb[~same], cb[~same], strict=True):
        i1, i2 = oa[f1 : f1 + c1], ob[f2 : f2 + c2]
        d = np.abs(range_a[i1][:, None] - range_b[i2][None, :])
        used1, used2 = set(), set()
        for flat in np.argsort(d, axis=None, kind="stable"):
            r, c = divmod(int(flat), len(i2))
            if r in used1 or c in used2:
                continue
            used1.add(r)
            used2.add(c)
            ia.append(i1[r : r + 1])
            ib.append(i2[c : c + 1])
            if len(used1) == min(c1, c2):
                break
    return np.concatenate(ia).astype(np.int64), np.concatenate(ib).astype(np.int64)


def partial_pulses(cloud: Any, spec: ScannerSpec) -> int:
    """How many pulses of a scan (``return_mode="all"``) split their footprint: two or
    more returns, or one that carries less than the pulse's whole energy (part of the
    footprint missed). Energies are read back from the intensity proxy (reflectance of
    the label × cosine of incidence × energy × (10 m / range)², 16-bit), so a return
    counts as whole within two intensity counts.

    Examples
    --------
    >>> ref = scan(scene, stations, reference_spec(spec))  # doctest: +SKIP
    >>> partial_pulses(ref.cloud, spec) / ref.station_stats[0].pulses_cast  # doctest: +SKIP
    0.13
    """
    from ..cloud import LABEL_CODES

    f = cloud.fields
    reflect = np.full(max(LABEL_CODES.values()) + 1, spec.reflectance.get("other", 0.5))
    for name, code in LABEL_CODES.items():
        reflect[code] = spec.reflectance.get(name, spec.reflectance.get("other", 0.5))
    rng = f["range_m"].astype(np.float64)
    scale = (
        reflect[f["label"]]
        * np.cos(np.radians(f["incidence_deg"].astype(np.float64)))
        * np.minimum(1.0, (10.0 / np.maximum(rng, 1e-9)) ** 2)
        * 65535.0
    )
    keys = pulse_keys(f)
    uniq, inv, count = np.unique(keys, return_inverse=True, return_counts=True)
    energy = np.bincount(inv, weights=f["intensity"] / np.maximum(scale, 1e-12))
    slack = np.bincount(inv, weights=2.0 / np.maximum(scale, 1e-12))
    return int(((count >= 2) | (energy < 1.0 - slack)).sum())


def footprint_errors(model: Any, reference: Any) -> dict[str, float]:
    """How far a simulated cloud lies from the footprint reference, pulse by pulse.

    Parameters
    ----------
    model, reference : Cloud
        Two scans of the same scene, stations and pulse grid (``return_mode="all"``
        for the figures on multiple returns), with the scan's per-point fields.

    Returns
    -------
    dict of str -> float
        The figures the module notes define (:data:`ERROR_NAMES` and ``pulses``).

    Examples
    --------
    >>> ref = scan(scene, stations, reference_spec(spec))  # doctest: +SKIP
    >>> fast = scan(scene, stations, spec)  # doctest: +SKIP
    >>> footprint_errors(fast.cloud, ref.cloud)["count_mismatch"]  # doctest: +SKIP
    0.004
    """
    fa, fb = model.fields, reference.fields
    ka, kb = pulse_keys(fa), pulse_keys(fb)
    ra, rb = fa["range_m"].astype(np.float64), fb["range_m"].astype(np.float64)
    ia, ib = match_returns(ka, ra, fa["return_number"], kb, rb, fb["return_number"])
    keys, na, nb = returns_per_pulse(ka, kb)
    n_p = max(len(keys), 1)
    dr = np.abs(ra[ia] - rb[ib])
    dp = np.linalg.norm(model.points[ia] - reference.points[ib], axis=1)
    inta = fa["intensity"].astype(np.float64)
    intb = fb["intensity"].astype(np.float64)
    di = np.abs(inta[ia] - intb[ib])
    lost = inta.sum() - inta[ia].sum() + intb.sum() - intb[ib].sum()

    def q(x: np.ndarray, p: float) -> float:
        return float(np.quantile(x, p)) if len(x) else 0.0

    return {
        "pulses": float(len(keys)),
        "count_mismatch": float((na != nb).sum() / n_p),
        "multi_share": float((na >= 2).sum() / n_p),
        "multi_share_ref": float((nb >= 2).sum() / n_p),
        "multi_share_error": float(abs((na >= 2).sum() - (nb >= 2).sum()) / n_p),
        "range_mean_m": float(dr.mean()) if len(dr) else 0.0,
        "range_p99_m": q(dr, 0.99),
        "range_max_m": float(dr.max()) if len(dr) else 0.0,
        "position_mean_m": float(dp.mean()) if len(dp) else 0.0,
        "position_p99_m": q(dp, 0.99),
        "intensity_mean": float(di.mean()) if len(di) else 0.0,
        "intensity_p99": q(di, 0.99),
        "unmatched_intensity": float(lost / max(intb.sum(), 1.0)),
    }


__all__ = [
    "ERROR_NAMES",
    "REFERENCE_SUBRAYS",
    "footprint_errors",
    "match_returns",
    "partial_pulses",
    "pulse_keys",
    "reference_spec",
    "returns_per_pulse",
    "window_spec",
]
