"""Scan planning: where to stand, how often, to measure a plot's trees well enough.

:func:`plan_scans` samples every tree's surface, casts rays from a grid of candidate
stations to the samples (:mod:`~treesim.plan.visibility`), chooses stations by lazy
greedy set cover and swaps (:mod:`~treesim.plan.cover`) towards a per-tree goal
(coverage at τ, DBH arc) within a budget (stations, field time), compares the plan with
the classic layouts (:mod:`~treesim.plan.layouts`) and verifies it with a full-resolution
scan (:func:`~treesim.plan.verify.verify_plan`); :func:`write_plan` writes ``plan.json``,
``stations.csv``, ``map.png`` and ``curve.png``.
"""

from .cover import Objective, Selection, improve, lazy_greedy
from .layouts import Layout, candidate_grid, classic_layouts, square_grid_xy
from .params import PlanParams
from .planner import PlanResult, plan_scans, tree_targets
from .samples import SampleSet, TreeTarget, sample_trees
from .verify import verify_plan
from .visibility import Visibility, VisibilityCaster, max_spacing_ok, visibility

__all__ = [
    "Layout",
    "Objective",
    "PlanParams",
    "PlanResult",
    "SampleSet",
    "Selection",
    "TreeTarget",
    "Visibility",
    "VisibilityCaster",
    "candidate_grid",
    "classic_layouts",
    "improve",
    "lazy_greedy",
    "max_spacing_ok",
    "plan_scans",
    "sample_trees",
    "square_grid_xy",
    "tree_targets",
    "verify_plan",
    "visibility",
]
