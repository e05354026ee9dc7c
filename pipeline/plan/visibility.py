"""Which samples each candidate station sees, and how well.

**The visibility rule.** A station can hit a sample only when both of these hold:

1. the first surface the ray from the station towards the sample meets lies within τ
   of the sample (its own surface, or one in front of it closer than τ: a thin branch's
   near side for a sample on its far side), so the return along that ray is a point
   within τ; for a DBH band sample, the first surface met must be its own (a point on
   the near side of a stem does not measure its far side);
2. its range is within the scanner's ``min_range_m`` .. ``max_range_m`` and its elevation
   within the vertical field of view (and its azimuth within the horizontal one, for a
   station heading 0);

and then it hits it with a probability ``p`` set by the pulse grid there (the earlier,
deterministic rule "seen when the grid is dense enough for τ" is the case ``p = 1``; it
called a twig that every station hits now and then unseen from all of them together).

**Hit probability.** At range ``r`` a pulse grid of step ``δ`` (the larger of the two
angular resolutions, rad) lays points ``a = r·δ`` apart across the beam and ``b = a / cos(i)``
along a surface met at incidence ``i``. Where the grid falls on the surface (its phase) is
unknown and, from one station to the next, as good as random: the sample is covered when
some point of the grid falls within τ of it.

* A surface (``w >= a``, ``w`` the sample's thickness: the distance along its inward normal
  to the tree's far side) sees a lattice of cell ``a × b`` with a uniformly random offset.
  The share of the plane within τ of a lattice point is, column by column across ``a``
  (``x`` from the nearest column, the nearest point of that column covering a stretch
  ``2·√(τ² − x²)`` of every ``b``)::

      p = (1/a) ∫_{-a/2}^{a/2} min(1, 2·√(max(0, τ² − x²)) / b) dx

  (:func:`hit_probability`, in closed form). When the cell is at least ``2τ`` each way the
  discs round the points do not overlap and ``p = π·τ² / (a·b)``, the share of the cell
  one disc covers; ``p = 1`` exactly when ``½·√(a² + b²) <= τ`` (the farthest a point
  can be from its cell's corners is half the diagonal). In between, where ``a < 2τ < b``
  (close range, grazing incidence), the discs along a column overlap into a strip and
  ``p`` is about ``2τ / b``, less than ``π·τ² / (a·b)``.
* A feature thinner than the cell (a twig or needle, ``w < a``) catches, per ``a`` of its
  length, the ``w/a`` share of one cell's pulse: it is hit once per ``a²/w`` of its length
  on average. The sample is covered when a hit falls within ``±τ`` along the feature:
  ``p = min(1, 2·τ·w / a²)`` (1 when the hits are at most ``2τ`` apart).
* On a surface, ``p`` is capped at ``f·π·τ² / (a·b)``, ``f`` the share of the τ disc
  round the sample that is surface of it (a leaf smaller than the disc, an edge):
  :data:`DISC_RAYS` rays down the sample's normal, measured once per sample
  (:meth:`VisibilityCaster._disc_fraction`), not per station.

**Stations together.** Each station's grid phase is independent of the others', so a set
``S`` of stations covers a sample with ``P = 1 − Π_S (1 − p_s) = 1 − exp(−Σ_S λ_s)`` with
the *intensity* ``λ = −ln(1 − p)`` (``p`` capped at ``1 − 1e-6``: ``λ <= 13.8``). Adding a
station adds its ``λ``, removing one subtracts it (:mod:`treesim.plan.cover`). Twigs and
needles that no single station resolves (``p < 1`` everywhere) are thus covered by several
stations together, as real scans cover them.

The *quality* of a sample a station can hit (``p > 0``) is ``cos(i)`` (stored as
``1 .. 255``; 0: not hit), the planner's tie-break between plans that meet the goal
equally (better incidence, even spacing around stems).

**Cost.** One Open3D ``RaycastingScene`` holds the whole plot (trees and terrain, float32 in a
float64 local frame around the plot). A candidate casts one ray per sample of only the
trees whose bounding box lies within its range and field of view (the scanner's angular
window of a box, :func:`treesim.scan.rays.box_window`). The cost is rays × the BVH's
traversal: it grows with the candidates and samples, and slowly with the scene's
triangles (``benchmarks/bench_plan.py``), whose BVH is built once.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..frame import LocalFrame
from ..params import ScannerSpec
from ..scan.rays import box_window
from ..scene import Scene
from .samples import SampleSet

__all__ = [
    "HIT_TOLERANCE_M",
    "P_MAX",
    "Visibility",
    "hit_probability",
    "intensity_of",
    "max_spacing_ok",
    "visibility",
]

#: Least slack of rule 1 (float32 in a local frame tens of metres across errs by
#: micrometres): a first hit this close before the sample is always its own surface.
HIT_TOLERANCE_M = 1e-4
#: Cap of one station's hit probability (its intensity ``−ln(1 − p)`` stays finite).
P_MAX = 1.0 - 1e-6
#: Rays cast per Open3D call.
_CHUNK = 1 << 20
#: Rays per surface sample that measure the share of its τ disc a station sees.
DISC_RAYS = 6
#: Their points in the unit disc (area-uniform radii, golden-angle turns).
_DISC = np.array(
    [
        (
            math.sqrt((k + 0.5) / DISC_RAYS) * math.cos(k * 2.399963229728653),
            math.sqrt((k + 0.5) / DISC_RAYS) * math.sin(k * 2.399963229728653),
        )
        for k in range(DISC_RAYS)
    ]
)


@dataclass
class Visibility:
    """Every sample from every station: hit intensity and quality.

    Attributes
    ----------
    intensity : (k, n) float32
        ``λ = −ln(1 − p)``, ``p`` the station's hit probability (0: cannot hit); a set of
        stations covers a sample with probability ``1 − exp(−Σ λ)``.
    quality : (k, n) uint8
        0 where ``p = 0``, else ``cos(incidence) × 255`` (1..255): the tie-break.
    rays_cast : (k,) int64
        Rays each station cast (samples of the trees in its range and window).
    trees_tested : (k,) int64
        Trees within each station's range and window.
    timings_s : dict
        ``scene_build``, ``cast`` (seconds).
    """

    intensity: np.ndarray
    quality: np.ndarray
    rays_cast: np.ndarray
    trees_tested: np.ndarray
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def probability(self) -> np.ndarray:
        """(k, n) each station's hit probability ``1 − exp(−λ)``."""
        return -np.expm1(-self.intensity.astype(np.float64))


