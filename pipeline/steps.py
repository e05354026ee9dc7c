"""The single stages on files: reconstruct, scan, compare (and report).

One function per stage that reads its input files, runs the stage and writes what the
stage's command writes, returning a :class:`StepResult` (a JSON-ready summary, the files
written, and the in-memory result). ``treesim reconstruct``, ``treesim scan`` and
``treesim compare`` are these functions plus printing; the service's ``reconstruct``,
``scan`` and ``compare`` processes call them too, so a stage behaves the same whichever
way it is asked for. The whole loop on one tree is :func:`treesim.run.run_tree`.

``progress(fraction, message)`` is the same callback as ``run_tree``'s: a fraction in 0..1
and a short stage name; each step ends with ``(1.0, "done")``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from .errors import InputFormatError, InvalidParameterError
from .jsonio import json_ready, write_json
from .params import CompareParams, ReconstructParams, ReportParams, ScanParams

__all__ = [
    "SCAN_OUTPUT_SUFFIXES",
    "StepResult",
    "compare_files",
    "estimate_scan_files",
    "scale_progress",
    "reconstruct_files",
    "scan_files",
    "scan_scene",
    "scan_sidecar",
]

Progress = Callable[[float, str], None]

#: The cloud formats a scan can be written as.
SCAN_OUTPUT_SUFFIXES = (".laz", ".las", ".ply", ".xyz", ".txt", ".csv")


@dataclass(frozen=True)
class StepResult:
    """What a step did.

    Attributes
    ----------
    summary : dict
        JSON-ready figures, settings and timings (what the step's JSON file holds).
    outputs : dict of str to Path
        The files written, by role.
    result : object
        The stage's own result in memory (TreeModel, ScanResult or Comparison).
    details : dict
        Extra facts for a caller that prints (the scene, the reference's kind, ...).
    """

    summary: dict[str, Any]
    outputs: dict[str, Path]
    result: Any = None
    details: dict[str, Any] = field(default_factory=dict)


def _say(progress: Progress | None) -> Progress:
    return progress or (lambda fraction, message: None)


def scale_progress(progress: Progress | None, lo: float, hi: float) -> Progress | None:
    """``progress`` for a part of the work: its 0..1 mapped onto ``lo``..``hi``."""
    if progress is None:
        return None
    return lambda f, m: progress(lo + (hi - lo) * min(max(f, 0.0), 1.0), m)


def _existing(path: str | Path) -> Path:
    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"{p} not found; check the path")
    return p


def reconstruct_files(
    cloud_path: str | Path,
    params: ReconstructParams | None = None,
    outdir: str | Path = "out/reconstruct",
    *,
    columns: Sequence[str | None] | None = None,
    threads: int = 0,
    progress: Progress | None = None,
) -> StepResult:
    """Reconstruct a tree mesh from a cloud file; write ``tree.ply``, ``cylinders.csv``
    (qsm) and ``tree.json`` into ``outdir``.

    ``threads`` > 0 replaces the preparation's thread count (0 keeps the parameters').
    ``columns`` names a text cloud's columns (see :func:`treesim.io.read_cloud`).
    """
    from .io import read_cloud
    from .reconstruct import reconstruct

    say = _say(progress)
    params = params or ReconstructParams()
    if threads:
        params = replace(params, prepare=replace(params.prepare, threads=int(threads)))
    path = _existing(cloud_path)
    say(0.0, "reading")
    cloud = read_cloud(path, columns=columns) if columns else read_cloud(path)
    model = reconstruct(cloud, params, progress=scale_progress(say, 0.05, 0.95))
    outputs = model.write(outdir)
    summary = json_ready(
        {
            "input": path.name,
            **model.to_dict(),
            "files": {k: p.name for k, p in outputs.items()},
        }
    )
    say(1.0, "done")
    return StepResult(summary, outputs, model)


def scan_scene(
    scene: Any, stations: Sequence[Any], params: ScanParams, *, threads: int = 0, **options: Any
) -> Any:
    """:func:`treesim.scan.scan` of ``scene`` from ``stations`` with the scanner, ray
    budget and level of detail of ``params`` (the one place a :class:`ScanParams` is
    unpacked for a scan); ``threads`` are Open3D's (0: all cores); ``options`` go to
    ``scan`` as they are (``window``, ``progress``, ``sink``, ``estimate``, ...).
    Returns the :class:`~treesim.scan.ScanResult`."""
    from .scan import scan

    return scan(
        scene,
        stations,
        params.scanner,
        chunk_rays=int(params.chunk_rays),
        max_rays=int(params.max_rays),
        nthreads=int(threads),
        lod=params.lod,
        **options,
    )


def scan_files(
    mesh_paths: Sequence[str | Path],
    params: ScanParams | None = None,
    out_path: str | Path = "out/scan.laz",
    *,
    stations: Sequence[Sequence[float]] | None = None,
    label: str | None = None,
    window: bool = True,
    threads: int = 0,
    progress: Progress | None = None,
    estimate: Callable[[Any], None] | None = None,
) -> StepResult:
    """Scan meshes with the virtual scanner; write the cloud to ``out_path`` (its suffix
    picks the format) and the scan's settings and figures to ``<stem>.json`` beside it.

    ``stations`` are scanner positions (m); None places ``params``' ring of stations
    around the scene (:func:`treesim.scan.stations_for`). ``label`` forces one part
    label on every mesh; ``window`` casts rays only towards the scene (False: the full
    field of view). ``estimate`` is called once before casting with the scan's
    :class:`~treesim.scan.ScanEstimate` (for this output's format).
    """
    from .io import open_cloud_writer
    from .scan import scan_fields, scan_metadata

    say = _say(progress)
    params = params or ScanParams()
    out = _scan_output(out_path)
    say(0.0, "loading the scene")
    t0 = time.perf_counter()
    meshes, scene, placed, rule = _scan_setup(mesh_paths, params, stations, label)
    t_load = time.perf_counter() - t0
    say(0.05, "scanning")
    # Open3D's import (~1 s, with extension modules that a Ctrl-C in mid-import leaves
    # half-initialised, failing the interpreter's exit) happens before any file exists
    import open3d  # noqa: F401

    # interrupted or failed, the step leaves nothing behind: no cloud (the writer's
    # temporary file is removed), no sidecar, no folder it made
    created = _make_folders(out.parent)
    committed = False
    try:
        t1 = time.perf_counter()
        # the cloud is written while it is cast: memory does not grow with the points;
        # a wind that sways the tree (a cylinder table given) adds wind_displacement_m
        fields = scan_fields(scene, params.scanner if params.scanner.wind_cylinders else None)
        with open_cloud_writer(
            out,
            fields=fields,
            metadata=scan_metadata(placed),
            origin_hint_m=scene.bounds[0],
            threads=int(threads),
        ) as writer:
            result = scan_scene(
                scene,
                placed,
                params,
                threads=threads,
                window=window,
                progress=scale_progress(say, 0.05, 0.95),
                sink=writer.write,
                sink_fields=list(fields),
                estimate=(lambda e: estimate(e.for_suffix(out.suffix))) if estimate else None,
            )
            say(0.95, "writing the cloud")
            t2 = time.perf_counter()
        committed = True
        t_write = time.perf_counter() - t2
        t_scan = t2 - t1
        summary = json_ready(
            {
                "meshes": [str(m) for m in meshes],
                "triangles": scene.n_triangles,
                "degenerate_triangles_dropped": scene.dropped_degenerate,
                "labels_in_scene": scene.labels_present(),
                "output": str(out),
                **({"station_rule": rule} if rule else {}),
                **result.summary(),
                # scan: casting and writing as it goes; write: finishing the file
                "timings_s": {"load": t_load, "scan": t_scan, "write": t_write},
            }
        )
        side = write_json(out.with_name(out.stem + ".json"), summary)
    except BaseException:
        if committed:  # the cloud without its sidecar: not a finished scan
            out.unlink(missing_ok=True)
        _remove_folders(created)
        raise
    say(1.0, "done")
    return StepResult(summary, {"cloud": out, "json": side}, result, {"scene": scene})


def _make_folders(folder: Path) -> list[Path]:
    """Make ``folder`` and its missing parents; return those made, outermost first."""
    missing = []
    p = folder
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    return missing[::-1]


def _remove_folders(made: list[Path]) -> None:
    """Remove folders :func:`_make_folders` made, innermost first, while they are empty."""
    for p in reversed(made):
        try:
            p.rmdir()
        except OSError:
            return


def _scan_output(out_path: str | Path) -> Path:
    out = Path(out_path)
    if out.suffix.lower() not in SCAN_OUTPUT_SUFFIXES:
        raise InvalidParameterError(
            f"{out}: write the scan as {', '.join(SCAN_OUTPUT_SUFFIXES)} (by suffix)"
        )
    return out


def _scan_setup(
    mesh_paths: Sequence[str | Path],
    params: ScanParams,
    stations: Sequence[Sequence[float]] | None,
    label: str | None,
) -> tuple[list[Path], Any, list[Any], dict[str, Any] | None]:
    """The meshes, the scene read from them, the stations and the station rule used."""
    from .scan import Station, load_scene, stations_for

    meshes = [_existing(m) for m in mesh_paths]
    if not meshes:
        raise InvalidParameterError("give at least one mesh to scan")
    scene = load_scene(meshes, labels=[label] * len(meshes) if label else None)
    rule = None
    if stations:
        placed = [Station(position_m=tuple(float(c) for c in s)) for s in stations]
    else:
        placed, rule = stations_for(scene.bounds, params)
    return meshes, scene, placed, rule


def estimate_scan_files(
    mesh_paths: Sequence[str | Path],
    params: ScanParams | None = None,
    out_path: str | Path = "out/scan.laz",
    *,
    stations: Sequence[Sequence[float]] | None = None,
    label: str | None = None,
    window: bool = True,
    threads: int = 0,
) -> StepResult:
    """What :func:`scan_files` with the same arguments would cast, record, write and
    take (:func:`treesim.scan.estimate_scan`), without scanning or writing anything.

    Returns a :class:`StepResult` whose ``result`` is the
    :class:`~treesim.scan.ScanEstimate` (for ``out_path``'s format) and ``summary`` its
    dict; ``details`` holds the scene and the station rule.
    """
    from .scan import estimate_scan

    params = params or ScanParams()
    out = _scan_output(out_path)
    meshes, scene, placed, rule = _scan_setup(mesh_paths, params, stations, label)
    est = estimate_scan(
        scene,
        placed,
        params.scanner,
        window=window,
        lod=params.lod,
        nthreads=int(threads),
        max_rays=int(params.max_rays),
        suffix=out.suffix,
    )
    summary = json_ready({"meshes": [str(m) for m in meshes], "output": str(out), **est.to_dict()})
    return StepResult(summary, {}, est, {"scene": scene, "station_rule": rule})


def scan_sidecar(cloud_path: Path) -> dict[str, Any] | None:
    """The scan settings :func:`scan_files` wrote beside a cloud (``OUT.json``), if any."""
    import json

    side = cloud_path.with_suffix(".json")
    if not side.is_file():
        return None
    try:
        info = json.loads(side.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or "stations" not in info:
        return None
    return {
        "source": side.name,
        "scanner": info.get("scanner"),
        "models_active": info.get("models_active"),
        "lod": info.get("lod"),
        "stations": [
            {k: st.get(k) for k in ("index", "position_m", "points")}
            for st in info.get("stations", [])
            if isinstance(st, dict)
        ],
    }


def compare_files(
    cloud_path: str | Path,
    reference_path: str | Path,
    params: CompareParams | None = None,
    outdir: str | Path = "out/compare",
    *,
    report: ReportParams | None = None,
    progress: Progress | None = None,
) -> StepResult:
    """Compare a cloud file with a reference mesh or cloud file (AVOHD, both ways, with
    coverage); write ``comparison.json`` and the distance clouds into ``outdir``, and
    with ``report`` the HTML report and its plots too."""
    from .compare import compare, write_comparison
    from .io import read_cloud, read_reference

    say = _say(progress)
    params = params or CompareParams()
    cloud_p = _existing(cloud_path)
    ref_p = _existing(reference_path)
    say(0.0, "reading")
    t0 = time.perf_counter()
    cloud = read_cloud(cloud_p)
    reference, kind = read_reference(ref_p)
    t_read = time.perf_counter() - t0
    say(0.1, "comparing")
    t0 = time.perf_counter()
    result = compare(cloud, reference, params=params)
    t_compare = time.perf_counter() - t0
    inputs: dict[str, Any] = {"cloud": str(cloud_p), "reference": str(ref_p)}
    sidecar = scan_sidecar(cloud_p)
    if sidecar:
        inputs["scan"] = sidecar
    outputs = write_comparison(result, outdir, inputs=inputs)
    timings = {"read": t_read, "compare": t_compare}
    if report is not None:
        from .report import build_report

        say(0.8, "drawing the report")
        t0 = time.perf_counter()
        files = build_report(result, outdir, params=report, inputs=inputs)
        timings["report"] = time.perf_counter() - t0
        outputs = {**outputs, "report": files["report_html"]}
    summary = json_ready(
        {
            "cloud": cloud_p.name,
            "reference": ref_p.name,
            "reference_kind": kind,
            **result.to_dict(),
            "timings_s": timings,
        }
    )
    say(1.0, "done")
    return StepResult(summary, outputs, result, {"kind": kind, "points": len(cloud)})
