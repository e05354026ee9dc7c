"""The planner's acceptance set-ups, shared by its tests and ``benchmarks/bench_plan.py
--acceptance`` (which prints the figures docs/validation.md quotes)."""

from __future__ import annotations

from typing import Any

import numpy as np

from treesim.params import instrument
from treesim.plan import PlanParams, plan_scans, verify_plan
from treesim.plan.sources import species_tree_plot
from treesim.plot import Plot, PlotTree
from treesim.plot.generate import generate_stand

VZ400 = instrument("riegl-vz400")
#: The single-tree ring case: candidate spacing (m) and the DBH arc goal (deg).
RING_SPACING_M = 0.25
RING_ARC_DEG = 350.0


def spaced_plot(
    n: int,
    radius_m: float,
    *,
    species: str,
    min_gap_m: float,
    margin_m: float,
    facets: int,
    seed: int,
    leaves: bool | None = None,
) -> Plot:
    """``n`` trees of one species at seeded uniform positions in the plot's disc (``margin_m``
    inside its edge), at least ``min_gap_m`` apart, each turned at random."""
    rng = np.random.default_rng(seed)
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = rng.uniform(-radius_m, radius_m, 2)
        if np.hypot(*p) <= radius_m - margin_m and all(
            np.hypot(*(p - q)) >= min_gap_m for q in pts
        ):
            pts.append(p)
    trees = [
        PlotTree(
            tree_id=i + 1,
            x_m=float(x),
            y_m=float(y),
            rotation_deg=float(rng.uniform(0, 360)),
            species=species,
            seed=i,
            leaves=leaves,
        )
        for i, (x, y) in enumerate(pts)
    ]
    return Plot(trees, radius_m=radius_m, facets=facets)


def sapling_plot(n: int = 20, radius_m: float = 8.0, seed: int = 1) -> Plot:
    """``n`` saplings at seeded random positions at least 1.5 m apart in a plot."""
    return spaced_plot(
        n, radius_m, species="sapling", min_gap_m=1.5, margin_m=0.5, facets=8, seed=seed
    )


def acceptance_plan() -> Any:
    """Issue 14's plot case: 20 saplings, goal coverage 0.8 at τ 3 cm and a 270° DBH arc,
    VZ-400 at 0.2°, candidates 1 m apart, verified."""
    spec = VZ400.spec(horizontal_resolution_deg=0.2, vertical_resolution_deg=0.2)
    params = PlanParams(
        goal_coverage=0.8,
        tolerance_m=0.03,
        dbh_arc_deg=270.0,
        samples_per_tree=600,
        candidate_spacing_m=1.0,
    )
    return plan_scans(sapling_plot(), spec=spec, instrument=VZ400, params=params)


def ring_plan() -> Any:
    """Issue 14's single-tree case: a sapling's DBH band seen all round (every sector),
    at 0.25° and τ 1 cm, candidates 1.5-4 m away."""
    plot = species_tree_plot("sapling", seed=0, facets=12, radius_m=4.0)
    spec = VZ400.spec(horizontal_resolution_deg=0.25, vertical_resolution_deg=0.25)
    return plan_scans(
        plot,
        spec=spec,
        instrument=VZ400,
        single_tree=True,
        params=PlanParams(
            goal_coverage=0.0,
            dbh_arc_deg=RING_ARC_DEG,
            tolerance_m=0.01,
            candidate_spacing_m=RING_SPACING_M,
            clearance_m=1.5,
            verify=False,
        ),
    )


def ring_gaps_deg(r: Any) -> tuple[np.ndarray, float]:
    """The angular gaps between the chosen stations round the stem, and the candidate
    grid's angular resolution at the nearest of them (deg)."""
    axis = r.samples.stem_xy[0]
    st = r.candidates[r.selection.chosen]
    ang = np.sort(np.degrees(np.arctan2(st[:, 1] - axis[1], st[:, 0] - axis[0])) % 360)
    gaps = np.diff(np.append(ang, ang[0] + 360))
    d_min = float(np.hypot(st[:, 0] - axis[0], st[:, 1] - axis[1]).min())
    return gaps, float(np.degrees(2 * RING_SPACING_M / d_min))


def model_check() -> tuple[Any, Plot, np.ndarray]:
    """Saplings and balsam firs on a small plot at 0.3°: the plan, the plot, and the
    predicted minus the full scan's coverage per tree (the planner's own samples)."""
    plot, _ = generate_stand("sapling:0.5,balsam-fir:0.5", 600, 5.0, seed=1, facets=8)
    spec = VZ400.spec(horizontal_resolution_deg=0.3, vertical_resolution_deg=0.3)
    r = plan_scans(
        plot,
        spec=spec,
        instrument=VZ400,
        params=PlanParams(
            goal_coverage=0.7,
            samples_per_tree=300,
            band_samples=60,
            candidate_spacing_m=2.0,
            verify=False,
        ),
    )
    ver = verify_plan(plot, r.stations, spec, r.targets, r.samples, r.objective, tolerance_m=0.02)
    got = np.array([ver["trees"][t.tree_id]["coverage_samples"] for t in r.targets])
    return r, plot, r.predicted["coverage"] - got


def verification_case() -> tuple[Any, Any, Any, Any]:
    """A small plan to verify on several executors or in sectors (a sapling stand, 0.5°
    steps, the plan's own verification off): ``(plot, spec, result, figures)``, where
    ``figures(**kw)`` is :func:`verify_plan` of the plan's stations with ``kw`` (its
    ``timings_s`` left out: they differ run to run)."""
    plot, _ = generate_stand("sapling", 600, 4.0, seed=1, facets=8)
    spec = VZ400.spec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5)
    params = PlanParams(
        goal_coverage=0.5, samples_per_tree=100, band_samples=36, candidate_spacing_m=2.0,
        verify=False,
    )  # fmt: skip
    r = plan_scans(plot, spec=spec, instrument=VZ400, params=params)

    def figures(**kw: Any) -> dict[str, Any]:
        v = verify_plan(
            plot, r.stations, spec, r.targets, r.samples, r.objective, tolerance_m=0.02, **kw
        )
        v.pop("timings_s")
        return v

    return plot, spec, r, figures