def _strip_integral(u: np.ndarray, tau: float) -> np.ndarray:
    """``∫_0^u √(τ² − x²) dx`` for ``0 <= u <= τ``."""
    u = np.clip(u, 0.0, tau)
    return 0.5 * (u * np.sqrt(np.maximum(tau * tau - u * u, 0.0)) + tau * tau * np.arcsin(u / tau))


def hit_probability(
    range_m: np.ndarray,
    cos_inc: np.ndarray,
    step_rad: float,
    tau_m: float,
    thickness_m: np.ndarray | float = np.inf,
    disc_fraction: np.ndarray | float = 1.0,
) -> np.ndarray:
    """One station's chance of a return within τ of a sample (module notes).

    A surface (``w >= a``): the share of the plane within τ of a lattice of cell
    ``a × b`` (``a = range × step``, ``b = a / cos i``), ``π·τ² / (a·b)`` when the cell is
    at least ``2τ`` each way, 1 when ``½·√(a² + b²) <= τ``; at most
    ``disc_fraction · π·τ² / (a·b)`` when only that share of the disc of radius τ round the
    sample is surface the station sees (a leaf smaller than the disc, an edge, a twig in
    front). A thinner feature: ``min(1, 2·τ·w / a²)``.
    """
    tau = float(tau_m)
    a = np.asarray(range_m, np.float64) * step_rad
    b = a / np.maximum(np.asarray(cos_inc, np.float64), 1e-12)
    w = np.broadcast_to(np.asarray(thickness_m, np.float64), a.shape)
    a_safe = np.maximum(a, 1e-300)
    # surface: (1/a) ∫_{-a/2}^{a/2} min(1, 2√(τ² − x²)/b) dx, in closed form; x0: where
    # the strip of one column is at least b high
    half = 0.5 * b
    x0 = np.sqrt(np.maximum(tau * tau - half * half, 0.0))
    ha = 0.5 * a
    full = np.minimum(x0, ha)
    part = (_strip_integral(np.minimum(ha, tau), tau) - _strip_integral(full, tau)) / np.maximum(
        half, 1e-300
    )
    surface = np.clip(2.0 * (full + part) / a_safe, 0.0, 1.0)
    f = np.broadcast_to(np.asarray(disc_fraction, np.float64), a.shape)
    surface = np.minimum(surface, f * math.pi * tau * tau / np.maximum(a * b, 1e-300))
    thin = np.minimum(1.0, 2.0 * tau * w / (a_safe * a_safe))
    return np.where(w >= a, surface, thin)


def intensity_of(p: np.ndarray) -> np.ndarray:
    """``λ = −ln(1 − p)`` (float32), ``p`` capped at :data:`P_MAX`."""
    return (-np.log1p(-np.minimum(np.asarray(p, np.float64), P_MAX))).astype(np.float32)


