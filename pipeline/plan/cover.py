"""Choosing stations: the goal as an objective, lazy greedy set cover, swap search.

**Objective.** A station hits each sample with a probability ``p``, independently of the
other stations (:mod:`treesim.plan.visibility`), stored as its intensity
``λ = −ln(1 − p)``. A set of stations ``S`` is summed up per sample by ``Λ = Σ_S λ`` (the
sample is covered with probability ``1 − exp(−Λ)``) and its best quality over ``S``
(0: no station can hit it). Per tree, with goal coverage ``g`` and goal arc ``A``::

    coverage = mean over its coverage samples of 1 − exp(−Λ)      (expected coverage)
    arc      = sectors whose band samples' expected share covered is ≥ ½, × sector width
    progress = min(1, coverage / g) + min(1, arc / A)      (a term is left out when off)
    F(S) = Σ_trees progress  +  ε · Σ_trees mean quality / 255

``ε`` (:data:`TIE_BREAK`) is smaller than one sample's share of any tree's progress, so
the quality term (better incidence, stations spread around stems) only chooses between
plans that make the same progress. Adding a station adds its ``λ`` row to ``Λ``; dropping
one subtracts it. The coverage term is a concave function (``1 − e^{−x}``, then the cap)
of sums of non-negative terms, summed: monotone submodular, as the set cover it
generalises (``p`` in {0, 1}); the arc term thresholds a sector's expected share, which
is not exactly submodular (two stations may each see a third of a sector): lazy greedy's
stale bounds can then be low, and the swap search makes up for it. A measured cloud is
the case ``Λ`` in {0, ∞} (:meth:`Objective.figures` takes ``inf``).

**Greedy** (:func:`lazy_greedy`, Minoux's lazy evaluation): keep each candidate's last
marginal gain as an upper bound in a heap; re-evaluate the top one and take it when it
still beats the next bound. Stop when every tree that can reach its goal (from all
candidates together) meets it, when the budget is spent, or when no candidate gains.

**Swap search** (:func:`improve`): with ``k`` greedy stations meeting the goal, try
``k - 1``: drop a station and swap stations for candidates (best improvement of F, every
station against every candidate at once) until the goal is met again (keep ``k - 1``, try
``k - 2``) or no swap improves F (a swap's base: ``Λ`` less the ``λ`` of the station it
replaces, the best quality of the others); a climb that ends on a local optimum is tried
again from another drop (least loss first, up to ``max_drops``) before ``k`` is kept.
Finally the kept plan is polished by the same swaps (trees short of their goal, and the
tie-break, can still move).
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .samples import SampleSet

__all__ = [
    "GAIN_EPS",
    "TIE_BREAK",
    "Objective",
    "Selection",
    "improve",
    "lazy_greedy",
    "reachable_trees",
    "state",
]

#: Weight of the quality tie-break, per tree (see the module's notes).
TIE_BREAK = 1e-6
#: Slack of the coverage goal: one station's hit probability is capped at ``1 − 1e-6``
#: (:data:`treesim.plan.visibility.P_MAX`), so samples it is sure to hit count as covered.
COVERAGE_SLACK = 1e-6
#: Least change of F that counts as a gain (a greedy step, a swap): F sums thousands of
#: float64 terms, whose rounding is ~1e-13; one sample's tie-break is ~1e-12 and more.
GAIN_EPS = 1e-13


class Objective:
    """The planner's objective over a :class:`SampleSet` (see the module's notes).

    Parameters
    ----------
    samples : SampleSet
    goal_coverage : float or (t,) float
        One goal for every tree, or one per tree (``samples.tree_ids`` order); 0: no
        coverage goal (for that tree).
    goal_arc_deg : float
        0: no arc goal.
    """

    def __init__(
        self, samples: SampleSet, goal_coverage: float | np.ndarray, goal_arc_deg: float
    ) -> None:
        self.s = samples
        self.n_trees = len(samples.tree_ids)
        self.g_cov = np.broadcast_to(np.asarray(goal_coverage, np.float64), (self.n_trees,)).copy()
        self.g_arc = float(goal_arc_deg)
        st = samples.block_starts
        self.starts = st
        self.sizes = np.diff(np.append(st, len(samples))).astype(np.float64)
        self.cov_block = np.full(self.n_trees, -1, np.int64)
        for b in np.flatnonzero(samples.block_sector < 0):
            self.cov_block[samples.block_tree[b]] = b
        self.sec_blocks = np.flatnonzero(samples.block_sector >= 0)
        self.sec_tree = samples.block_tree[self.sec_blocks]
        tree_start = np.array([samples.tree_slice(i).start for i in range(self.n_trees)])
        tree_stop = np.array([samples.tree_slice(i).stop for i in range(self.n_trees)])
        self.tree_start, self.tree_n = tree_start, (tree_stop - tree_start).astype(np.float64)

    # -- figures ---------------------------------------------------------------------
    def figures(
        self, intensity: np.ndarray, quality: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """Per-tree expected ``coverage`` (t,), ``arc_deg`` (t,) and ``quality`` (t,) for
        rows of summed intensities ``Λ`` (m, n) (``inf``: covered for sure, as a measured
        cloud's samples are; 0: never) and best qualities ``quality`` (m, n) (``None``: no
        quality term) → arrays (m, t)."""
        lam = np.atleast_2d(np.asarray(intensity, np.float64))
        m = len(lam)
        seen = -np.expm1(-lam)  # 1 − exp(−Λ); Λ = inf gives 1
        sums = np.add.reduceat(seen, self.starts, axis=1) if len(self.starts) else np.zeros((m, 0))
        frac = sums / self.sizes
        cov = np.zeros((m, self.n_trees))
        has = self.cov_block >= 0
        cov[:, has] = frac[:, self.cov_block[has]]
        arc = np.zeros((m, self.n_trees))
        if len(self.sec_blocks):
            sec_seen = (frac[:, self.sec_blocks] >= 0.5).astype(np.float64)
            for_t = np.zeros((len(self.sec_blocks), self.n_trees))
            for_t[np.arange(len(self.sec_blocks)), self.sec_tree] = 1.0
            arc = (sec_seen @ for_t) * self.s.arc_bin_deg
        ok = self.tree_n > 0
        qs = np.zeros((m, self.n_trees))
        if quality is not None:
            best = np.atleast_2d(quality)
            qsum = np.add.reduceat(best.astype(np.float64), self.tree_start[ok], axis=1)
            qs[:, ok] = qsum / (255.0 * self.tree_n[ok])
        return {"coverage": cov, "arc_deg": arc, "quality": qs}

    def progress(self, figs: dict[str, np.ndarray]) -> np.ndarray:
        """(m, t) progress towards each tree's goal, 0 .. number of goals."""
        p = np.zeros_like(figs["coverage"])
        on = self.g_cov > 0
        if on.any():
            p[:, on] += np.minimum(1.0, figs["coverage"][:, on] / self.g_cov[on])
        if self.g_arc > 0:
            p += np.minimum(1.0, figs["arc_deg"] / self.g_arc)
        return p

    def met(self, figs: dict[str, np.ndarray]) -> np.ndarray:
        """(m, t) whether each tree meets its goal (coverage to within :data:`COVERAGE_SLACK`:
        a station sure to hit a sample covers it with probability ``1 − 1e-6``)."""
        ok = np.ones_like(figs["coverage"], dtype=bool)
        on = self.g_cov > 0
        if on.any():
            ok[:, on] &= figs["coverage"][:, on] >= self.g_cov[on] - COVERAGE_SLACK
        if self.g_arc > 0:
            ok &= figs["arc_deg"] >= self.g_arc - 1e-9
        return ok

    def value(self, intensity: np.ndarray, quality: np.ndarray | None = None) -> np.ndarray:
        """F for each row of ``Λ`` (m, n) and best qualities (m, n) → (m,)."""
        figs = self.figures(intensity, quality)
        return self.progress(figs).sum(axis=1) + TIE_BREAK * figs["quality"].sum(axis=1)

    def values_added(
        self,
        base: tuple[np.ndarray, np.ndarray],
        intensity: np.ndarray,
        quality: np.ndarray,
        chunk: int = 64,
    ) -> np.ndarray:
        """F of the state ``base`` (``Λ`` (n,), best quality (n,)) with each candidate row
        of ``intensity`` (k, n) and ``quality`` (k, n) added → (k,)."""
        lam0, q0 = base
        lam0 = np.asarray(lam0, np.float64)
        out = np.empty(len(intensity))
        for j in range(0, len(intensity), chunk):
            out[j : j + chunk] = self.value(
                lam0[None] + intensity[j : j + chunk], np.maximum(q0[None], quality[j : j + chunk])
            )
        return out


