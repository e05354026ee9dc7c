"""The single stages on files: reconstruct, scan, compare (and report).

One function per stage that reads its input files, runs the stage and writes what the
stage's command writes, returning a :class:`StepResult` (a JSON-ready summary, the files
written, and the in-memory result). ``treesim reconstruct``, ``treesim scan`` and
``treesim compare`` are these functions plus printing; the service's ``reconstruct``,
``scan`` and ``compare`` processes call them too, so a stage behaves the same whichever
way it is asked for. The whole loop on one tree is :func:`pipeline.run.run_tree`.

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
    "scale_progress",
    "reconstruct_files",
    "scan_files",
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
    ``columns`` names a text cloud's columns (see :func:`pipeline.io.read_cloud`).
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
) -> StepResult:
    """Scan meshes with the virtual scanner; write the cloud to ``out_path`` (its suffix
    picks the format) and the scan's settings and figures to ``<stem>.json`` beside it.

    ``stations`` are scanner positions (m); None places ``params``' ring of stations
    around the scene (:func:`pipeline.scan.stations_for`). ``label`` forces one part
    label on every mesh; ``window`` casts rays only towards the scene (False: the full
    field of view).
    """
    from .io import open_cloud_writer
    from .scan import SCAN_FIELDS, Station, load_scene, scan, scan_metadata, stations_for

    say = _say(progress)
    params = params or ScanParams()
    out = Path(out_path)
    if out.suffix.lower() not in SCAN_OUTPUT_SUFFIXES:
        raise InvalidParameterError(
            f"{out}: write the scan as {', '.join(SCAN_OUTPUT_SUFFIXES)} (by suffix)"
        )
    meshes = [_existing(m) for m in mesh_paths]
    if not meshes:
        raise InvalidParameterError("give at least one mesh to scan")
    say(0.0, "loading the scene")
    t0 = time.perf_counter()
    scene = load_scene(meshes, labels=[label] * len(meshes) if label else None)
    t_load = time.perf_counter() - t0
    rule = None
    if stations:
        placed = [Station(position_m=tuple(float(c) for c in s)) for s in stations]
    else:
        placed, rule = stations_for(scene.bounds, params)
    say(0.05, "scanning")
    out.parent.mkdir(parents=True, exist_ok=True)
    t1 = time.perf_counter()
    # the cloud is written while it is cast: memory does not grow with the points
    with open_cloud_writer(
        out,
        fields=SCAN_FIELDS,
        metadata=scan_metadata(placed),
        origin_hint_m=scene.bounds[0],
        threads=int(threads),
    ) as writer:
        result = scan(
            scene,
            placed,
            params.scanner,
            window=window,
            chunk_rays=int(params.chunk_rays),
            max_rays=int(params.max_rays),
            nthreads=int(threads),
            progress=scale_progress(say, 0.05, 0.95),
            sink=writer.write,
            lod=params.lod,
        )
        say(0.95, "writing the cloud")
        t2 = time.perf_counter()
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
    say(1.0, "done")
    return StepResult(summary, {"cloud": out, "json": side}, result, {"scene": scene})


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
