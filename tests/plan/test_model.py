"""The probabilistic visibility model against full scans, and the verdict's honesty."""

from __future__ import annotations

import numpy as np

from treesim.plan.planner import _compare, _judge_verified

from .setups import model_check


def test_predicted_coverage_matches_a_full_scan_on_saplings_and_firs():
    # Saplings (leaves) and balsam firs (needles, twigs) on a small plot, coarse 0.3°:
    # the old 0/1 rule ("seen when the pulse grid is dense enough for τ") called most of
    # a fir unseen from every station (predicted ~0.4 below the scan); the expected
    # coverage over independent stations is within a few points of the scan per tree.
    r, plot, err = model_check()
    species = {plot.tree(t.tree_id).species for t in r.targets}
    assert species == {"sapling", "balsam-fir"}
    # what the docs print (validation, scan planning): "within 2.9 points of the scan per
    # tree on average (at most 5.2)"; held to the figures as printed, in points to one
    # decimal (measured 2.94 and 5.19; the old rule: 20.1 and 25.4, the disc share cast
    # per candidate: 4.5 and 9.1)
    points = 100 * np.abs(err)
    assert round(float(np.mean(points)), 1) <= 2.9, err
    assert round(float(np.max(points)), 1) <= 5.2, err


def _cmp(plan_stations: int, base_stations: int) -> dict:
    return {
        "best_baseline": "grid-2.7m",
        "baseline_stations": base_stations,
        "verdict": "plan better",
        "statement": "…",
    }


def test_verdict_is_judged_on_the_verified_figures():
    plan = {"n_stations": 5, "field_time_min": 20.6, "goal_met": True}
    # the evidence case: predicted "plan better", verified 8/12 against 12/12
    v = _judge_verified(_cmp(5, 25), plan, 8, 12, 12, 12)
    assert v["verdict"] == "baseline better (verified)"
    assert "8/12" in v["statement"] and "12/12" in v["statement"]
    assert not v["plan_goal_met"] and v["baseline_goal_met"]
    # both verified: the station counts decide
    v = _judge_verified(_cmp(5, 25), plan, 12, 12, 12, 12)
    assert v["verdict"] == "plan better (verified)"
    v = _judge_verified(_cmp(5, 5), plan, 12, 12, 12, 12)
    assert v["verdict"] == "as good (verified)"
    # unreachable trees lower the count required
    v = _judge_verified(_cmp(5, 25), plan, 10, 9, 10, 12)
    assert v["verdict"] == "plan better (verified)" and v["required"] == 10
    v = _judge_verified(_cmp(5, 25), plan, 7, 9, 10, 12)
    assert v["verdict"] == "neither (verified)"
    # no classic layout reaches the goal by the model: the best of them is verified
    # all the same, and named with its stations
    ring = {"name": "ring-3", "goal_met": False, "objective": 0.9, "n_stations": 3}
    cmp_ = _compare(plan, [ring, {**ring, "name": "cross-5", "objective": 0.5}])
    assert cmp_["verdict"] == "plan only" and cmp_["best_baseline"] == "ring-3"
    v = _judge_verified(cmp_, plan, 12, 11, 12, 12)
    assert v["verdict"] == "plan better (verified)" and "ring-3 does not with 3" in v["statement"]
    # no baseline verified
    v = _judge_verified({"best_baseline": None}, plan, 12, None, 12, 12)
    assert v["verdict"] == "plan only (verified)"
