"""Pareto fronts of time against an accuracy figure."""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["dominates", "pareto_front"]


def _finite(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def dominates(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether ``a`` dominates ``b`` when both coordinates are to be minimised: no worse
    in either and better in at least one."""
    return a[0] <= b[0] and a[1] <= b[1] and (a[0] < b[0] or a[1] < b[1])


def pareto_front(
    cost: Sequence[float | None],
    value: Sequence[float | None],
    *,
    higher_is_better: bool = False,
) -> list[int]:
    """The indices of the non-dominated points of (cost, value).

    A point is on the front when no other point has lower-or-equal cost and a
    better-or-equal value with at least one of the two strictly better. Equal points
    are all on the front (neither beats the other). Points with a missing or non-finite
    cost or value take no part.

    Parameters
    ----------
    cost : sequence of float or None
        What is minimised (wall time).
    value : sequence of float or None
        The figure, minimised unless ``higher_is_better`` (coverage).

    Returns
    -------
    list of int
        Indices into the inputs, by increasing cost (then value, best first).
    """
    if len(cost) != len(value):
        raise ValueError(f"cost and value differ in length: {len(cost)} != {len(value)}")
    sign = -1.0 if higher_is_better else 1.0
    pts = sorted(
        (float(c), sign * float(v), i)
        for i, (c, v) in enumerate(zip(cost, value, strict=True))
        if _finite(c) and _finite(v)
    )
    front: list[int] = []
    best = math.inf  # the best value among strictly cheaper points
    k = 0
    while k < len(pts):
        c = pts[k][0]
        group = []
        while k < len(pts) and pts[k][0] == c:
            group.append(pts[k])
            k += 1
        g_best = group[0][1]  # sorted: the group's best value first
        if g_best < best:
            front.extend(i for _, v, i in group if v == g_best)
            best = g_best
    return front
