"""``compare``: AVOHD both ways between a cloud and a reference, and the report (as
``treesim compare --report``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from treesim.params import CompareParams, ReportParams, json_schema, merge

from .base import Input, Process, Progress, job_schema, pop_preset, preset_schema


@dataclass(frozen=True)
class CompareJob:
    """A compare job's parameters: the comparison's and the report's."""

    compare: CompareParams
    report: ReportParams


def _compare_extra() -> dict[str, Any]:
    report = json_schema(ReportParams)
    report["description"] = "the report's plots"
    return {**preset_schema("comparison and report settings"), "report": report}


def _parse_compare(parameters: Mapping[str, Any]) -> CompareJob:
    preset, data = pop_preset(parameters)
    report_given = data.pop("report", None) or {}
    base_c = preset.compare if preset else CompareParams()
    base_r = preset.report if preset else ReportParams()
    return CompareJob(merge(base_c, data), merge(base_r, report_given))


def _execute_compare(
    inputs: Mapping[str, Path],
    params: CompareJob,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.steps import compare_files

    cp = replace(params.compare, nthreads=threads)
    result = compare_files(
        inputs["cloud"], inputs["reference"], cp, out, report=params.report, progress=progress
    )
    return result.summary


PROCESS = Process(
    id="compare",
    title="Compare a cloud with a reference (AVOHD) and report",
    description="Absolute distances both ways between a cloud and a reference mesh "
    "or cloud, coverage, and the report (as treesim compare --report).",
    inputs=(
        Input("cloud", ("cloud",), "the (simulated) point cloud"),
        Input("reference", ("mesh", "cloud"), "the reference mesh or cloud"),
    ),
    outputs=(
        ("comparison.json", "the figures"),
        ("report.html", "the report"),
    ),
    extra_schema=_compare_extra,
    base_schema=lambda: job_schema(CompareParams),
    parse=_parse_compare,
    execute=_execute_compare,
)
