"""The whole loop for one tree: reconstruct → scan the model → compare → report.

``run_tree(cloud, params, outdir)`` takes a field point cloud of one tree and

1. reconstructs a tree mesh (:func:`pipeline.reconstruct.reconstruct`): ``tree.ply``,
   ``cylinders.csv`` (qsm), ``tree.json``;
2. scans that mesh with the virtual TLS scanner (:func:`pipeline.scan.scan`) from a ring
   of stations around it placed by the station rule (:mod:`pipeline.scan.stations`):
   ``scan.laz`` (0.1 mm LAZ with the per-point fields) and ``scan.json``;
3. compares the simulated cloud, in float64, with the mesh it was scanned from
   (``vs_mesh/``: how well the scan design samples the model) and with the original field
   cloud (``vs_field/``: how close the simulation comes to the real scan):
   ``comparison.json`` and the distance clouds in each folder;
4. draws a report per comparison (``vs_*/report.html`` and plots) and one run page,
   ``report.html`` (:mod:`pipeline.report.run_page`), that presents both;

and writes ``run.json`` last: the parameters, software versions, ``timings_s`` per stage,
and the figures under ``reconstruction`` (``tree.json``'s names), ``scan``, ``vs_mesh`` and
``vs_field`` (``comparison.json``'s names).

The parameters (:class:`~pipeline.params.RunParams`), the run presets and the TOML
language are the parameter model's, :mod:`pipeline.params`.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ._system import cpu_count
from .atomic import write_text
from .cloud import Cloud
from .compare import COMPARISON_FIGURES
from .errors import InputFormatError, InvalidParameterError
from .jsonio import json_ready as _jsonable
from .jsonio import write_json as _write_json
from .params import RunParams, params_hash, run_preset
from .report.run_page import STAGES, run_page
from .scene import Scene
from .steps import scale_progress

__all__ = ["STAGES", "RunResult", "file_sha256", "run_tree", "software_versions"]

Progress = Callable[[float, str], None]


def file_sha256(path: str | Path, *, chunk_bytes: int = 1 << 22) -> str:
    """SHA-256 of a file's content (read in chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk_bytes):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class RunResult:
    """What :func:`run_tree` wrote.

    Attributes
    ----------
    outdir : Path
    report_html : Path
        The run page presenting both comparisons.
    run_json : Path
    summary : dict
        ``run.json``'s content.
    """

    outdir: Path
    report_html: Path
    run_json: Path
    summary: dict[str, Any]

    @property
    def timings_s(self) -> dict[str, float]:
        return self.summary["timings_s"]

    @property
    def reconstruction(self) -> dict[str, Any]:
        return self.summary["reconstruction"]

    @property
    def vs_mesh(self) -> dict[str, Any]:
        return self.summary["vs_mesh"]

    @property
    def vs_field(self) -> dict[str, Any]:
        return self.summary["vs_field"]


def software_versions() -> dict[str, str]:
    """Versions of Python, treesim and every library a run uses."""
    from ._version import software_versions as base

    return base("pymeshlab", "trimesh", "matplotlib")


#: Level of detail of QSM meshes in a run: facets whose sagitta is at most this fraction
#: of the point spacing at the nearest station (:func:`pipeline.models.plan_lod`). A
#: tenth keeps the inscribed polygon's one-sided offset (about 2/3 of the sagitta) under
#: 7 % of the spacing, so a cylinder fitted to the simulated cloud is not biased thinner
#: by more than that, while twigs, whose sagitta is tiny at any count, drop to 8 facets.
RUN_LOD_TOLERANCE = 0.1


def _lod_scene(
    model: Any, stations: list[Any], params: RunParams
) -> tuple[Scene, dict[str, Any]] | None:
    """The scene a run scans under ``lod="auto"``: the QSM table meshed with facets from
    the projected size at the nearest station, and why; None when that changes
    nothing."""
    import math

    from .cloud import LABEL_CODES
    from .models import plan_lod, sink_branches, tubes_to_mesh

    spec = params.scan.scanner
    spacing = math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
    # the rows as meshed (reconstruct's branch_tubes): branch starts sunk into parents
    table = sink_branches(model.cylinders).table
    plan = plan_lod(
        table,
        np.array([st.position_m for st in stations]),
        spacing,
        max_facets=int(params.reconstruct.facets),
        tolerance=RUN_LOD_TOLERANCE,
    )
    if (plan.facets == int(params.reconstruct.facets)).all():
        return None
    tubes = tubes_to_mesh(table, facets=plan.facets)
    v, f = tubes.vertices, tubes.faces
    label = np.full(len(f), LABEL_CODES["wood"], dtype=np.uint8)
    scene = Scene.from_labelled_mesh(v, f, label, name_prefix="reconstruction (lod):")
    info = plan.describe(joints="miter")
    info["why"] = (
        f"QSM mesh for the scan: {len(f):,} triangles instead of {len(model.faces):,}, "
        f"each branch's tube with the fewest facets (>= {int(plan.facets.min())}) whose "
        f"sagitta is at most {RUN_LOD_TOLERANCE:g} of the point spacing at the nearest "
        "station on every cylinder of it"
    )
    return scene, info


