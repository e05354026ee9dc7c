"""``treesim plan --wind-speed-m-s``: the sway of each tree against the plan's goals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from treesim.cli import main
from treesim.plan import PlanParams, plan_scans
from treesim.plan.sources import mesh_tree_plot, species_tree_plot
from treesim.plan.wind import STEP_S, WINDOW_S, wind_risk
from treesim.scan.wind import Forcing, Structure, SwayModel, cylinders_from

from .setups import VZ400

SPEC = VZ400.spec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5)
FAST = dict(
    samples_per_tree=200,
    band_samples=60,
    candidate_spacing_m=2.0,
    grid_spacings_m=(5.0,),
    verify=False,
    dbh_arc_deg=270.0,
)


@pytest.fixture(scope="module")
def sapling():
    return species_tree_plot("sapling", facets=8)


def _plan(plot, **kw):
    return plan_scans(plot, spec=SPEC, instrument=VZ400, params=PlanParams(**FAST, **kw))


def _without_timings(d):
    return {k: v for k, v in d.items() if k != "timings_s"}


def test_wind_zero_leaves_the_plan_as_before_and_wind_does_not_move_stations(sapling):
    still = _plan(sapling).to_dict()
    zero = _plan(sapling, wind_speed_m_s=0.0).to_dict()
    assert "wind" not in still and "wind" not in zero
    assert _without_timings(zero) == _without_timings(still)
    windy = _plan(sapling, wind_speed_m_s=5.0).to_dict()
    assert windy["plan"]["stations"] == still["plan"]["stations"]
    assert windy["wind"]["wind_speed_m_s"] == 5.0
    assert _without_timings({k: v for k, v in windy.items() if k != "wind"}) == _without_timings(
        still
    )


def _oracle(plot, speed, seed, tol_m):
    """The sway figures from the wind model called directly (its public displacement)."""
    cyl = cylinders_from(plot.tree_table(1))
    cyl = cyl.shifted(cyl.start[0])
    st = Structure(cyl)  # the sapling is leaf-off
    model = SwayModel.turbulent(st, Forcing(speed, 0.0, 0.3, seed))
    roots = np.flatnonzero(st.parent_b < 0)
    stem = roots[np.argmax(st.length_b[roots])]
    n = int(round(WINDOW_S / STEP_S))
    branch = np.append(st.branch_of, stem)
    xi = np.append(st.xi_mid, 1.3 / st.length_b[stem])
    mags = np.array(
        [np.linalg.norm(model.displacement(k * STEP_S, branch, xi), axis=1) for k in range(n)]
    )
    sway = np.percentile(mags, 95.0, axis=0)
    area = 2 * np.pi * 0.5 * (cyl.radius_m + cyl.end_radius_m) * cyl.length_m
    crown = st.branch_of != stem
    c_sway, c_area = sway[:-1][crown], area[crown]
    order = np.argsort(c_sway)
    share = np.cumsum(c_area[order]) / c_area.sum()
    p95 = c_sway[order][np.argmax(share >= 0.95)]
    within = area[sway[:-1] <= tol_m].sum() / area.sum()
    return {"stem_sway_dbh_m": sway[-1], "crown_sway_p95_m": p95, "within": within}


def test_calm_wind_risks_nothing_strong_wind_risks_coverage(sapling):
    params = PlanParams(goal_coverage=0.8, tolerance_m=0.02, dbh_arc_deg=270.0, sample_seed=3)
    calm = wind_risk(sapling, params.with_(wind_speed_m_s=0.5), [1], np.array([0.95]))
    strong = wind_risk(sapling, params.with_(wind_speed_m_s=15.0), [1], np.array([0.95]))
    t_calm, t_strong = calm["trees"][0], strong["trees"][0]
    assert t_calm["goals_at_risk"] == [] and "no goal is at risk" in calm["summary"][0]
    assert "coverage" in t_strong["goals_at_risk"]
    assert "at 15 m/s the coverage goal (τ 2 cm) is at risk on 1 of 1 trees" in strong["summary"][0]
    for speed, t in ((0.5, t_calm), (15.0, t_strong)):
        o = _oracle(sapling, speed, 3, 0.02)
        assert t["stem_sway_dbh_m"] == pytest.approx(o["stem_sway_dbh_m"], rel=1e-9, abs=1e-12)
        assert t["crown_sway_p95_m"] == pytest.approx(o["crown_sway_p95_m"], rel=1e-9)
        assert t["surface_within_tolerance"] == pytest.approx(o["within"], rel=1e-9)
    o = _oracle(sapling, 0.5, 3, 0.02)
    assert o["crown_sway_p95_m"] < 0.02 and o["stem_sway_dbh_m"] < 0.02
    # the same seed, the same figures
    again = wind_risk(sapling, params.with_(wind_speed_m_s=15.0), [1], np.array([0.95]))
    assert again == strong


def test_a_tree_without_a_table_is_unknown(tmp_path, sapling, capsys):
    import trimesh

    parts = sapling.tree_parts(1)
    v = np.concatenate([p.vertices for p in parts])
    off = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    f = np.concatenate([p.faces + o for p, o in zip(parts, off, strict=True)])
    path = tmp_path / "tree.ply"
    trimesh.Trimesh(v, f, process=False).export(path)
    plot = mesh_tree_plot(path)
    block = wind_risk(plot, PlanParams(wind_speed_m_s=5.0), [1], np.array([0.9]))
    assert block["trees"][0]["status"] == "unknown"
    assert block["trees"][0]["goals_at_risk"] is None
    assert "unknown for 1 of 1 trees" in block["summary"][0]
    out = tmp_path / "p"
    rc = main(
        ["plan", "--species", "sapling", "--facets", "8", "--wind-speed-m-s", "15",
         "--dbh-arc-deg", "270", "--samples-per-tree", "200", "--band-samples", "60",
         "--resolution-deg", "0.5", "--no-verify", "--grid-spacing-m", "5", "-o", str(out)]
    )  # fmt: skip
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    d = json.loads((out / "plan.json").read_text())
    assert d["wind"]["trees"][0]["goals_at_risk"]
    assert "wind: at 15 m/s the coverage goal" in captured.out + captured.err
