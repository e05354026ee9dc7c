"""The processes the service runs as jobs: ``run``, ``reconstruct``, ``scan``, ``compare``.

Each is a thin adapter over one :mod:`pipeline` function: its inputs (files, by kind), the
JSON Schema of its parameters (generated from the parameter model,
:func:`pipeline.params.json_schema`, plus the preset names the CLI takes), how a request's
parameters become the parameter dataclass (:func:`pipeline.params.merge` decides), and the
call that runs it in a job's process. A new process is one more entry in
:data:`PROCESSES`; nothing else in the service names a parameter.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pipeline.errors import InvalidParameterError
from pipeline.params import (
    DEFAULT_RUN_PRESET,
    INSTRUMENTS,
    RUN_PRESETS,
    SETTINGS,
    CompareParams,
    ReconstructParams,
    ReportParams,
    RunParams,
    ScannerSpec,
    ScanParams,
    json_schema,
    merge,
    params_from_dict,
    run_preset,
    scan_params,
    walk,
)

__all__ = ["PROCESSES", "Input", "Process", "check_parameters"]

Progress = Callable[[float, str], None]


@dataclass(frozen=True)
class Input:
    """One input file of a process: an upload's id or an earlier job's result."""

    name: str
    kinds: tuple[str, ...]
    description: str

    def schema(self) -> dict[str, Any]:
        return {
            "description": f"{self.description} ({' or '.join(self.kinds)}): an upload's id, "
            'or {"job": JOB_ID, "result": NAME} for a result of an earlier successful job',
            "oneOf": [
                {"type": "string", "description": "upload id"},
                {
                    "type": "object",
                    "properties": {"job": {"type": "string"}, "result": {"type": "string"}},
                    "required": ["job", "result"],
                    "additionalProperties": False,
                },
            ],
        }


@dataclass(frozen=True)
class Process:
    """A process: what it reads, which parameters it takes, what it writes."""

    id: str
    title: str
    description: str
    inputs: tuple[Input, ...]
    outputs: tuple[tuple[str, str], ...]
    extra_schema: Callable[[], dict[str, Any]]
    base_schema: Callable[[], dict[str, Any]]
    parse: Callable[[Mapping[str, Any]], Any]
    execute: Callable[[Mapping[str, Path], Any, Path, int, Progress, str], dict[str, Any]]

    def parameters_schema(self) -> dict[str, Any]:
        """JSON Schema (2020-12) of the ``parameters`` object of a job of this process."""
        base = self.base_schema()
        props = {**self.extra_schema(), **base["properties"]}
        props.pop("threads", None)  # the worker sets it (TREESIM_JOB_THREADS)
        return {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": f"{self.id} parameters",
            "description": base.get("description", ""),
            "type": "object",
            "properties": props,
            "additionalProperties": False,
        }

    def describe(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "title": self.title,
            "description": self.description,
            "version": _version(),
            "inputs": {i.name: i.schema() for i in self.inputs},
            "parameters": self.parameters_schema(),
            "outputs": {name: {"description": d} for name, d in self.outputs},
            "jobControlOptions": ["async-execute", "dismiss"],
        }


def _version() -> str:
    from pipeline._version import __version__

    return __version__


#: JSON Schema keywords of a number's range: the schema states it, the model words it.
_RANGE_KEYWORDS = frozenset({"minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"})


def _out_of_range(err: Any) -> bool:
    """Whether a schema error is only a number outside its declared range (also inside an
    optional field's ``anyOf``): the parameter model refuses the same values (one range,
    ``param(ge=...)``) and says so in the command line's words."""
    if err.validator in _RANGE_KEYWORDS:
        return True
    return err.validator == "anyOf" and any(_out_of_range(c) for c in err.context)


def check_parameters(process: Process, parameters: Mapping[str, Any]) -> Any:
    """Validate a request's parameters: against the JSON Schema first (so an unknown or
    mistyped field is named by its path), then by the parameter model (which also words a
    value out of its range). Returns the parameter object; raises
    :class:`InvalidParameterError` (its ``field`` attribute names the parameter)."""
    import jsonschema

    if not isinstance(parameters, Mapping):
        raise _field_error("parameters", "parameters must be an object")
    validator = jsonschema.Draft202012Validator(process.parameters_schema())
    errors = sorted(
        (e for e in validator.iter_errors(dict(parameters)) if not _out_of_range(e)),
        key=lambda e: list(e.path),
    )
    if errors:
        err = errors[0]
        path = ".".join(str(p) for p in err.path)
        if err.validator == "additionalProperties":
            extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
            where = f"{path}." if path else ""
            known = ", ".join(err.schema.get("properties", {}))
            raise _field_error(
                f"parameters.{where}{extra[0]}",
                f"unknown parameter {where}{extra[0]!r}; known here: {known}",
            )
        message = err.message
        if len(message) > 300:
            message = message[:300] + "…"
        raise _field_error(f"parameters.{path}" if path else "parameters", f"{path}: {message}")
    try:
        return process.parse(parameters)
    except InvalidParameterError as exc:
        path = getattr(exc, "field", None)
        raise _field_error(f"parameters.{path}" if path else "parameters", str(exc)) from None


def _field_error(field: str, message: str) -> InvalidParameterError:
    exc = InvalidParameterError(message)
    exc.field = field  # type: ignore[attr-defined]
    return exc


def _preset_schema(what: str) -> dict[str, Any]:
    return {
        "preset": {
            "type": "string",
            "enum": list(RUN_PRESETS),
            "description": f"start from this run preset's {what} (as treesim run --preset)",
        }
    }


def _pop_preset(parameters: Mapping[str, Any]) -> tuple[RunParams | None, dict[str, Any]]:
    data = dict(parameters)
    name = data.pop("preset", None)
    return (run_preset(str(name)) if name is not None else None), data


