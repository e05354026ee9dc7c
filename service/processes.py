"""The processes the service runs as jobs: ``run``, ``reconstruct``, ``scan``, ``compare``,
``plan`` and ``plot-scan``.

Each is a thin adapter over one :mod:`treesim` function: its inputs (files, by kind), the
JSON Schema of its parameters (generated from the parameter model,
:func:`treesim.params.json_schema`, plus the preset names the CLI takes), how a request's
parameters become the parameter dataclass (:func:`treesim.params.merge` decides), and the
call that runs it in a job's process. A new process is one more entry in
:data:`PROCESSES`; nothing else in the service names a parameter.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from treesim.errors import InvalidParameterError
from treesim.params import (
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
    required: bool = True

    def schema(self) -> dict[str, Any]:
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
    from treesim.steps import reconstruct_files

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
    from treesim.steps import scan_files

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
    from treesim.steps import compare_files

    cp = replace(params.compare, nthreads=threads)
    result = compare_files(
        inputs["cloud"], inputs["reference"], cp, out, report=params.report, progress=progress
    )
    return result.summary


# -- plots: where a plan or a plot scan gets its plot ------------------------------------------
def _source_schema() -> dict[str, Any]:
    """``stand``, ``tree`` and ``radius_m``: a plot made by the job instead of one uploaded."""
    from treesim.models import SPECIES
    from treesim.params.models import ModelParams
    from treesim.plot.generate import StandParams

    stand = json_schema(StandParams)
    stand["description"] = (
        "generate a stand instead of giving inputs.plot (as treesim plot generate); its "
        "plot.toml and trees.csv come back under stand/"
    )
    tree = json_schema(ModelParams)
    tree["properties"] = {
        k: v for k, v in tree["properties"].items() if k in ("species", "seed", "leaves", "facets")
    }
    tree["properties"]["species"] = {
        "type": "string",
        "enum": list(SPECIES),
        "description": tree["properties"]["species"]["description"],
    }
    tree["required"] = ["species"]
    tree["description"] = "one procedural tree instead of a plot (as treesim plan --species)"
    return {
        "stand": stand,
        "tree": tree,
        "radius_m": {
            "type": "number",
            "exclusiveMinimum": 0,
            "maximum": 1000,
            "x-unit": "m",
            "description": "one tree (inputs.mesh or tree): radius of the area around it "
            "(default 1.5 x the station rule's distance)",
        },
    }


def _pop_source(data: dict[str, Any]) -> Any:
    """The plot source of a plan or plot scan, its fields taken out of ``data``."""
    from treesim.params.models import ModelParams
    from treesim.plot.generate import StandParams

    from .plots import PlotSource

    stand = data.pop("stand", None)
    tree = data.pop("tree", None)
    radius = data.pop("radius_m", None)
    if radius is not None and not (
        isinstance(radius, int | float) and not isinstance(radius, bool) and 0 < radius <= 1000
    ):
        raise _field_error("radius_m", f"radius_m must be in (0, 1000] m, got {radius!r}")
    st = None if stand is None else merge(StandParams(), stand, prefix="stand.")
    mp = None
    if tree is not None:
        mp = merge(ModelParams(), tree, prefix="tree.")
        if not mp.species:
            raise _field_error("tree.species", "tree.species: give a species")
    return PlotSource(stand=st, tree=mp, radius_m=None if radius is None else float(radius))


def _check_source(inputs: frozenset[str], job: Any) -> None:
    job.source.check(inputs)


_PLOT_INPUTS = (
    Input(
        "plot",
        ("plot",),
        "the plot: a zip archive of plot.toml, its trees CSV and the trees' files "
        "(or give parameters.stand, parameters.tree or inputs.mesh)",
        required=False,
    ),
    Input("mesh", ("mesh",), "one tree as a mesh, instead of a plot", required=False),
)
#: What a generated stand (parameters.stand) leaves among a plan's or plot scan's results.
_STAND_OUTPUTS = (
    ("stand/plot.toml", "a generated stand's plot file (stand only)"),
    ("stand/trees.csv", "a generated stand's trees (stand only)"),
)


# -- plan -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanJob:
    plan: Any  # PlanParams
    instrument: str
    spec: ScannerSpec
    source: Any  # PlotSource


def _plan_extra() -> dict[str, Any]:
    from treesim.plan.params import DEFAULT_INSTRUMENT

    res = _resolution_schema()
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
        **_source_schema(),
    }


def _plan_schema() -> dict[str, Any]:
    from treesim.plan.params import PlanParams

    return _job_schema(PlanParams)


def _with_resolution(spec: ScannerSpec, resolution_deg: Any) -> ScannerSpec:
    if resolution_deg is None:
        return spec
    try:
        return spec.with_(
            horizontal_resolution_deg=resolution_deg, vertical_resolution_deg=resolution_deg
        )
    except InvalidParameterError as exc:
        raise _field_error("resolution_deg", f"resolution_deg: {exc}") from None


def _parse_plan(parameters: Mapping[str, Any]) -> PlanJob:
    from treesim.params import instrument
    from treesim.plan.params import DEFAULT_INSTRUMENT, PlanParams

    data = dict(parameters)
    source = _pop_source(data)
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

    from .plots import open_plot

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


# -- plot-scan --------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlotScanJob:
    scan: ScanParams
    stations: tuple[tuple[float, ...], ...] | None
    compare: CompareParams
    figures: bool
    source: Any  # PlotSource


#: ScanParams fields a plot scan does not use (the station rule is one tree's).
_NOT_FOR_PLOTS = ("min_distance_m",)


def _plot_scan_schema() -> dict[str, Any]:
    schema = _job_schema(ScanParams)
    for key in _NOT_FOR_PLOTS:
        schema["properties"].pop(key, None)
    props = schema["properties"]
    props["distance_m"]["description"] = (
        "distance of the ring's stations from the plot centre (null: half the plot's radius)"
    )
    props["height_m"]["description"] = "instrument height above the terrain"
    return schema


def _plot_scan_extra() -> dict[str, Any]:
    tol = json_schema(CompareParams)["properties"]["tolerance_m"]
    tol["description"] = "the per-tree comparison's " + tol["description"]
    return {
        **_scan_extra(),
        "stations": {
            "type": "array",
            "minItems": 1,
            "maxItems": 1000,
            "items": {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 3},
            "description": "station positions in the plot's frame (m): [x, y] stands "
            "height_m above the terrain, [x, y, z] where given (default a ring of n_stations "
            "at distance_m; or inputs.stations, a plan job's stations.csv)",
        },
        "tolerance_m": tol,
        "figures": {
            "type": "boolean",
            "default": True,
            "description": "measure every tree against its own mesh (tree_figures.csv); "
            "false: scan only",
        },
        **_source_schema(),
    }


def _parse_plot_scan(parameters: Mapping[str, Any]) -> PlotScanJob:
    import math

    data = dict(parameters)
    source = _pop_source(data)
    stations = data.pop("stations", None)
    if stations is not None:
        try:
            stations = tuple(tuple(float(c) for c in s) for s in stations)
        except (TypeError, ValueError, OverflowError):
            stations = ((math.nan,),)
        if not all(math.isfinite(c) for s in stations for c in s):
            raise _field_error("stations", "stations: every coordinate must be a finite number")
    tol = data.pop("tolerance_m", None)
    compare = merge(CompareParams(), {} if tol is None else {"tolerance_m": tol})
    figures = bool(data.pop("figures", True))
    return PlotScanJob(_parse_scan(data), stations, compare, figures, source)


def _check_plot_scan(inputs: frozenset[str], job: PlotScanJob) -> None:
    job.source.check(inputs - {"stations"})
    if "stations" in inputs and job.stations is not None:
        raise _field_error(
            "inputs.stations", "give the stations once: inputs.stations or parameters.stations"
        )


def _execute_plot_scan(
    inputs: Mapping[str, Path],
    job: PlotScanJob,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.plot.scan import plot_scan_files, plot_stations, read_stations_csv

    from .plots import open_plot

    plot_inputs = {k: v for k, v in inputs.items() if k != "stations"}
    sp = job.scan
    with open_plot(job.source, plot_inputs, out) as (plot, _single, what):
        if "stations" in inputs:
            stations = read_stations_csv(inputs["stations"], plot, height_m=sp.height_m)
        else:
            stations = plot_stations(
                plot,
                positions=job.stations,
                n=sp.n_stations,
                distance_m=sp.distance_m,
                height_m=sp.height_m,
                start_angle_deg=sp.start_angle_deg,
            )
        step = plot_scan_files(
            plot,
            out,
            sp,
            stations=stations,
            compare=job.compare,
            figures=job.figures,
            threads=threads,
            progress=progress,
        )
    s = step.summary
    rows = step.details["trees"]
    cov = [r["coverage"] for r in rows]
    return {
        "inputs": what,
        "plot": s["plot"],
        "points": s["points"],
        "rays_cast": s["rays_cast"],
        "stations": [
            {
                "position_m": st["position_m"],
                "points": st["points"],
                "trees_loaded": len(st["trees_loaded"]),
            }
            for st in s["stations"]
        ],
        "trees_measured": len(rows),
        "coverage": (
            {"min": min(cov), "mean": sum(cov) / len(cov), "max": max(cov)} if cov else None
        ),
        "warnings": s["warnings"],
        "timings_s": s["timings_s"],
    }


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
            inputs=(
                _CLOUD,
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
        Process(
            id="plan",
            title="Plan scan stations for a plot or a tree",
            description="Choose scanner stations from a grid of candidates over a plot (or "
            "around one tree) so that every tree meets a goal (coverage at a tolerance, the "
            "DBH band seen over an arc) within a budget (stations, field time); compare with "
            "the classic layouts and, unless verify is off, verify with a full-resolution "
            "scan (as treesim plan).",
            inputs=_PLOT_INPUTS,
            outputs=(
                ("plan.json", "goal, budget, chosen stations, per-tree figures, baselines"),
                ("stations.csv", "the chosen stations: order, x, y, z, field time"),
                ("map.png", "the plot with the stations and per-tree coverage"),
                ("curve.png", "coverage and field time against the number of stations"),
                *_STAND_OUTPUTS,
            ),
            extra_schema=_plan_extra,
            base_schema=_plan_schema,
            parse=_parse_plan,
            execute=_execute_plan,
            check_inputs=_check_source,
        ),
        Process(
            id="plot-scan",
            title="Scan a plot and measure every tree in it",
            description="Scan a plot from stations, one at a time, loading only the trees "
            "each station can record; label every point with its tree_id; measure each "
            "tree's points against its own mesh (as treesim plot scan).",
            inputs=(
                *_PLOT_INPUTS,
                Input(
                    "stations",
                    ("table",),
                    "station positions: a plan job's stations.csv (x_m, y_m and z_m or "
                    "height_m), instead of parameters.stations or the ring",
                    required=False,
                ),
            ),
            outputs=(
                ("plot_scan.laz", "the simulated cloud with tree_id and station per point"),
                ("plot_scan.json", "scanner, stations, trees loaded, truth and figures"),
                ("tree_figures.csv", "one row per tree: points, coverage, AVOHD, DBH, height"),
                *_STAND_OUTPUTS,
            ),
            extra_schema=_plot_scan_extra,
            base_schema=_plot_scan_schema,
            parse=_parse_plot_scan,
            execute=_execute_plot_scan,
            check_inputs=_check_plot_scan,
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
