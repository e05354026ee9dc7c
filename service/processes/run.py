"""``run``: the whole loop on one tree (as ``treesim run``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from treesim.params import DEFAULT_RUN_PRESET, RUN_PRESETS, RunParams, params_from_dict

from .base import CLOUD, Input, Process, Progress, job_schema


def _run_schema() -> dict[str, Any]:
    schema = job_schema(RunParams)
    schema["properties"]["preset"] = {
        "type": "string",
        "enum": list(RUN_PRESETS),
        "default": DEFAULT_RUN_PRESET,
        "description": "the run preset to start from (as treesim run --preset); the other "
        "parameters override it",
    }
    return schema


def _parse_run(parameters: Mapping[str, Any]) -> RunParams:
    return params_from_dict(parameters)


def _execute_run(
    inputs: Mapping[str, Path],
    params: RunParams,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.run import run_tree

    result = run_tree(
        inputs["cloud"],
        params.with_threads(threads),
        out,
        name=name or None,
        progress=progress,
        reference_qsm=inputs.get("reference_qsm"),
    )
    s = result.summary
    return {
        "name": s["name"],
        "params_hash": s["params_hash"],
        "reconstruction": s["reconstruction"],
        "scan": {k: s["scan"][k] for k in ("points", "rays_cast")},
        "vs_mesh": s["vs_mesh"],
        "vs_field": s["vs_field"],
        "timings_s": s["timings_s"],
        "report": "report.html",
    }


PROCESS = Process(
    id="run",
    title="The whole loop on one tree",
    description="Reconstruct a tree mesh from a field cloud, scan it with the virtual "
    "scanner, compare the simulated cloud with the mesh and with the field cloud, and "
    "report (as treesim run).",
    inputs=(
        CLOUD,
        Input(
            "reference_qsm",
            ("cylinders",),
            "a QSM cylinder table of the same tree (TreeQSM, SimpleForest or treesim "
            "CSV), set beside the reconstruction as treesim run --reference-qsm",
            required=False,
        ),
    ),
    outputs=(
        ("report.html", "the run page"),
        ("run.json", "parameters, figures and timings"),
        ("tree.ply", "the reconstructed mesh"),
        ("scan.laz", "the simulated cloud"),
        ("vs_mesh/comparison.json", "the simulated cloud against the mesh"),
        ("vs_field/comparison.json", "the simulated cloud against the field cloud"),
    ),
    extra_schema=lambda: {},
    base_schema=_run_schema,
    parse=_parse_run,
    execute=_execute_run,
)
