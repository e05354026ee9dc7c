"""The occlusion profile: coverage and point density by height, per station and together.

A comparison's coverage is one number; where a tree is occluded is a question of height
(the crown hides itself, the lower stem is seen from every station). The profile cuts the
reference into horizontal slices of ``bin_m`` from its lowest point up and gives, per slice:

* ``reference_points``: reference samples (mesh) or points (cloud) in the slice;
* ``coverage``: the share of them within τ of the cloud, for all stations together
  (``"all"``, from the comparison's completeness distances) and for each station's points
  alone (``"S0"``, ``"S1"``, ...: each station's own k-d tree, queried up to τ);
* ``cloud_points``: points of the cloud in the slice, all and per station;
* ``density_per_m2`` (mesh references): those points over the slice's reference surface
  area (the area's share is its share of the area-uniform samples).

Everything is computed from what a report reads (:class:`~treesim.report.data.ReportData`),
so a report drawn again from the saved files gives the same profile.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..geometry import kdtree
from .data import ReportData

__all__ = ["TARGET_BINS", "auto_bin_m", "occlusion_profile"]

#: About this many slices when the slice height is not given.
TARGET_BINS = 20


def auto_bin_m(height_m: float, target: int = TARGET_BINS) -> float:
    """A round slice height (1, 2, 2.5 or 5 × 10^k m) giving at most about ``target``
    slices over ``height_m``."""
    if not math.isfinite(height_m) or height_m <= 0:
        return 1.0
    raw = height_m / target
    k = math.floor(math.log10(raw))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        step = m * 10.0**k
        if step >= raw * (1 - 1e-9):
            return float(f"{step:.6g}")
    return float(10.0 ** (k + 1))  # pragma: no cover (10 × 10^k always qualifies)


class _CellGrid:
    """Cubic cells small enough that two points in one cell are closer than τ (side
    τ/√3, less a margin far above float rounding), and the cell of each reference point.

    A reference point that shares its cell with a station's point is within τ of that
    station without a k-d tree query; only the others are queried (about half of a
    tree's samples on the bundled tree), and the answer is the same.
    """

    def __init__(self, side: float, lo: np.ndarray, dims: tuple[int, int, int], keys: np.ndarray):
        self.side, self.lo, self.dims, self.keys = side, lo, dims, keys

    @classmethod
    def of(cls, ref_c: np.ndarray, tau: float) -> _CellGrid | None:
        """The grid over ``ref_c``'s box; None where τ is not positive or the cells would
        not fit one int64 index (then every point is queried)."""
        if not (math.isfinite(tau) and tau > 0) or len(ref_c) == 0:
            return None
        side = tau / math.sqrt(3.0) * (1.0 - 1e-6)
        cell = np.floor(ref_c / side)
        lo = cell.min(axis=0)
        dims = tuple(int(n) for n in cell.max(axis=0) - lo + 1)
        if not all(math.isfinite(n) for n in dims) or math.prod(dims) >= 2**62:
            return None  # pragma: no cover (a reference light-years across at a τ of µm)
        keys = np.ravel_multi_index((cell - lo).astype(np.int64).T, dims)
        return cls(side, lo, dims, keys)

    def shared(self, pts: np.ndarray) -> np.ndarray:
        """Whether each reference point's cell holds one of ``pts`` (same frame)."""
        cell = np.floor(pts / self.side) - self.lo
        inside = np.all((cell >= 0) & (cell < np.asarray(self.dims)), axis=1)
        held = np.ravel_multi_index(cell[inside].astype(np.int64).T, self.dims)
        return np.isin(self.keys, held)


def _within(
    ref_c: np.ndarray,
    pts: np.ndarray,
    tau: float,
    grid: _CellGrid | None,
    workers: int,
    known: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Whether each of ``ref_c`` is within ``tau`` of one of ``pts``: what ``known``
    (``(known, within)`` masks) says, else a shared cell of ``grid`` says yes at once; a
    k-d tree query on ``pts`` answers the others."""
    if known is not None:
        near = known[1].copy()
        rest = np.flatnonzero(~known[0])
    else:
        near = np.zeros(len(ref_c), dtype=bool) if grid is None else grid.shared(pts)
        rest = np.flatnonzero(~near)
    if len(rest):
        d, _ = kdtree(pts).query(
            ref_c[rest], k=1, distance_upper_bound=tau * (1 + 1e-12), workers=workers
        )
        near[rest] = d <= tau
    return near


def occlusion_profile(
    data: ReportData, *, bin_m: float | None = None, workers: int = -1
) -> dict[str, Any]:
    """Coverage and point density by height slice, per station and all together.

    Parameters
    ----------
    data : ReportData
        A comparison's figures and per-point distances (its τ is ``tolerance_m``).
    bin_m : float, optional
        Slice height (m); default :func:`auto_bin_m` of the reference's height.
    workers : int
        Threads of the k-d tree queries (-1: all).

    Returns
    -------
    dict
        ``bin_m``, ``base_z_m`` (the reference's lowest z: heights are above it),
        ``edges_m`` (slice bounds, heights), ``stations`` (names, ``"S0"`` ...),
        ``reference_points`` (per slice), ``coverage`` (name -> per slice, ``None``
        where a slice has no reference), ``cloud_points`` (name -> per slice) and, for a
        mesh reference, ``area_m2`` (per slice) and ``density_per_m2`` (name -> per
        slice, ``None`` where a slice has no surface). Cloud points outside the
        reference's height range fall in the end slices.
    """
    s = data.summary
    tau = float(s["tolerance_m"])
    ref = np.asarray(data.reference_points, dtype=np.float64)
    cloud = np.asarray(data.cloud_points, dtype=np.float64)
    base = float(ref[:, 2].min())
    top = float(ref[:, 2].max())
    step = float(bin_m) if bin_m is not None else auto_bin_m(top - base)
    n_bins = max(1, math.ceil((top - base) / step - 1e-9))
    edges = base + step * np.arange(n_bins + 1)

    def slot(z: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((z - base) / step).astype(np.int64), 0, n_bins - 1)

    ref_bin = slot(ref[:, 2])
    cloud_bin = slot(cloud[:, 2])
    n_ref = np.bincount(ref_bin, minlength=n_bins)

    def share(mask: np.ndarray) -> list[float | None]:
        hit = np.bincount(ref_bin, weights=mask.astype(np.float64), minlength=n_bins)
        return [float(h / n) if n else None for h, n in zip(hit, n_ref, strict=True)]

    covered = {"all": share(np.asarray(data.reference_distance_m) <= tau)}
    counts = {"all": np.bincount(cloud_bin, minlength=n_bins)}
    stations: list[str] = []
    if data.cloud_station is not None:
        st = np.asarray(data.cloud_station)
        centre = ref.mean(axis=0)
        ref_c = ref - centre  # queried once per station
        known = data.station_within or {}
        grid = None if known else _CellGrid.of(ref_c, tau)
        for code in np.unique(st):
            name = f"S{int(code)}"
            stations.append(name)
            sel = st == code
            hint = known.get(int(code))
            if hint is None and grid is None and known:  # a station the hints lack
                grid = _CellGrid.of(ref_c, tau)
            near = _within(ref_c, cloud[sel] - centre, tau, grid, workers, hint)
            covered[name] = share(near)
            counts[name] = np.bincount(cloud_bin[sel], minlength=n_bins)
    out: dict[str, Any] = {
        "bin_m": step,
        "base_z_m": base,
        "edges_m": [float(e - base) for e in edges],
        "tolerance_m": tau,
        "stations": stations,
        "reference_points": [int(n) for n in n_ref],
        "coverage": covered,
        "cloud_points": {k: [int(c) for c in v] for k, v in counts.items()},
    }
    info = s.get("reference") or {}
    area, samples = info.get("area_m2"), info.get("samples")
    if info.get("kind") == "mesh" and area and samples:
        slice_area = n_ref * (float(area) / float(samples))
        out["area_m2"] = [float(a) for a in slice_area]
        out["density_per_m2"] = {
            k: [float(c / a) if a > 0 else None for c, a in zip(v, slice_area, strict=True)]
            for k, v in counts.items()
        }
    return out
