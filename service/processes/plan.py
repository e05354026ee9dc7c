"""``plan``: scan stations for a plot or a tree, chosen to meet a goal within a budget
(as ``treesim plan``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from treesim.errors import InvalidParameterError
from treesim.params import INSTRUMENTS, ScannerSpec, merge

from .base import Process, Progress, field_error, job_schema, resolution_schema
from .sources import PLOT_INPUTS, STAND_OUTPUTS, check_source, pop_source, source_schema


@dataclass(frozen=True)
class PlanJob:
    """A plan job's parameters: the plan's, the instrument (its name and its scanner at
    the resolution asked) and where the plot comes from."""

    plan: Any  # PlanParams
    instrument: str
    spec: ScannerSpec
    source: Any  # PlotSource


def _plan_extra() -> dict[str, Any]:
    from treesim.plan.params import DEFAULT_INSTRUMENT

    res = resolution_schema()
    res["description"] += (
        " (default the instrument's): sets the visibility rule's point spacing, the field "
        "time and the verification scans"
    )
    return {
        "instrument": {
            "type": "string",
            "enum": list(INSTRUMENTS),
            "default": DEFAULT_INSTRUMENT,
            "description": "the instrument: field of view, ranges, measurement rate and "
            "set-up time (as treesim plan --instrument)",
        },
        "resolution_deg": res,
        **source_schema(),
    }


def _plan_schema() -> dict[str, Any]:
    from treesim.plan.params import PlanParams

    return job_schema(PlanParams)


def _with_resolution(spec: ScannerSpec, resolution_deg: Any) -> ScannerSpec:
    if resolution_deg is None:
        return spec
    try:
        return spec.with_(
            horizontal_resolution_deg=resolution_deg, vertical_resolution_deg=resolution_deg
        )
    except InvalidParameterError as exc:
        raise field_error("resolution_deg", f"resolution_deg: {exc}") from None


def _parse_plan(parameters: Mapping[str, Any]) -> PlanJob:
    from treesim.params import instrument
    from treesim.plan.params import DEFAULT_INSTRUMENT, PlanParams

    data = dict(parameters)
    source = pop_source(data)
    name = str(data.pop("instrument", DEFAULT_INSTRUMENT))
    spec = _with_resolution(instrument(name).spec(), data.pop("resolution_deg", None))
    return PlanJob(merge(PlanParams(), data), name, spec, source)


def _execute_plan(
    inputs: Mapping[str, Path],
    job: PlanJob,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.params import instrument
    from treesim.plan import plan_scans
    from treesim.plan.outputs import write_plan
    from treesim.steps import scale_progress

    from ..plots import open_plot

    inst = instrument(job.instrument)
    with open_plot(job.source, inputs, out) as (plot, single, what):
        progress(0.0, "planning")
        result = plan_scans(
            plot,
            spec=job.spec,
            instrument=inst,
            params=job.plan.with_(threads=threads),
            progress=scale_progress(progress, 0.0, 0.95),
            single_tree=single,
        )
        progress(0.95, "writing the plan")
        given = {**what, "instrument": inst.name}
        given["resolution_deg"] = job.spec.horizontal_resolution_deg
        written = write_plan(result, out, inputs=given)
    d = result.to_dict()
    plan = d["plan"]
    ver = d["comparison"].get("verified")
    return {
        "inputs": given,
        "n_stations": plan["n_stations"],
        "field_time_min": plan["field_time_min"],
        "goal_met": plan["goal_met"],
        "trees_meeting_goal": plan["trees_meeting_goal"],
        "trees": plan["trees"],
        "stop_reason": plan["stop_reason"],
        "stations": plan["stations"],
        "unreachable_trees": d["unreachable_trees"],
        "statement": d["comparison"]["statement"],
        "verified": ver,
        "timings_s": d["timings_s"],
        "files": list(written),
    }


PROCESS = Process(
    id="plan",
    title="Plan scan stations for a plot or a tree",
    description="Choose scanner stations from a grid of candidates over a plot (or "
    "around one tree) so that every tree meets a goal (coverage at a tolerance, the "
    "DBH band seen over an arc) within a budget (stations, field time); compare with "
    "the classic layouts and, unless verify is off, verify with a full-resolution "
    "scan (as treesim plan).",
    inputs=PLOT_INPUTS,
    outputs=(
        ("plan.json", "goal, budget, chosen stations, per-tree figures, baselines"),
        ("stations.csv", "the chosen stations: order, x, y, z, field time"),
        ("map.png", "the plot with the stations and per-tree coverage"),
        ("curve.png", "coverage and field time against the number of stations"),
        *STAND_OUTPUTS,
    ),
    extra_schema=_plan_extra,
    base_schema=_plan_schema,
    parse=_parse_plan,
    execute=_execute_plan,
    check_inputs=check_source,
)