# -- run --------------------------------------------------------------------------------------
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
    from pipeline.run import run_tree

    result = run_tree(
        inputs["cloud"], params.with_threads(threads), out, name=name or None, progress=progress
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


# -- reconstruct ------------------------------------------------------------------------------
def _parse_reconstruct(parameters: Mapping[str, Any]) -> ReconstructParams:
    preset, data = _pop_preset(parameters)
    return merge(preset.reconstruct if preset else ReconstructParams(), data)


def _execute_reconstruct(
    inputs: Mapping[str, Path],
    params: ReconstructParams,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from pipeline.steps import reconstruct_files

    result = reconstruct_files(inputs["cloud"], params, out, threads=threads, progress=progress)
    return result.summary


# -- scan -------------------------------------------------------------------------------------
def _scan_extra() -> dict[str, Any]:
    return {
        **_preset_schema("stations and scanner"),
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
        "resolution_deg": _resolution_schema(),
    }


def _resolution_schema() -> dict[str, Any]:
    """``resolution_deg`` (the flat setting, as treesim scan --resolution-deg): the schema
    of the angular step it sets on both axes (its range and unit), less the default, which
    comes from the preset or the instrument."""
    setting = SETTINGS["resolution_deg"]
    step = json_schema(ScannerSpec)["properties"][setting.paths[0][-1]]
    step.pop("default")
    return {**step, "description": setting.help}


def _parse_scan(parameters: Mapping[str, Any]) -> ScanParams:
    preset, data = _pop_preset(parameters)
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
    from pipeline.steps import scan_files

    result = scan_files(
        [inputs["mesh"]], params, out / "scan.laz", threads=threads, progress=progress
    )
    return result.summary


# -- compare ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class CompareJob:
    compare: CompareParams
    report: ReportParams


def _compare_extra() -> dict[str, Any]:
    report = json_schema(ReportParams)
    report["description"] = "the report's plots"
    return {**_preset_schema("comparison and report settings"), "report": report}


def _parse_compare(parameters: Mapping[str, Any]) -> CompareJob:
    preset, data = _pop_preset(parameters)
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
    from pipeline.steps import compare_files

    cp = replace(params.compare, nthreads=threads)
    result = compare_files(
        inputs["cloud"], inputs["reference"], cp, out, report=params.report, progress=progress
    )
    return result.summary


_CLOUD = Input("cloud", ("cloud",), "a point cloud of one tree")

#: The processes by id.
PROCESSES: dict[str, Process] = {
    p.id: p
    for p in (
        Process(
            id="run",
            title="The whole loop on one tree",
            description="Reconstruct a tree mesh from a field cloud, scan it with the virtual "
            "scanner, compare the simulated cloud with the mesh and with the field cloud, and "
            "report (as treesim run).",
            inputs=(_CLOUD,),
            outputs=(
                ("report.html", "the run page"),
                ("run.json", "parameters, figures and timings"),
                ("tree.ply", "the reconstructed mesh"),
                ("scan.laz", "the simulated cloud"),
                ("vs_mesh/comparison.json", "the simulated cloud against the mesh"),
                ("vs_field/comparison.json", "the simulated cloud against the field cloud"),
            ),
            extra_schema=lambda: {},
            base_schema=lambda: _run_schema(),
            parse=_parse_run,
            execute=_execute_run,
        ),
        Process(
            id="reconstruct",
            title="Reconstruct a tree mesh",
            description="A tree mesh from a field cloud: cylinder QSM, screened Poisson or "
            "ball pivoting (as treesim reconstruct).",
            inputs=(_CLOUD,),
            outputs=(
                ("tree.ply", "the tree mesh, labelled wood"),
                ("cylinders.csv", "the QSM's cylinders (qsm only)"),
                ("tree.json", "DBH, height, volumes and what preparation removed"),
            ),
            extra_schema=lambda: _preset_schema("reconstruction settings"),
            base_schema=lambda: _job_schema(ReconstructParams),
            parse=_parse_reconstruct,
            execute=_execute_reconstruct,
        ),
        Process(
            id="scan",
            title="Scan a mesh with the virtual TLS scanner",
            description="A simulated TLS cloud of a mesh from a ring of stations (as treesim "
            "scan).",
            inputs=(Input("mesh", ("mesh",), "the scene: a tree mesh"),),
            outputs=(
                ("scan.laz", "the simulated cloud with per-point fields"),
                ("scan.json", "scanner settings, stations, rays and timings"),
            ),
            extra_schema=_scan_extra,
            base_schema=lambda: _job_schema(ScanParams),
            parse=_parse_scan,
            execute=_execute_scan,
        ),
        Process(
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
            base_schema=lambda: _job_schema(CompareParams),
            parse=_parse_compare,
            execute=_execute_compare,
        ),
    )
}


def _job_schema(cls: type) -> dict[str, Any]:
    """The parameter model's JSON Schema less its execution-only fields (threads): the
    worker decides those (``TREESIM_JOB_THREADS``), and they never change a result."""
    schema = json_schema(cls)
    for info in walk(cls):
        if info.execution_only:
            node = schema
            for key in info.path[:-1]:
                node = node["properties"][key]
            node["properties"].pop(info.path[-1], None)
            if info.path[-1] in node.get("required", []):
                node["required"].remove(info.path[-1])
    return schema


def _run_schema() -> dict[str, Any]:
    schema = _job_schema(RunParams)
    schema["properties"]["preset"] = {
        "type": "string",
        "enum": list(RUN_PRESETS),
        "default": DEFAULT_RUN_PRESET,
        "description": "the run preset to start from (as treesim run --preset); the other "
        "parameters override it",
    }
    return schema