def run_tree(
    cloud: Cloud | np.ndarray | str | Path,
    params: RunParams | None = None,
    outdir: str | Path = "out/run",
    *,
    name: str | None = None,
    progress: Progress | None = None,
) -> RunResult:
    """Run the whole loop on one tree and write every artefact into ``outdir``.

    Parameters
    ----------
    cloud : Cloud, (n, 3) float array, or path
        The field point cloud of one tree (a file: LAS, LAZ, PLY, XYZ, TXT, CSV, ...).
    params : RunParams, optional
        Default the ``standard`` preset.
    outdir : str or Path
        Created if missing; existing files of the same names are replaced.
    name : str, optional
        The tree's name in the report (default the file's stem).
    progress : callable(fraction, message), optional
        Called as the stages advance.

    Returns
    -------
    RunResult
        Paths and ``run.json``'s content.

    Raises
    ------
    TreesimError
        From any stage, with its message (e.g. ``InputFormatError`` for a corrupt file,
        ``ReconstructionError``, ``ScanError``).
    """
    from ._version import __version__
    from .compare import compare, write_comparison
    from .io import read_cloud, write_cloud, write_mesh
    from .reconstruct import reconstruct
    from .report import build_report
    from .scan import scan, stations_for

    params = params or run_preset()
    if not isinstance(params, RunParams):
        raise InvalidParameterError(f"params must be RunParams, got {type(params).__name__}")
    say = progress or (lambda f, m: None)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    threads = int(params.threads) or cpu_count()
    timings: dict[str, float] = {}
    t_all = time.perf_counter()

    # -- read ------------------------------------------------------------------------------
    if isinstance(cloud, (str, Path)) and not Path(cloud).is_file():
        raise InputFormatError(f"{cloud} not found; check the path")
    say(0.0, "reading")
    t0 = time.perf_counter()
    inputs: dict[str, Any]
    if isinstance(cloud, (str, Path)):
        path = Path(cloud)
        field_cloud = read_cloud(path)
        inputs = {"cloud": str(path), "sha256": file_sha256(path), "bytes": path.stat().st_size}
        name = name or path.stem
    elif isinstance(cloud, Cloud):
        field_cloud = cloud
        inputs = {"cloud": None}
    else:
        field_cloud = Cloud(np.asarray(cloud, dtype=np.float64))
        inputs = {"cloud": None}
    field_cloud.validate()
    inputs["points"] = len(field_cloud)
    name = name or "tree"
    timings["read"] = time.perf_counter() - t0

    # -- reconstruct -----------------------------------------------------------------------
    t0 = time.perf_counter()
    rp = replace(params.reconstruct, prepare=replace(params.reconstruct.prepare, threads=threads))
    model = reconstruct(field_cloud, rp, progress=scale_progress(say, 0.02, 0.35))
    written = model.write(out)
    timings["reconstruct"] = time.perf_counter() - t0

    # -- scan ------------------------------------------------------------------------------
    t0 = time.perf_counter()
    scene = Scene.from_labelled_mesh(
        model.vertices, model.faces, model.face_label, name_prefix="reconstruction:"
    )
    sp = params.scan
    stations, station_rule = stations_for(scene.bounds, sp)
    scanned_mesh = written["mesh"].name
    facet_lod = None
    qsm_lod = sp.lod == "auto" and model.cylinders is not None
    lod_scene = _lod_scene(model, stations, params) if qsm_lod else None
    if lod_scene is not None:
        scene, facet_lod = lod_scene
        scanned_mesh = "scan_mesh.ply"
        write_mesh(out / scanned_mesh, scene.vertices, scene.faces)
    say(0.35, "scanning")
    result = scan(
        scene,
        stations,
        sp.scanner,
        chunk_rays=int(sp.chunk_rays),
        max_rays=int(sp.max_rays),
        nthreads=threads,
        progress=scale_progress(say, 0.35, 0.5),
        lod=sp.lod,
    )
    if facet_lod is not None:
        result.lod["facets"] = facet_lod
    sim = result.cloud
    scan_path = write_cloud(out / "scan.laz", sim)
    scan_summary = {
        "mesh": scanned_mesh,
        "triangles": scene.n_triangles,
        "labels_in_scene": scene.labels_present(),
        "output": scan_path.name,
        "station_rule": station_rule,
        **result.summary(),
    }
    _write_json(out / "scan.json", scan_summary)
    timings["scan"] = time.perf_counter() - t0
    scan_inputs = {
        "source": "scan.json",
        "scanner": sp.scanner.to_dict(),
        "models_active": result.models,
        "lod": result.lod,
        "stations": [
            {"index": s.index, "position_m": list(s.position_m), "points": s.points}
            for s in result.station_stats
        ],
    }

    # -- compare ---------------------------------------------------------------------------
    cp = replace(params.compare, nthreads=threads)
    say(0.5, "comparing with the mesh")
    t0 = time.perf_counter()
    vs_mesh = compare(sim, scene, params=cp)
    in_mesh = {
        "cloud": "../scan.laz",
        "reference": f"../{scanned_mesh}",
        "scan": scan_inputs,
    }
    write_comparison(vs_mesh, out / "vs_mesh", inputs=in_mesh, formats=(".laz",))
    timings["compare_mesh"] = time.perf_counter() - t0
    say(0.62, "comparing with the field cloud")
    t0 = time.perf_counter()
    vs_field = compare(sim, field_cloud, params=cp)
    in_field = {
        "cloud": "../scan.laz",
        "reference": inputs["cloud"] or "field cloud (memory)",
        "scan": scan_inputs,
    }
    write_comparison(vs_field, out / "vs_field", inputs=in_field, formats=(".laz",))
    timings["compare_field"] = time.perf_counter() - t0

    # -- report ----------------------------------------------------------------------------
    say(0.72, "drawing the reports")
    t0 = time.perf_counter()
    build_report(vs_mesh, out / "vs_mesh", params=params.report, inputs=in_mesh)
    say(0.86, "drawing the reports")
    build_report(vs_field, out / "vs_field", params=params.report, inputs=in_field)
    mesh_fig = {k: v for k, v in vs_mesh.to_dict().items() if k in COMPARISON_FIGURES}
    field_fig = {k: v for k, v in vs_field.to_dict().items() if k in COMPARISON_FIGURES}
    summary: dict[str, Any] = {
        "kind": "treesim.run",
        "name": name,
        "inputs": inputs,
        "parameters": params.to_dict(),
        "params_hash": params_hash(params),
        "threads": threads,
        "software": software_versions(),
        "reconstruction": dict(model.figures),
        "scan": {
            "points": len(sim),
            "rays_cast": result.rays_cast,
            "stations": [s.to_dict() for s in result.station_stats],
            "station_rule": scan_summary["station_rule"],
            "models_active": result.models,
            "lod": result.lod,
            "warnings": result.warnings,
        },
        "vs_mesh": mesh_fig,
        "vs_field": field_fig,
        "files": {
            "mesh": written["mesh"].name,
            **({"cylinders": written["cylinders"].name} if "cylinders" in written else {}),
            "tree_json": written["json"].name,
            "scan": scan_path.name,
            "scan_json": "scan.json",
            "vs_mesh": "vs_mesh/comparison.json",
            "vs_field": "vs_field/comparison.json",
            "vs_mesh_report": "vs_mesh/report.html",
            "vs_field_report": "vs_field/report.html",
            "report": "report.html",
        },
    }
    summary["summary_text"] = _summary_texts(out)
    timings["report"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_all
    summary["timings_s"] = timings
    write_text(out / "report.html", run_page(summary, __version__))
    _write_json(out / "run.json", summary)
    say(1.0, "done")
    return RunResult(
        outdir=out,
        report_html=out / "report.html",
        run_json=out / "run.json",
        summary=_jsonable(summary),
    )


def _summary_texts(out: Path) -> dict[str, str]:
    texts = {}
    for key in ("vs_mesh", "vs_field"):
        try:
            texts[key] = json.loads((out / key / "report.json").read_text())["summary"]
        except (OSError, ValueError, KeyError):
            texts[key] = ""
    return texts
