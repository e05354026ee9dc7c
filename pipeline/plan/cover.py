"""Choosing stations: the goal as an objective, lazy greedy set cover, swap search.

**Objective.** For a set of stations ``S`` every sample keeps its best quality over ``S``
(0: unseen). Per tree, with goal coverage ``g`` and goal arc ``A``::

    progress = min(1, coverage / g) + min(1, arc / A)      (a term is left out when off)
    F(S) = Σ_trees progress  +  ε · Σ_trees mean quality / 255

``ε`` (:data:`TIE_BREAK`) is smaller than one sample's share of any tree's progress, so
the quality term (better incidence, stations spread around stems) only chooses between
plans that make the same progress. The coverage term is a truncated coverage function
(monotone submodular); the arc term counts sectors at least half of whose samples are
seen, which is not exactly submodular (two stations may each see a third of a sector):
lazy greedy's stale bounds can then be low, and the swap search makes up for it.

**Greedy** (:func:`lazy_greedy`, Minoux's lazy evaluation): keep each candidate's last
marginal gain as an upper bound in a heap; re-evaluate the top one and take it when it
still beats the next bound. Stop when every tree that can reach its goal (from all
candidates together) meets it, when the budget is spent, or when no candidate gains.

**Swap search** (:func:`improve`): with ``k`` greedy stations meeting the goal, try
``k - 1``: drop a station and swap stations for candidates (best improvement of F, every
station against every candidate at once) until the goal is met again (keep ``k - 1``, try
``k - 2``) or no swap improves F; a climb that ends on a local optimum is tried again from
another drop (least loss first, up to ``max_drops``) before ``k`` is kept.
Finally the kept plan is polished by the same swaps (only the tie-break can move).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .samples import SampleSet

__all__ = ["TIE_BREAK", "Objective", "Selection", "improve", "lazy_greedy"]

#: Weight of the quality tie-break, per tree (see the module's notes).
TIE_BREAK = 1e-6


class Objective:
    """The planner's objective over a :class:`SampleSet` (see the module's notes).

    Parameters
    ----------
    samples : SampleSet
    goal_coverage : float
        0: no coverage goal.
    goal_arc_deg : float
        0: no arc goal.
    """

    def __init__(self, samples: SampleSet, goal_coverage: float, goal_arc_deg: float) -> None:
        self.s = samples
        self.g_cov = float(goal_coverage)
        self.g_arc = float(goal_arc_deg)
        self.n_trees = len(samples.tree_ids)
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
    def figures(self, best: np.ndarray) -> dict[str, np.ndarray]:
        """Per-tree ``coverage`` (t,), ``arc_deg`` (t,) and ``quality`` (t,) for rows of best
        qualities ``best`` (m, n) → arrays (m, t)."""
        best = np.atleast_2d(best)
        m = len(best)
        seen = (best > 0).astype(np.float32)
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
        qsum = np.add.reduceat(best.astype(np.float32), self.tree_start[ok], axis=1)
        qs[:, ok] = qsum / (255.0 * self.tree_n[ok])
        return {"coverage": cov, "arc_deg": arc, "quality": qs}

    def progress(self, figs: dict[str, np.ndarray]) -> np.ndarray:
        """(m, t) progress towards each tree's goal, 0 .. number of goals."""
        p = np.zeros_like(figs["coverage"])
        if self.g_cov > 0:
            p += np.minimum(1.0, figs["coverage"] / self.g_cov)
        if self.g_arc > 0:
            p += np.minimum(1.0, figs["arc_deg"] / self.g_arc)
        return p

    def met(self, figs: dict[str, np.ndarray]) -> np.ndarray:
        """(m, t) whether each tree meets its goal."""
        ok = np.ones_like(figs["coverage"], dtype=bool)
        if self.g_cov > 0:
            ok &= figs["coverage"] >= self.g_cov - 1e-12
        if self.g_arc > 0:
            ok &= figs["arc_deg"] >= self.g_arc - 1e-9
        return ok

    def value(self, best: np.ndarray) -> np.ndarray:
        """F for each row of ``best`` (m, n) → (m,)."""
        figs = self.figures(best)
        return self.progress(figs).sum(axis=1) + TIE_BREAK * figs["quality"].sum(axis=1)

    def values_added(self, base: np.ndarray, quality: np.ndarray, chunk: int = 64) -> np.ndarray:
        """F of ``base`` (n,) with each candidate row of ``quality`` (k, n) added → (k,)."""
        out = np.empty(len(quality))
        for j in range(0, len(quality), chunk):
            out[j : j + chunk] = self.value(np.maximum(base[None], quality[j : j + chunk]))
        return out


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