def state(
    intensity: np.ndarray, quality: np.ndarray, chosen: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """The objective's state for the stations ``chosen``: ``Λ`` (n,) float64 (the sum of
    their intensities) and the best quality (n,) uint8."""
    ch = list(chosen)
    if not ch:
        return np.zeros(intensity.shape[1]), np.zeros(quality.shape[1], np.uint8)
    return intensity[ch].sum(axis=0, dtype=np.float64), quality[ch].max(axis=0)


def default_quality(intensity: np.ndarray, quality: np.ndarray | None) -> np.ndarray:
    """``quality``, or 255 wherever a station can hit (hand-made matrices)."""
    if quality is not None:
        return quality
    return np.where(np.asarray(intensity) > 0, 255, 0).astype(np.uint8)


@dataclass
class Selection:
    """Stations chosen (candidate indices, in order) and how."""

    chosen: list[int]
    gains: list[float]
    values: list[float]
    stop_reason: str
    evaluations: int = 0
    swaps: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)


def reachable_trees(
    obj: Objective, intensity: np.ndarray, quality: np.ndarray | None = None
) -> np.ndarray:
    """(t,) bool: trees that meet their goal with every candidate at once."""
    q = default_quality(intensity, quality)
    return obj.met(obj.figures(*state(intensity, q, range(len(intensity)))))[0]