def max_spacing_ok(
    range_m: np.ndarray,
    cos_inc: np.ndarray,
    step_rad: float,
    tau_m: float,
    thickness_m: np.ndarray | float = np.inf,
) -> np.ndarray:
    """Whether one station is sure to hit there (``p == 1``): the half-diagonal of the
    pulse grid's cell on the surface is at most τ, or for a feature thinner than the
    cell, its hits are at most ``2τ`` apart."""
    return hit_probability(range_m, cos_inc, step_rad, tau_m, thickness_m) >= 1.0


class VisibilityCaster:
    """The plot's ray-casting scene, built once, and the rule applied per station."""

    def __init__(self, scene: Scene, samples: SampleSet, *, nthreads: int = 0) -> None:
        import open3d as o3d

        t0 = time.perf_counter()
        self.frame = LocalFrame.around(scene.vertices[np.unique(scene.faces)])
        self.samples = samples
        self.pts = self.frame.to_local(samples.points)
        self.bounds = samples.bounds - self.frame.origin_array
        self.rc = o3d.t.geometry.RaycastingScene(nthreads=int(nthreads))
        self.rc.add_triangles(
            o3d.core.Tensor(self.frame.to_local(scene.vertices).astype(np.float32)),
            o3d.core.Tensor(scene.faces.astype(np.uint32)),
        )
        self._o3d = o3d
        self._cast(np.zeros((1, 6), np.float32))  # the BVH is built on the first query
        self.build_s = time.perf_counter() - t0
        self.thickness_m = self._thickness()
        self._disc: dict[float, np.ndarray] = {}

    def _cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``t_hit`` and the unit normal of the triangle hit, per ray."""
        out = self.rc.cast_rays(self._o3d.core.Tensor(rays.astype(np.float32)))
        return out["t_hit"].numpy().astype(np.float64), out["primitive_normals"].numpy()

    def _thickness(self) -> np.ndarray:
        """Per sample, the distance along its inward normal (outward normals assumed, as
        closed tubes have) to the next surface: a branch's diameter; inf for open sheets
        (leaves, whose extent, not their thickness, matters). The ray starts 1 mm inside,
        clear of the sample's own triangle whatever float32 makes of it."""
        eps = 1e-3
        n = self.samples.normals
        rays = np.concatenate([self.pts - eps * n, -n], axis=1)
        out = np.empty(len(rays))
        for k in range(0, len(rays), _CHUNK):
            out[k : k + _CHUNK] = self._cast(rays[k : k + _CHUNK])[0]
        return out + eps

    def _disc_fraction(self, which: np.ndarray, tau_m: float) -> np.ndarray:
        """Per sample ``which``, the share of :data:`DISC_RAYS` points of the disc of radius
        τ round it in its tangent plane that are surface of it: a ray down the sample's
        normal from ``2τ`` above each disc point must first meet a surface within τ of the
        sample (a leaf smaller than the disc, an edge, or a twig just in front, leave
        part of it bare). Measured once per sample and τ, not per station: the planner's
        cost then follows the candidates, not the triangles near the surface (the disc
        rays run among them); the station's own view of the sample is its central ray."""
        key = float(tau_m)
        if key not in self._disc:
            pts = self.pts
            n = self.samples.normals
            e = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [[1.0, 0, 0]], [[0, 1.0, 0]])
            u = np.cross(n, e)
            u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
            v = np.cross(n, u)
            off = tau_m * (_DISC[:, 0, None, None] * u[None] + _DISC[:, 1, None, None] * v[None])
            tgt = (pts[None] + off).reshape(-1, 3)  # (s·m, 3), disc point by disc point
            down = np.tile(n, (len(_DISC), 1))
            rays = np.concatenate([tgt + 2.0 * tau_m * down, -down], axis=1)
            t_hit = np.empty(len(tgt))
            for k in range(0, len(tgt), _CHUNK):
                t_hit[k : k + _CHUNK] = self._cast(rays[k : k + _CHUNK])[0]
            hit = rays[:, :3] + np.where(np.isfinite(t_hit), t_hit, 0.0)[:, None] * rays[:, 3:]
            near = np.isfinite(t_hit) & (
                np.linalg.norm(hit - np.tile(pts, (len(_DISC), 1)), axis=1) <= tau_m
            )
            self._disc[key] = near.reshape(len(_DISC), -1).mean(axis=0)
        return self._disc[key][which]

    def trees_in_view(self, o: np.ndarray, spec: ScannerSpec) -> np.ndarray:
        """Indices of the trees whose sample box lies within range and the vertical field
        of view of a station at local ``o`` (heading 0)."""
        out = []
        v0, v1 = spec.vertical_fov_deg
        for i, (lo, hi) in enumerate(self.bounds):
            if not np.isfinite(lo).all():
                continue
            w = box_window(lo - o, hi - o)
            if w.min_distance_m > spec.max_range_m or w.max_distance_m < spec.min_range_m:
                continue
            if w.elevation_deg[1] < v0 or w.elevation_deg[0] > v1:
                continue
            out.append(i)
        return np.asarray(out, np.int64)

    def station(
        self, position: np.ndarray, spec: ScannerSpec, tau_m: float
    ) -> tuple[np.ndarray, np.ndarray, int, int]:
        """Hit probability (n,) float64 and quality (n,) uint8 of every sample from one
        station (plot coordinates), rays cast, trees tested."""
        s = self.samples
        q = np.zeros(len(s), np.uint8)
        prob = np.zeros(len(s))
        o = self.frame.to_local(np.asarray(position, np.float64)[None])[0]
        trees = self.trees_in_view(o, spec)
        if not len(trees):
            return prob, q, 0, 0
        idx = np.flatnonzero(np.isin(s.tree_of, trees))
        d = self.pts[idx] - o
        dist = np.linalg.norm(d, axis=1)
        el = np.degrees(np.arcsin(np.clip(d[:, 2] / np.maximum(dist, 1e-300), -1, 1)))
        ok = (dist >= spec.min_range_m) & (dist <= spec.max_range_m)
        ok &= (el >= spec.vertical_fov_deg[0]) & (el <= spec.vertical_fov_deg[1])
        if not spec.full_turn:
            az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
            h0, h1 = spec.horizontal_fov_deg
            ok &= ((az - h0) % 360.0) <= (h1 - h0)
        cand = np.flatnonzero(ok)
        # rays: origin o, direction to the sample (unnormalised: the sample is at t = 1)
        rays = np.empty((len(cand), 6), np.float64)
        rays[:, :3] = o
        rays[:, 3:] = d[cand]
        t_hit = np.empty(len(cand))
        normal = np.empty((len(cand), 3))
        for k in range(0, len(cand), _CHUNK):
            t_hit[k : k + _CHUNK], normal[k : k + _CHUNK] = self._cast(rays[k : k + _CHUNK])
        dc = dist[cand]
        first = t_hit >= 1.0 - max(tau_m, HIT_TOLERANCE_M) / np.maximum(dc, 1e-300)
        # the surface met: the sample's own when the ray passes everything before it
        own = t_hit >= 1.0 - HIT_TOLERANCE_M / np.maximum(dc, 1e-300)
        nrm = np.where(own[:, None], s.normals[idx[cand]], normal)
        cos_inc = np.abs(np.einsum("ij,ij->i", nrm, d[cand])) / np.maximum(dc, 1e-300)
        step = math.radians(max(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
        # the hit's range (the sample's, or the nearer surface's) sets the spacing
        r_hit = np.minimum(t_hit, 1.0) * dc
        w = np.where(own, self.thickness_m[idx[cand]], np.inf)
        # band samples (DBH) count only on their own side of the stem: the first hit is
        # their own surface, not the stem's near side within τ of them
        first &= own | ~s.band[idx[cand]]
        # the share of the τ disc round a surface sample that the station sees
        frac = np.ones(len(cand))
        surf = np.flatnonzero(first & (w >= r_hit * step))
        if len(surf):
            frac[surf] = self._disc_fraction(idx[cand[surf]], tau_m)
        pc = np.where(first, hit_probability(r_hit, cos_inc, step, tau_m, w, frac), 0.0)
        seen = np.flatnonzero(pc > 0)
        prob[idx[cand[seen]]] = pc[seen]
        q[idx[cand[seen]]] = np.clip(np.rint(255.0 * cos_inc[seen]), 1, 255).astype(np.uint8)
        return prob, q, int(len(cand)), int(len(trees))


def visibility(
    caster: VisibilityCaster,
    positions: np.ndarray,
    spec: ScannerSpec,
    tau_m: float,
    *,
    progress: Any = None,
) -> Visibility:
    """:class:`Visibility` of every sample from every station in ``positions`` (k, 3)."""
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    k = len(positions)
    q = np.zeros((k, len(caster.samples)), np.uint8)
    lam = np.zeros((k, len(caster.samples)), np.float32)
    rays = np.zeros(k, np.int64)
    trees = np.zeros(k, np.int64)
    t0 = time.perf_counter()
    for j, p in enumerate(positions):
        if progress is not None and (j % 8 == 0):
            progress(j / max(1, k), f"visibility: candidate {j + 1}/{k}")
        prob, q[j], rays[j], trees[j] = caster.station(p, spec, tau_m)
        lam[j] = intensity_of(prob)
    return Visibility(
        intensity=lam,
        quality=q,
        rays_cast=rays,
        trees_tested=trees,
        timings_s={"scene_build": caster.build_s, "cast": time.perf_counter() - t0},
    )