def reachable_trees(obj: Objective, quality: np.ndarray) -> np.ndarray:
    """(t,) bool: trees that meet their goal with every candidate at once."""
    best = quality.max(axis=0) if len(quality) else np.zeros(quality.shape[1], np.uint8)
    return obj.met(obj.figures(best))[0]


def lazy_greedy(
    obj: Objective,
    quality: np.ndarray,
    max_stations: int,
    *,
    reachable: np.ndarray | None = None,
) -> Selection:
    """Lazy greedy set cover (see the module's notes).

    Parameters
    ----------
    obj : Objective
    quality : (k, n) uint8
        Candidates' sample qualities (:class:`~pipeline.plan.visibility.Visibility`).
    max_stations : int
        Budget in stations.
    reachable : (t,) bool, optional
        Trees whose goal some plan can meet (default: computed); the greedy stops when
        all of them meet it.
    """
    k, n = quality.shape
    if reachable is None:
        reachable = reachable_trees(obj, quality)
    best = np.zeros(n, np.uint8)
    f_now = float(obj.value(best)[0])
    evals = 1
    heap: list[tuple[float, int]] = []
    if k:
        first = obj.values_added(best, quality) - f_now
        evals += k
        heap = [(-float(g), j) for j, g in enumerate(first)]
        heapq.heapify(heap)
    chosen: list[int] = []
    gains: list[float] = []
    values: list[float] = []
    reason = "no candidates"
    while True:
        met = obj.met(obj.figures(best))[0]
        if reachable.any() and met[reachable].all():
            reason = "goal met" if reachable.all() else "goal met by every tree that can reach it"
            break
        if not reachable.any() and chosen and gains[-1] <= 0:
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
            g = float(obj.value(np.maximum(best, quality[j]))[0]) - f_now
            evals += 1
            if not heap or g >= -heap[0][0] - 1e-15:
                break
            heapq.heappush(heap, (-g, j))
        if g <= 0:
            reason = "no candidate adds anything"
            break
        chosen.append(j)
        gains.append(g)
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
    obj: Objective, quality: np.ndarray, chosen: list[int]
) -> tuple[float, int, int, int]:
    """The swap (position in ``chosen``, candidate) that maximises F: (F, pos, cand, evals)."""
    b1, top, b2 = _top2(quality, chosen)
    best_v, best_pos, best_c = -np.inf, -1, -1
    evals = 0
    taken = set(chosen)
    for pos in range(len(chosen)):
        base = np.where(top == pos, b2, b1)
        vals = obj.values_added(base, quality)
        evals += len(quality)
        for c in taken:
            vals[c] = -np.inf
        c = int(np.argmax(vals))
        if vals[c] > best_v:
            best_v, best_pos, best_c = float(vals[c]), pos, c
    return best_v, best_pos, best_c, evals


def improve(
    obj: Objective,
    quality: np.ndarray,
    sel: Selection,
    *,
    reachable: np.ndarray,
    max_rounds: int = 50,
    max_drops: int = 8,
) -> Selection:
    """Swap search after the greedy (see the module's notes); returns a new Selection."""
    chosen = list(sel.chosen)
    evals, swaps = 0, 0
    history: list[dict[str, Any]] = []

    def goal_met(ch: list[int]) -> bool:
        if not ch:
            return False
        met = obj.met(obj.figures(quality[ch].max(axis=0)))[0]
        return bool(reachable.any() and met[reachable].all())

    def value(ch: list[int]) -> float:
        return float(obj.value(quality[ch].max(axis=0))[0]) if ch else 0.0

    def climb(ch: list[int], stop_when_met: bool) -> tuple[list[int], bool]:
        nonlocal evals, swaps
        f = value(ch)
        for _ in range(max_rounds):
            if stop_when_met and goal_met(ch):
                return ch, True
            v, pos, c, e = _best_swap(obj, quality, ch)
            evals += e
            if not v > f + 1e-15:
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
    best = np.zeros(quality.shape[1], np.uint8)
    f = float(obj.value(best)[0])
    rest = list(chosen)
    while rest:
        vals = obj.values_added(best, quality[rest])
        i = int(np.argmax(vals))
        ordered.append(rest.pop(i))
        gains.append(float(vals[i]) - f)
        f = float(vals[i])
        values.append(f)
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