def lazy_greedy(
    obj: Objective,
    intensity: np.ndarray,
    max_stations: int,
    *,
    quality: np.ndarray | None = None,
    reachable: np.ndarray | None = None,
) -> Selection:
    """Lazy greedy set cover (see the module's notes).

    Parameters
    ----------
    obj : Objective
    intensity : (k, n) float32
        Candidates' hit intensities ``λ`` (:class:`~treesim.plan.visibility.Visibility`).
    max_stations : int
        Budget in stations.
    quality : (k, n) uint8, optional
        Candidates' sample qualities (the tie-break; default 255 where ``λ > 0``).
    reachable : (t,) bool, optional
        Trees whose goal some plan can meet (default: computed); the greedy stops when
        all of them meet it.
    """
    quality = default_quality(intensity, quality)
    k, n = intensity.shape
    if reachable is None:
        reachable = reachable_trees(obj, intensity, quality)
    lam, best = state(intensity, quality, [])
    f_now = float(obj.value(lam, best)[0])
    evals = 1
    heap: list[tuple[float, int]] = []
    if k:
        first = obj.values_added((lam, best), intensity, quality) - f_now
        evals += k
        heap = [(-float(g), j) for j, g in enumerate(first)]
        heapq.heapify(heap)
    chosen: list[int] = []
    gains: list[float] = []
    values: list[float] = []
    reason = "no candidates"
    while True:
        met = obj.met(obj.figures(lam))[0]
        if reachable.any() and met[reachable].all():
            reason = "goal met" if reachable.all() else "goal met by every tree that can reach it"
            break
        if not reachable.any() and chosen and gains[-1] <= GAIN_EPS:
            reason = "no tree can reach its goal; no candidate adds anything"
            break
        if len(chosen) >= max_stations:
            reason = "budget spent"
            break
        if not heap:
            reason = "no candidates left"
            break
        while True:
            neg, j = heapq.heappop(heap)
            g = float(obj.value(lam + intensity[j], np.maximum(best, quality[j]))[0]) - f_now
            evals += 1
            if not heap or g >= -heap[0][0] - 1e-15:
                break
            heapq.heappush(heap, (-g, j))
        if g <= GAIN_EPS:
            reason = "no candidate adds anything"
            break
        chosen.append(j)
        gains.append(g)
        lam = lam + intensity[j]
        best = np.maximum(best, quality[j])
        f_now += g
        values.append(f_now)
    return Selection(
        chosen=chosen, gains=gains, values=values, stop_reason=reason, evaluations=evals
    )


