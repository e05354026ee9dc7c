"""The Pareto front of (time, figure): known answers, and the definition itself checked
against a brute-force search on random points."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from treesim.sweep import dominates, pareto_front


def brute_force(cost, value, higher_is_better=False):
    sign = -1 if higher_is_better else 1
    pts = {
        i: (c, sign * v)
        for i, (c, v) in enumerate(zip(cost, value, strict=True))
        if c is not None and v is not None and math.isfinite(c) and math.isfinite(v)
    }
    return {i for i, p in pts.items() if not any(dominates(q, p) for q in pts.values())}


def test_a_staircase():
    # time:    1   2   3   4   5
    # figure:  5   3   4   1   1
    # (3, 4) is beaten by (2, 3); (5, 1) by (4, 1)
    assert pareto_front([1, 2, 3, 4, 5], [5, 3, 4, 1, 1]) == [0, 1, 3]


def test_higher_is_better_flips_the_figure():
    # coverage: more is better
    assert pareto_front([1, 2, 3], [0.5, 0.4, 0.9], higher_is_better=True) == [0, 2]
    assert pareto_front([1, 2, 3], [0.5, 0.4, 0.9]) == [0, 1]


def test_ties():
    # equal points are both on the front; at equal time only the best value counts
    assert pareto_front([1, 1, 2], [2, 2, 1]) == [0, 1, 2]
    assert pareto_front([1, 1, 2], [3, 2, 2]) == [1]
    # equal value, more time: beaten
    assert pareto_front([1, 2], [1, 1]) == [0]


def test_missing_values_take_no_part():
    assert pareto_front([1, None, 3, 4], [5, 0, float("nan"), 1]) == [0, 3]
    assert pareto_front([], []) == []
    assert pareto_front([None], [1.0]) == []


def test_lengths_must_match():
    with pytest.raises(ValueError, match="differ in length"):
        pareto_front([1, 2], [1])


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
small = st.integers(min_value=0, max_value=5).map(float)  # many ties


@given(
    st.lists(st.tuples(st.one_of(finite, small), st.one_of(finite, small, st.none())), max_size=40),
    st.booleans(),
)
def test_the_front_is_exactly_the_non_dominated_points(pts, higher):
    cost = [c for c, _ in pts]
    value = [v for _, v in pts]
    front = pareto_front(cost, value, higher_is_better=higher)
    assert set(front) == brute_force(cost, value, higher)
    assert len(front) == len(set(front))
    # by increasing cost
    assert [cost[i] for i in front] == sorted(cost[i] for i in front)


@given(st.lists(st.tuples(finite, finite), min_size=1, max_size=40))
def test_every_point_off_the_front_is_beaten_by_one_on_it(pts):
    cost, value = zip(*pts, strict=True)
    front = pareto_front(cost, value)
    assert front, "a non-empty set has a front"
    on = [(cost[i], value[i]) for i in front]
    for i, p in enumerate(pts):
        if i not in front:
            assert any(dominates(q, p) for q in on)
