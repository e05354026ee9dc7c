"""Acceptance of ``treesim plan`` (issue 14): on a plot of 20 trees the plan is compared
with the classic layouts and verified by a full scan; on one tree it recovers the
three-station ring when that is what the goal needs."""

from __future__ import annotations

import numpy as np
import pytest

from .setups import RING_ARC_DEG, acceptance_plan, ring_gaps_deg, ring_plan


@pytest.fixture(scope="module")
def plot_plan():
    return acceptance_plan()


@pytest.mark.slow
def test_plot_plan_against_the_classic_layouts(plot_plan):
    r = plot_plan
    d = r.to_dict()
    assert len(r.targets) >= 20
    assert d["plan"]["goal_met"] and d["unreachable_trees"] == []
    cmp_ = d["comparison"]
    # the comparison is computed from the baselines' own figures, and consistently
    reaching = [b for b in d["baselines"] if b["goal_met"]]
    names = {b["name"] for b in d["baselines"]}
    assert {"ring-3", "centre+3", "cross-5"} <= names and sum(
        n.startswith("grid-") for n in names
    ) == 3
    for b in d["baselines"]:
        met = [b["per_tree"][t.tree_id]["coverage"] >= 0.8 for t in r.targets]
        arcs = [b["per_tree"][t.tree_id]["arc_deg"] >= 270 for t in r.targets]
        assert b["goal_met"] == all(m and a for m, a in zip(met, arcs, strict=True))
    pred = cmp_["predicted"]
    if reaching:
        best = min(reaching, key=lambda b: b["n_stations"])
        assert cmp_["baseline_stations"] == best["n_stations"]
        assert cmp_["fewer_stations"] == best["n_stations"] - d["plan"]["n_stations"]
        verdict = {1: "plan better", 0: "as good", -1: "baseline better"}[
            int(np.sign(cmp_["fewer_stations"]))
        ]
        assert pred["verdict"] == verdict
        assert cmp_["less_field_time_min"] == pytest.approx(
            cmp_["fewer_stations"] * r.station_time_s / 60
        )
    else:
        assert pred["verdict"] == "plan only"
    # the headline verdict is the verified one, from the verified counts
    ver_c = cmp_["verified"]
    assert cmp_["basis"] == "verified" and cmp_["verdict"].endswith("(verified)")
    assert ver_c["plan_goal_met"] == (ver_c["plan_trees_meeting_goal"] >= ver_c["required"])
    # the plan's stations: within the budget, each gaining something, field time adds up
    rows = d["plan"]["stations"]
    assert 1 <= len(rows) <= r.max_stations
    assert all(row["predicted_gain"] > 0 for row in rows)
    assert rows[-1]["cumulative_field_time_min"] == pytest.approx(d["plan"]["field_time_min"])
    # verified: a full-resolution scan of the plan meets the goal on every tree (the
    # stations aim at the goal plus goal_margin, 0.05: a tree's verified coverage lies
    # within a few points of the prediction, either side; without the margin one tree
    # here verified at 0.799 for a goal of 0.8), and the prediction is close
    ver = r.verification
    assert ver is not None and ver["points"] > 0
    assert ver["trees_meeting_goal"] == len(r.targets), {
        t: (e["coverage"], e["arc_deg"]) for t, e in ver["trees"].items() if not e["goal_met"]
    }
    # the acceptance, judged on the scans: fewer stations than the best classic
    # layout that reaches the goal, or honestly as good
    assert cmp_["verdict"] in ("plan better (verified)", "as good (verified)"), cmp_
    err = np.array(
        [
            r.predicted["coverage"][i] - ver["trees"][t.tree_id]["coverage"]
            for i, t in enumerate(r.targets)
        ]
    )
    # the plan's per-tree error as an absolute error (a signed mean lets errors of either
    # sign cancel): measured 4.7 points on average and at most 10.0 (2026-11-26; every
    # tree predicted below its scan, the goal margin's doing), bounded at 5 and 11
    assert np.mean(np.abs(err)) < 0.05, err
    assert np.max(np.abs(err)) < 0.11, err


@pytest.mark.slow
def test_plan_files(plot_plan, tmp_path):
    from treesim.plan.outputs import PLAN_FILES, write_plan

    paths = write_plan(plot_plan, tmp_path)
    assert set(paths) == set(PLAN_FILES)
    for p in paths.values():
        assert p.stat().st_size > 0
    lines = (tmp_path / "stations.csv").read_text().splitlines()
    assert lines[0].split(",")[:4] == ["order", "x_m", "y_m", "z_m"]
    assert len(lines) == 1 + len(plot_plan.selection.chosen)


def test_one_tree_recovers_the_three_station_ring():
    # The goal: the DBH band seen all round (every sector). Candidates stand 1.5-4 m
    # from the sapling; at 0.25° and τ = 1 cm one station hits the band's sectors with an
    # expected share >= ½ over ~160° at most (the hit probability falls with incidence),
    # under half the goal: three stations are needed, and suffice only when no gap
    # between them exceeds one station's arc. (At 0.15° one station's arc reaches 180°
    # and two opposite stations do.)
    r = ring_plan()
    sectors_goal = RING_ARC_DEG
    assert r.samples.n_sectors[0] * r.samples.arc_bin_deg >= sectors_goal
    # two stations cannot do it: the widest single arc is under half the goal
    one = r.objective.figures(r.visibility.intensity)["arc_deg"][:, 0]
    assert 2 * one.max() < sectors_goal
    assert r.goal_met and len(r.selection.chosen) == 3
    gaps, tol = ring_gaps_deg(r)
    print("\nring gaps (deg):", np.round(gaps, 1), "tolerance", round(float(tol), 1))
    assert np.all(np.abs(gaps - 120) <= tol), (gaps, tol)
