"""``scan``: a simulated TLS cloud of a mesh (as ``treesim scan``). Its extra parameters
(preset, instrument, beam, noise, resolution) and their parsing serve ``plot-scan`` too."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from treesim.params import INSTRUMENTS, ScanParams, scan_params

from .base import (
    Input,
    Process,
    Progress,
    job_schema,
    pop_preset,
    preset_schema,
    resolution_schema,
)


def scan_extra() -> dict[str, Any]:
    """The flat settings a scan job takes beside ScanParams (as treesim scan's options)."""
    return {
        **preset_schema("stations and scanner"),
        "instrument": {
            "type": "string",
            "enum": list(INSTRUMENTS),
            "description": "start from a real instrument's figures (as treesim scan --instrument)",
        },
        "beam": {
            "type": "boolean",
            "default": False,
            "description": "turn on the beam divergence model: the instrument's, or a "
            "generic TLS's without one (as treesim scan --beam)",
        },
        "noise": {
            "type": "boolean",
            "default": False,
            "description": "turn on range noise and angular jitter: the instrument's, or a "
            "generic TLS's without one (as treesim scan --noise)",
        },
        "resolution_deg": resolution_schema(),
    }


def parse_scan(parameters: Mapping[str, Any]) -> ScanParams:
    """ScanParams from a request: the preset, then the instrument and the flat settings."""
    preset, data = pop_preset(parameters)
    return scan_params(
        data,
        base=preset.scan if preset else None,
        instrument=data.pop("instrument", None),
        beam=bool(data.pop("beam", False)),
        noise=bool(data.pop("noise", False)),
        resolution_deg=data.pop("resolution_deg", None),
    )


def _execute_scan(
    inputs: Mapping[str, Path],
    params: ScanParams,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.steps import scan_files

    result = scan_files(
        [inputs["mesh"]], params, out / "scan.laz", threads=threads, progress=progress
    )
    return result.summary


PROCESS = Process(
    id="scan",
    title="Scan a mesh with the virtual TLS scanner",
    description="A simulated TLS cloud of a mesh from a ring of stations (as treesim scan).",
    inputs=(Input("mesh", ("mesh",), "the scene: a tree mesh"),),
    outputs=(
        ("scan.laz", "the simulated cloud with per-point fields"),
        ("scan.json", "scanner settings, stations, rays and timings"),
    ),
    extra_schema=scan_extra,
    base_schema=lambda: job_schema(ScanParams),
    parse=parse_scan,
    execute=_execute_scan,
)
