"""What every process is made of: :class:`Input` and :class:`Process`, the validation of a
request's parameters (:func:`check_parameters`), and the schema helpers the process modules
share (a parameter model's schema less its execution-only fields, the run presets, the
flat ``resolution_deg``)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
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
    "KIND_MEDIA_TYPES",
    "Input",
    "Process",
    "Progress",
    "check_parameters",
    "field_error",
    "job_schema",
    "openapi30_schema",
    "output_ids",
    "pop_preset",
    "preset_schema",
    "resolution_schema",
]

#: A job's progress callback: fraction done in [0, 1] and a few words on the stage.
Progress = Callable[[float, str], None]


#: Media types a file input of each kind may have (its description's ``schema``).
KIND_MEDIA_TYPES: dict[str, tuple[str, ...]] = {
    "cloud": ("application/vnd.laszip", "application/vnd.las", "application/octet-stream"),
    "mesh": ("model/obj", "model/stl", "application/octet-stream"),
    "plot": ("application/zip",),
    "cylinders": ("text/csv",),
    "table": ("text/csv",),
}

_FORMATS = {
    "cloud": "LAS, LAZ, PLY, E57 or XYZ",
    "mesh": "PLY, OBJ, STL, OFF or GLB",
    "plot": "a plot archive (zip)",
    "cylinders": "a QSM cylinder table (CSV)",
    "table": "a table (CSV)",
}


@dataclass(frozen=True)
class Input:
    """One input file of a process: an upload's id or an earlier job's result."""

    name: str
    kinds: tuple[str, ...]
    description: str
    required: bool = True

    def schema(self) -> dict[str, Any]:
        """The input's entry in the process description (OGC API - Processes'
        ``inputDescription``): a file, given by reference."""
        media = [m for k in self.kinds for m in KIND_MEDIA_TYPES.get(k, ())]
        formats = " or ".join(_FORMATS.get(k, k) for k in self.kinds)
        return {
            "title": self.name,
            "description": f"{self.description} ({formats}), by reference: "
            '{"href": URL} of an upload (POST /v1/uploads) or of a result of an earlier '
            "job of this service; treesim also takes the upload's id, or "
            '{"job": JOB_ID, "result": NAME}' + ("" if self.required else "; optional"),
            "schema": {
                "anyOf": [
                    {"type": "string", "contentMediaType": m, "contentEncoding": "binary"}
                    for m in dict.fromkeys(media)
                ]
            },
            "minOccurs": 1 if self.required else 0,
            "maxOccurs": 1,
            # treesim's extension: the kinds of upload or result the input takes (a media
            # type alone cannot tell a QSM table from a stations table: both are text/csv)
            "x-treesim-kinds": list(self.kinds),
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

    def output_ids(self) -> dict[str, str]:
        """Output id → its file name: the name less its suffix, folders joined by ``_``
        (``vs_mesh/comparison.json`` → ``vs_mesh_comparison``); where two files share
        that, their ids keep the suffix (``tree_ply``, ``tree_json``)."""
        return output_ids(name for name, _ in self.outputs)

    def describe(self) -> dict[str, Any]:
        """The process description the API serves at ``/v1/processes/{id}`` (OGC API -
        Processes' ``process.yaml``, less its links): the files and every setting of the
        parameters object as inputs, each with a JSON Schema (OpenAPI 3.0's dialect); the
        outputs by id with their media types; and the parameters' own JSON Schema
        (2020-12), treesim's extension."""
        from ..jobs.worker import media_type

        parameters = self.parameters_schema()
        inputs = {i.name: i.schema() for i in self.inputs}
        for name, prop in parameters["properties"].items():
            text = prop.get("description", "")
            schema = openapi30_schema(prop)
            if name in inputs:  # a file or a value (plot-scan's stations: a CSV or a list)
                file = inputs[name]
                inputs[name] = {
                    **file,
                    "description": f"{file['description']}; or, by value: {text}",
                    "schema": {"anyOf": [*file["schema"]["anyOf"], schema]},
                }
                continue
            inputs[name] = {
                "title": name,
                "description": f"{text} (a setting; also accepted in the parameters object)",
                "schema": schema,
                "minOccurs": 0,
                "maxOccurs": 1,
            }
        files = dict(self.outputs)
        outputs = {}
        for oid, name in self.output_ids().items():
            mt = media_type(name)
            text = mt.startswith("text/") or mt == "application/json"
            outputs[oid] = {
                "title": name,
                "description": files[name],
                "schema": {
                    "type": "string",
                    "contentMediaType": mt,
                    **({} if text else {"contentEncoding": "binary"}),
                },
            }
        return {
            "id": self.id,
            "title": self.title,
            "description": self.description,
            "version": _version(),
            "inputs": inputs,
            "parameters": parameters,
            "outputs": outputs,
            "jobControlOptions": ["async-execute", "dismiss"],
            "outputTransmission": ["reference"],
        }


def output_ids(names: Iterable[str]) -> dict[str, str]:
    """Output ids for result file names (see :meth:`Process.output_ids`).

    Examples
    --------
    >>> output_ids(["tree.ply", "tree.json", "vs_mesh/comparison.json"])
    {'tree_ply': 'tree.ply', 'tree_json': 'tree.json', 'vs_mesh_comparison': 'vs_mesh/comparison.json'}
    """  # noqa: E501
    names = list(names)

    def short(name: str) -> str:
        p = PurePosixPath(name)
        return "_".join([*p.parent.parts, p.stem])

    stems = [short(n) for n in names]
    return {
        (s if stems.count(s) == 1 else short(n) + "_" + PurePosixPath(n).suffix.lstrip(".")): n
        for s, n in zip(stems, names, strict=True)
    }


def openapi30_schema(schema: Any) -> Any:
    """A JSON Schema (2020-12, as :func:`treesim.params.json_schema` writes them) in
    OpenAPI 3.0's dialect, which OGC API - Processes 1.0 descriptions use (see
    :func:`treesim.service.openapi30.schema30`), a file's media type kept.

    Examples
    --------
    >>> s = openapi30_schema({"type": "string", "contentMediaType": "application/zip"})
    >>> s["contentMediaType"]
    'application/zip'
    """
    from ..openapi30 import OGC_KEYWORDS, schema30

    return schema30(schema, OGC_KEYWORDS)


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
        if err.validator in ("maxItems", "minItems"):  # not the whole list echoed back
            most = "most" if err.validator == "maxItems" else "least"
            message = f"{len(err.instance)} items given; at {most} {err.validator_value}"
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