def _top2(quality: np.ndarray, chosen: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per sample: best quality over ``chosen``, which of them gives it, second best."""
    q = quality[chosen]
    order = np.argsort(q, axis=0)
    top = order[-1]
    b1 = np.take_along_axis(q, top[None], 0)[0]
    b2 = np.take_along_axis(q, order[-2][None], 0)[0] if len(chosen) > 1 else np.zeros_like(b1)
    return b1, top, b2


def _best_swap(
    obj: Objective, intensity: np.ndarray, quality: np.ndarray, chosen: list[int]
) -> tuple[float, int, int, int]:
    """The swap (position in ``chosen``, candidate) that maximises F: (F, pos, cand, evals)."""
    total = intensity[chosen].sum(axis=0, dtype=np.float64)
    b1, top, b2 = _top2(quality, chosen)
    best_v, best_pos, best_c = -np.inf, -1, -1
    evals = 0
    taken = set(chosen)
    for pos in range(len(chosen)):
        base_lam = np.maximum(total - intensity[chosen[pos]], 0.0)
        base_q = np.where(top == pos, b2, b1)
        vals = obj.values_added((base_lam, base_q), intensity, quality)
        evals += len(intensity)
        for c in taken:
            vals[c] = -np.inf
        c = int(np.argmax(vals))
        if vals[c] > best_v:
            best_v, best_pos, best_c = float(vals[c]), pos, c
    return best_v, best_pos, best_c, evals


def improve(
    obj: Objective,
    intensity: np.ndarray,
    sel: Selection,
    *,
    quality: np.ndarray | None = None,
    reachable: np.ndarray,
    max_rounds: int = 50,
    max_drops: int = 8,
) -> Selection:
    """Swap search after the greedy (see the module's notes); returns a new Selection."""
    quality = default_quality(intensity, quality)
    chosen = list(sel.chosen)
    evals, swaps = 0, 0
    history: list[dict[str, Any]] = []

    def goal_met(ch: list[int]) -> bool:
        if not ch:
            return False
        met = obj.met(obj.figures(state(intensity, quality, ch)[0]))[0]
        return bool(reachable.any() and met[reachable].all())

    def value(ch: list[int]) -> float:
        return float(obj.value(*state(intensity, quality, ch))[0]) if ch else 0.0

    def climb(ch: list[int], stop_when_met: bool) -> tuple[list[int], bool]:
        nonlocal evals, swaps
        f = value(ch)
        for _ in range(max_rounds):
            if stop_when_met and goal_met(ch):
                return ch, True
            v, pos, c, e = _best_swap(obj, intensity, quality, ch)
            evals += e
            if not v > f + GAIN_EPS:
                break
            trial = ch[:pos] + [c] + ch[pos + 1 :]
            if not stop_when_met and goal_met(ch) and not goal_met(trial):
                break  # polishing never gives up a met goal
            ch, f = trial, v
            swaps += 1
        return ch, goal_met(ch)

    if goal_met(chosen):
        while len(chosen) > 1:
            # drop a station (least loss first), then climb towards the goal; a climb can
            # stop on a local optimum, so up to max_drops different drops are tried
            vals = [value(chosen[:i] + chosen[i + 1 :]) for i in range(len(chosen))]
            evals += len(chosen)
            ok = False
            for drop in np.argsort(vals)[::-1][:max_drops]:
                d = int(drop)
                trial, ok = climb(chosen[:d] + chosen[d + 1 :], stop_when_met=True)
                if ok:
                    break
            history.append({"tried_stations": len(chosen) - 1, "goal_met": ok})
            if not ok:
                break
            chosen = trial
    chosen, _ = climb(chosen, stop_when_met=False)
    # order: greedy order of the kept stations (each next one adds the most)
    ordered: list[int] = []
    gains: list[float] = []
    values: list[float] = []
    lam, best = state(intensity, quality, [])
    f = float(obj.value(lam, best)[0])
    rest = list(chosen)
    while rest:
        vals = obj.values_added((lam, best), intensity[rest], quality[rest])
        i = int(np.argmax(vals))
        ordered.append(rest.pop(i))
        gains.append(float(vals[i]) - f)
        f = float(vals[i])
        values.append(f)
        lam = lam + intensity[ordered[-1]]
        best = np.maximum(best, quality[ordered[-1]])
    reason = sel.stop_reason
    if len(ordered) < len(sel.chosen):
        reason += f"; swap search dropped {len(sel.chosen) - len(ordered)} station(s)"
    return Selection(
        chosen=ordered,
        gains=gains,
        values=values,
        stop_reason=reason,
        evaluations=sel.evaluations + evals,
        swaps=swaps,
        history=history,
    )
