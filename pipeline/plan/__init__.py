"""Scan planning: where to stand, how often, to measure a plot's trees well enough.

:func:`plan_scans` samples every tree's surface, casts rays from a grid of candidate
stations to the samples (:mod:`~treesim.plan.visibility`), chooses stations by lazy
greedy set cover and swaps (:mod:`~treesim.plan.cover`) towards a per-tree goal
(coverage at τ, DBH arc) within a budget (stations, field time), compares the plan with
the classic layouts (:mod:`~treesim.plan.layouts`) and verifies it with a full-resolution
scan (:func:`~treesim.plan.verify.verify_plan`); :func:`write_plan` writes ``plan.json``,
``stations.csv``, ``map.png`` and ``curve.png``.
"""

from typing import TYPE_CHECKING

from .._lazy import keep_functions, lazy_names

if TYPE_CHECKING:  # for readers of the source (type checkers, the API reference)
    from .cover import Objective, Selection, improve, lazy_greedy
    from .layouts import Layout, candidate_grid, classic_layouts, square_grid_xy
    from .params import PlanParams
    from .planner import PlanResult, plan_scans, tree_targets
    from .samples import SampleSet, TreeTarget, sample_trees
    from .verify import verify_plan
    from .visibility import Visibility, VisibilityCaster, max_spacing_ok, visibility

#: Every name, imported on first use (PEP 562): ``treesim plan --help`` needs the
#: parameters only, not the planner (which loads numpy and the caster).
_LAZY = {
    **dict.fromkeys(("Objective", "Selection", "improve", "lazy_greedy"), ".cover"),
    **dict.fromkeys(("Layout", "candidate_grid", "classic_layouts", "square_grid_xy"), ".layouts"),
    "PlanParams": ".params",
    **dict.fromkeys(("PlanResult", "plan_scans", "tree_targets"), ".planner"),
    **dict.fromkeys(("SampleSet", "TreeTarget", "sample_trees"), ".samples"),
    "verify_plan": ".verify",
    **dict.fromkeys(
        ("Visibility", "VisibilityCaster", "max_spacing_ok", "visibility"), ".visibility"
    ),
}


__getattr__, __dir__ = lazy_names(__name__, _LAZY)


# the function visibility shares its submodule's name
keep_functions(__name__, ["visibility"])


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
