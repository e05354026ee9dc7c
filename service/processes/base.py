"""What every process is made of: :class:`Input` and :class:`Process`, the validation of a
request's parameters (:func:`check_parameters`), and the schema helpers the process modules
share (a parameter model's schema less its execution-only fields, the run presets, the
flat ``resolution_deg``)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from treesim.errors import InvalidParameterError
from treesim.params import (
    RUN_PRESETS,
    SETTINGS,
    RunParams,
    ScannerSpec,
    json_schema,
    run_preset,
    walk,
)

__all__ = [
    "CLOUD",
    "Input",
    "Process",
    "Progress",
    "check_parameters",
    "field_error",
    "job_schema",
    "pop_preset",
    "preset_schema",
    "resolution_schema",
]

#: A job's progress callback: fraction done in [0, 1] and a few words on the stage.
Progress = Callable[[float, str], None]


@dataclass(frozen=True)
class Input:
    """One input file of a process: an upload's id or an earlier job's result."""

    name: str
    kinds: tuple[str, ...]
    description: str
    required: bool = True

    def schema(self) -> dict[str, Any]:
        """The input's entry in the process description (OGC API - Processes)."""
        return {
            "description": f"{self.description} ({' or '.join(self.kinds)}): an upload's id, "
            'or {"job": JOB_ID, "result": NAME} for a result of an earlier successful job'
            + ("" if self.required else "; optional"),
            "minOccurs": 1 if self.required else 0,
            "maxOccurs": 1,
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
    #: checks the inputs given (their names) against the parsed parameters, where one
    #: may stand for another (a plot archive or a stand to generate): raises
    #: :class:`InvalidParameterError` with ``field``
    check_inputs: Callable[[frozenset[str], Any], None] | None = None

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
        """The process description the API serves at ``/v1/processes/{id}``."""
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
    from treesim._version import __version__

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
        raise field_error("parameters", "parameters must be an object")
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
            raise field_error(
                f"parameters.{where}{extra[0]}",
                f"unknown parameter {where}{extra[0]!r}; known here: {known}",
            )
        message = err.message
        if len(message) > 300:
            message = message[:300] + "…"
        raise field_error(f"parameters.{path}" if path else "parameters", f"{path}: {message}")
    try:
        return process.parse(parameters)
    except InvalidParameterError as exc:
        path = getattr(exc, "field", None)
        raise field_error(f"parameters.{path}" if path else "parameters", str(exc)) from None


def field_error(field: str, message: str) -> InvalidParameterError:
    """An :class:`InvalidParameterError` whose ``field`` names the parameter (the API's
    problem document points at it)."""
    exc = InvalidParameterError(message)
    exc.field = field  # type: ignore[attr-defined]
    return exc


def preset_schema(what: str) -> dict[str, Any]:
    """``preset``: start from a run preset's part named ``what`` (as the CLI's --preset)."""
    return {
        "preset": {
            "type": "string",
            "enum": list(RUN_PRESETS),
            "description": f"start from this run preset's {what} (as treesim run --preset)",
        }
    }


def pop_preset(parameters: Mapping[str, Any]) -> tuple[RunParams | None, dict[str, Any]]:
    """The run preset a request names (or None) and its other parameters."""
    data = dict(parameters)
    name = data.pop("preset", None)
    return (run_preset(str(name)) if name is not None else None), data


def job_schema(cls: type) -> dict[str, Any]:
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


def resolution_schema() -> dict[str, Any]:
    """``resolution_deg`` (the flat setting, as treesim scan --resolution-deg): the schema
    of the angular step it sets on both axes (its range and unit), less the default, which
    comes from the preset or the instrument."""
    setting = SETTINGS["resolution_deg"]
    step = json_schema(ScannerSpec)["properties"][setting.paths[0][-1]]
    step.pop("default")
    return {**step, "description": setting.help}


#: The one field cloud that ``run`` and ``reconstruct`` read.
CLOUD = Input("cloud", ("cloud",), "a point cloud of one tree")
