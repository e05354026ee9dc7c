"""Planner run time against the number of candidates and against the scene's size.

Two series on one seeded plot of procedural trees (``aspen``, leaf-off, on flat ground;
no verification scan, which is a scan's cost, measured by ``bench_scan.py``):

1. **Candidates.** Tubes at 16 facets; candidate grid spacings chosen to give roughly
   25 to 400 candidates. Expected: the visibility step (rays to the samples of the trees
   in each candidate's range) and the choice grow linearly with the candidates.
2. **Scene size.** Candidates fixed; tubes at 8, 16, 32 and 64 facets per ring (the
   triangles grow ~8×). Expected: the visibility step grows far slower than the triangles
   (rays × the BVH's traversal); what grows with them is mostly paid once per plan:
   building the ray-casting scene and the per-tree sampling (its hidden-surface test
   casts lines through the tree).
3. ``--acceptance``: issue 14's cases (``tests/plan/setups.py``, which the acceptance
   tests assert on): the 20-sapling plot against the classic layouts, verified; the
   single tree's ring; the model's error against a scan on saplings and firs.

Each row prints the planner's own ``timings_s`` (``plan.json``). Usage:
``python benchmarks/bench_plan.py [--quick] [--acceptance]`` (``--quick``: 4 trees, fewer points).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.plan.setups import (  # noqa: E402
    acceptance_plan,
    model_check,
    ring_gaps_deg,
    ring_plan,
    spaced_plot,
)
from treesim.params import instrument  # noqa: E402
from treesim.plan import PlanParams, plan_scans  # noqa: E402
from treesim.plot import Plot  # noqa: E402


def stand(n: int, radius_m: float, facets: int, seed: int = 3) -> Plot:
    """``n`` leaf-off aspens at least 4 m apart."""
    return spaced_plot(
        n, radius_m, species="aspen", min_gap_m=4.0, margin_m=1.0, facets=facets, seed=seed,
        leaves=False,
    )  # fmt: skip


def acceptance() -> None:
    """Issue 14's acceptance cases (``tests/plan/setups.py``), with the figures the
    manual quotes (docs/validation.md; --docs writes them)."""
    t0 = time.perf_counter()
    r = acceptance_plan()
    d = r.to_dict()
    c = d["comparison"]
    print(
        f"\n3. acceptance: 20 saplings, goal 0.8 at 3 cm + 270° DBH arc, VZ-400 at 0.2° "
        f"({d['candidates']['count']} candidates; {time.perf_counter() - t0:.1f} s)"
    )
    print(f"   plan: {d['plan']['n_stations']} stations, {d['plan']['field_time_min']:.1f} min")
    for b in d["baselines"]:
        print(
            f"   {b['name']:<12} {b['n_stations']:>3} stations {b['field_time_min']:>6.1f} min"
            f"  goal met by the model: {b['trees_meeting_goal']}/{len(r.targets)}"
        )
    v = c.get("verified", {})
    print(f"   predicted: {c['predicted']['verdict']}: {c['predicted']['statement']}")
    print(
        f"   verified: plan {v.get('plan_trees_meeting_goal')}/{v.get('trees')}, "
        f"{v.get('baseline')} {v.get('baseline_trees_meeting_goal')}/{v.get('trees')}: "
        f"{c['verdict']}: {c['statement']}"
    )
    ver = r.verification["trees"]
    err = np.array(
        [r.predicted["coverage"][i] - ver[t.tree_id]["coverage"] for i, t in enumerate(r.targets)]
    )
    print(
        f"   predicted - verified coverage per tree: {err.min():+.3f} .. {err.max():+.3f} "
        f"(mean {err.mean():+.3f})"
    )
    rr = ring_plan()
    gaps, tol = ring_gaps_deg(rr)
    print(
        f"\n4. one sapling, DBH band all round: {len(rr.selection.chosen)} stations, gaps "
        f"{', '.join(f'{g:.1f}' for g in gaps)}° (grid resolution {tol:.1f}°)"
    )
    m, _, e = model_check()
    print(
        f"\n5. 5 saplings and firs at 0.3°, {len(m.stations)} stations: predicted - scanned "
        f"coverage per tree, mean |error| {np.mean(np.abs(e)):.3f}, max {np.max(np.abs(e)):.3f}"
    )


def run(plot: Plot, spacing: float, samples: int) -> dict:
    inst = instrument("riegl-vz400")
    spec = inst.spec()
    for t in plot.trees:  # meshing the trees is the generator's cost, not the planner's
        plot.tree_parts(t.tree_id)
    t0 = time.perf_counter()
    r = plan_scans(
        plot,
        spec=spec,
        instrument=inst,
        params=PlanParams(candidate_spacing_m=spacing, samples_per_tree=samples, verify=False),
    )
    wall = time.perf_counter() - t0
    d = r.to_dict()
    tm = d["timings_s"]
    return {
        "candidates": d["candidates"]["count"],
        "triangles": d["plot"]["triangles"],
        "rays": d["candidates"]["rays_cast"],
        "stations": d["plan"]["n_stations"],
        "sampling": tm["sampling"],
        "build": tm["scene_build"],
        "visibility": tm["visibility"],
        "choice": tm["greedy"] + tm["swap_search"],
        "baselines": tm["baselines"],
        "total": wall,
    }


HEAD = (
    f"{'candidates':>10} {'triangles':>10} {'rays':>10} {'stations':>8} {'sampling s':>10} "
    f"{'build s':>8} {'visib. s':>8} {'µs/ray':>7} {'choice s':>8} {'baselines s':>11} "
    f"{'total s':>8}"
)


def line(r: dict) -> str:
    return (
        f"{r['candidates']:>10} {r['triangles']:>10,} {r['rays']:>10,} {r['stations']:>8} "
        f"{r['sampling']:>10.2f} {r['build']:>8.2f} {r['visibility']:>8.2f} "
        f"{1e6 * r['visibility'] / max(1, r['rays']):>7.2f} {r['choice']:>8.2f} "
        f"{r['baselines']:>11.2f} {r['total']:>8.2f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--acceptance", action="store_true", help="also run issue 14's acceptance cases"
    )
    args = ap.parse_args()
    n, radius, samples = (4, 10.0, 500) if args.quick else (8, 12.0, 1000)
    print(
        f"bench_plan.py, {date.today()}, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores; {n} aspens (leaf-off) in a {radius:g} m plot, "
        f"{samples} samples per tree, riegl-vz400 at 0.04°, no verification"
    )
    print("\n1. against the number of candidates (16 facets)")
    print(HEAD)
    plot = stand(n, radius, 16)
    for spacing in (4.0, 2.0, 1.0) if args.quick else (4.0, 2.5, 1.5, 1.0):
        print(line(run(plot, spacing, samples)), flush=True)
    print("\n2. against the scene's size (candidate spacing 2 m)")
    print(HEAD)
    for facets in (8, 16, 32) if args.quick else (8, 16, 32, 64):
        print(line(run(stand(n, radius, facets), 2.0, samples)), flush=True)
    if args.acceptance:
        acceptance()


if __name__ == "__main__":
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("bench-plan"), "bench_plan.py"):
        main()
