"""``reconstruct``: a tree mesh from a field cloud (as ``treesim reconstruct``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from treesim.params import ReconstructParams, merge

from .base import CLOUD, Process, Progress, job_schema, pop_preset, preset_schema


def _parse_reconstruct(parameters: Mapping[str, Any]) -> ReconstructParams:
    preset, data = pop_preset(parameters)
    return merge(preset.reconstruct if preset else ReconstructParams(), data)


def _execute_reconstruct(
    inputs: Mapping[str, Path],
    params: ReconstructParams,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.steps import reconstruct_files

    result = reconstruct_files(inputs["cloud"], params, out, threads=threads, progress=progress)
    return result.summary


PROCESS = Process(
    id="reconstruct",
    title="Reconstruct a tree mesh",
    description="A tree mesh from a field cloud: cylinder QSM, screened Poisson or "
    "ball pivoting (as treesim reconstruct).",
    inputs=(CLOUD,),
    outputs=(
        ("tree.ply", "the tree mesh, labelled wood"),
        ("cylinders.csv", "the QSM's cylinders (qsm only)"),
        ("tree.json", "DBH, height, volumes and what preparation removed"),
    ),
    extra_schema=lambda: preset_schema("reconstruction settings"),
    base_schema=lambda: job_schema(ReconstructParams),
    parse=_parse_reconstruct,
    execute=_execute_reconstruct,
)
