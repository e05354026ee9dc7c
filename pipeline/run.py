"""The whole loop for one tree: reconstruct → scan the model → compare → report.

``run_tree(cloud, params, outdir)`` takes a field point cloud of one tree and

1. reconstructs a tree mesh (:func:`treesim.reconstruct.reconstruct`): ``tree.ply``,
   ``cylinders.csv`` (qsm), ``tree.json``;
2. scans that mesh with the virtual TLS scanner (:func:`treesim.scan.scan`) from a ring
   of stations around it placed by the station rule (:mod:`treesim.scan.stations`):
   ``scan.laz`` (0.1 mm LAZ with the per-point fields), ``scan.ply`` (the same in float64,
   exactly what was compared) and ``scan.json``;
3. compares the simulated cloud, in float64, with the mesh it was scanned from
   (``vs_mesh/``: how well the scan design samples the model) and with the original field
   cloud (``vs_field/``: how close the simulation comes to the real scan), both with one
   coverage tolerance τ (:func:`run_tolerance`): ``comparison.json`` and the distance
   clouds in each folder;
4. draws a report per comparison (``vs_*/report.html`` and plots) from the files just
   written, so that ``treesim report vs_mesh`` draws the same figures again, the field and
   simulated clouds side by side (``clouds.png``), and one run page, ``report.html``
   (:mod:`treesim.report.run_page`), that presents it all;

and writes ``run.json`` last: the parameters, software versions, ``timings_s`` per stage,
and the figures under ``reconstruction`` (``tree.json``'s names), ``tolerance``,
``clouds``, ``scan``, ``vs_mesh`` and ``vs_field`` (``comparison.json``'s names), and
``reference_qsm`` when one was given. Inputs outside the folder are named by their path
relative to it (and their SHA-256), links inside it are relative, and every page is
self-contained or links within the folder, so an output folder can be moved.

The parameters (:class:`~treesim.params.RunParams`), the run presets and the TOML
language are the parameter model's, :mod:`treesim.params`.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._system import cpu_count
from .atomic import write_text
from .cloud import Cloud
from .compare import COMPARISON_FIGURES
from .errors import InputFormatError, InvalidParameterError
from .jsonio import json_ready as _jsonable
from .jsonio import write_json as _write_json
from .params import RunParams, params_hash, run_preset
from .report import draw_report
from .report.background import BackgroundDrawer, preload_drawing
from .report.data import ReportData
from .report.figures import gc_paused, writing_behind
from .report.run_page import STAGES, run_page, run_viewer_payload
from .scene import Scene
from .steps import scale_progress, scan_scene

if TYPE_CHECKING:
    from .models import CylinderTable

__all__ = [
    "STAGES",
    "RunResult",
    "file_sha256",
    "lod_plan",
    "run_tolerance",
    "run_tree",
    "software_versions",
]

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

    Examples
    --------
    >>> import treesim as ts
    >>> result = ts.run_tree("tree.laz", ts.run_preset("draft"), "out/run")  # doctest: +SKIP
    >>> result.report_html  # doctest: +SKIP
    PosixPath('out/run/report.html')
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
#: of the point spacing at the nearest station (:func:`treesim.models.plan_lod`). A
#: tenth keeps the inscribed polygon's one-sided offset (about 2/3 of the sagitta) under
#: 7 % of the spacing, so a cylinder fitted to the simulated cloud is not biased thinner
#: by more than that, while twigs, whose sagitta is tiny at any count, drop to 8 facets.
RUN_LOD_TOLERANCE = 0.1


def lod_plan(table: Any, stations: Sequence[Any], spec: Any, max_facets: int) -> Any:
    """A run's level of detail for a cylinder table scanned with ``spec`` (a
    :class:`~treesim.params.ScannerSpec`) from ``stations``: facets per row from the
    point spacing at the nearest station (the finer of the scanner's two steps) within
    :data:`RUN_LOD_TOLERANCE`, at most ``max_facets``
    (:func:`treesim.models.plan_lod`; returns its ``LodPlan``)."""
    import math

    from .models import plan_lod

    return plan_lod(
        table,
        np.array([st.position_m for st in stations]),
        math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg)),
        max_facets=int(max_facets),
        tolerance=RUN_LOD_TOLERANCE,
    )


def _lod_scene(
    model: Any, stations: list[Any], params: RunParams
) -> tuple[Scene, dict[str, Any]] | None:
    """The scene a run scans under ``lod="auto"``: the QSM table meshed with facets from
    the projected size at the nearest station (:func:`lod_plan`), and why; None when
    that changes nothing."""
    from .cloud import LABEL_CODES
    from .models import sink_branches, tubes_to_mesh

    # the rows as meshed (reconstruct's branch_tubes): branch starts sunk into parents
    table = sink_branches(model.cylinders).table
    plan = lod_plan(table, stations, params.scan.scanner, int(params.reconstruct.facets))
    if (plan.facets == int(params.reconstruct.facets)).all():
        return None
    tubes = tubes_to_mesh(table, facets=plan.facets)
    v, f = tubes.vertices, tubes.faces
    label = np.full(len(f), LABEL_CODES["wood"], dtype=np.uint8)
    # what the model holds beside its wood (a leaf layer) is scanned as it is
    other = np.asarray(model.face_label) != LABEL_CODES["wood"]
    if other.any():
        # only the vertices those triangles use: the rest are the full-detail wood's
        used, of = np.unique(np.asarray(model.faces)[other], return_inverse=True)
        f = np.concatenate([f, of.reshape(-1, 3) + len(v)])
        v = np.concatenate([v, np.asarray(model.vertices)[used]])
        label = np.concatenate([label, np.asarray(model.face_label)[other]])
    scene = Scene.from_labelled_mesh(v, f, label, name_prefix="reconstruction (lod):")
    info = plan.describe(joints="miter")
    info["why"] = (
        f"QSM mesh for the scan: {len(f):,} triangles instead of {len(model.faces):,}, "
        f"each branch's tube with the fewest facets (>= {int(plan.facets.min())}) whose "
        f"sagitta is at most {RUN_LOD_TOLERANCE:g} of the point spacing at the nearest "
        "station on every cylinder of it"
    )
    return scene, info


#: The figures a reference QSM and the reconstruction are compared on (``tree.json``'s and
#: :meth:`~treesim.models.CylinderTable.summary`'s names).
REFERENCE_FIGURES = (
    "dbh_m",
    "height_m",
    "volume_total_m3",
    "volume_stem_m3",
    "volume_branch_m3",
    "n_cylinders",
)


def reference_qsm_figures(table: CylinderTable, reconstruction: dict[str, Any]) -> dict[str, Any]:
    """A reference QSM's figures beside the reconstruction's.

    Parameters
    ----------
    table : CylinderTable
        The reference, as :func:`treesim.models.read_cylinders` read it (TreeQSM CSV or
        text export, SimpleForest or treesim's CSV).
    reconstruction : dict
        ``tree.json``'s figures.

    Returns
    -------
    dict
        ``figures`` (the reference's, :data:`REFERENCE_FIGURES`), ``difference``
        (reconstruction − reference, same units) and ``relative`` (that difference over
        the reference's value), each ``None`` where either side has no value.
    """
    summary = table.summary()
    ref = {k: summary.get(k) for k in REFERENCE_FIGURES}
    diff: dict[str, float | None] = {}
    rel: dict[str, float | None] = {}
    for k in REFERENCE_FIGURES:
        a, b = reconstruction.get(k), ref[k]
        ok = isinstance(a, (int, float)) and isinstance(b, (int, float))
        diff[k] = float(a - b) if ok else None
        rel[k] = float(a / b - 1.0) if ok and b else None
    return {"figures": ref, "difference": diff, "relative": rel}


def run_tolerance(field_cloud: Cloud, params: RunParams) -> dict[str, Any]:
    """The one coverage tolerance τ of a run, used by both of its comparisons.

    ``params.compare.tolerance_m`` when given; else
    :data:`~treesim.compare.TOLERANCE_FACTOR` × the *field* cloud's median point spacing,
    measured once. Deriving τ from the field cloud, never from the simulated one, keeps it
    fixed for a tree whatever the scan design, so runs of one tree with different
    stations or resolutions report coverage within the same distance (the sweep's rule,
    :func:`treesim.sweep.trees.derive_tolerance`, for one tree).

    Returns
    -------
    dict
        ``tolerance_m``, ``rule`` (in words), the field cloud's median point spacing
        ``field_point_spacing_m`` and, when τ is derived from it, ``factor``.
    """
    from .compare import TOLERANCE_FACTOR
    from .frame import LocalFrame
    from .geometry import point_spacing

    cp = params.compare
    pts = LocalFrame.around(field_cloud.points).to_local(field_cloud.points)
    spacing = point_spacing(pts, subsample=cp.spacing_subsample, seed=cp.seed)
    if cp.tolerance_m is not None:
        tau = float(cp.tolerance_m)
        return {
            "tolerance_m": tau,
            "rule": f"given ({tau * 1000:.4g} mm, --tolerance-m)",
            "field_point_spacing_m": spacing,
        }
    tau = TOLERANCE_FACTOR * spacing
    return {
        "tolerance_m": tau,
        "rule": f"{TOLERANCE_FACTOR:g} × the field cloud's median point spacing "
        f"({spacing * 1000:.3g} mm), one τ for the whole run",
        "factor": TOLERANCE_FACTOR,
        "field_point_spacing_m": spacing,
    }


def run_tree(
    cloud: Cloud | np.ndarray | str | Path,
    params: RunParams | None = None,
    outdir: str | Path = "out/run",
    *,
    name: str | None = None,
    reference_qsm: str | Path | None = None,
    progress: Progress | None = None,
    report_auto: str = "full",
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
    reference_qsm : str or Path, optional
        A QSM of the same tree made elsewhere (TreeQSM or SimpleForest cylinder table):
        its DBH, height and volumes are shown beside the reconstruction's
        (:func:`reference_qsm_figures`; ``run.json``'s ``reference_qsm``).
    progress : callable(fraction, message), optional
        Called as the stages advance.
    report_auto : {"full", "summary", "none"}
        The reports drawn when ``params.report.level`` is ``"auto"``
        (:meth:`~treesim.params.ReportParams.resolved`): ``"full"`` for one run;
        :func:`treesim.run_batch` and the sweep ask for ``"summary"``.

    Returns
    -------
    RunResult
        Paths and ``run.json``'s content.

    Raises
    ------
    TreesimError
        From any stage, with its message (e.g. ``InputFormatError`` for a corrupt file,
        ``ReconstructionError``, ``ScanError``).

    Examples
    --------
    >>> from importlib.resources import files
    >>> import treesim as ts
    >>> cloud = files("treesim") / "data" / "coffee_tree" / "cloud.txt"
    >>> result = ts.run_tree(cloud, ts.run_preset("draft"), "out/coffee")  # doctest: +SKIP
    >>> result.report_html  # doctest: +SKIP
    PosixPath('out/coffee/report.html')
    """
    from ._version import __version__

    params = params or run_preset()
    if not isinstance(params, RunParams):
        raise InvalidParameterError(f"params must be RunParams, got {type(params).__name__}")
    say = progress or (lambda f, m: None)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    threads = int(params.threads) or cpu_count()
    timings: dict[str, float] = {}
    t_all = time.perf_counter()
    level = params.report.resolved(report_auto)
    ref_table = _check_inputs(cloud, reference_qsm)  # before any work: fail at once
    # full reports: drawing processes started now (importing this module, whose draw_clouds
    # they draw), drawing as soon as their inputs exist
    workers = None if level == "full" else 0
    with BackgroundDrawer.start(workers, preload=[__name__]) as drawer:
        if level == "full" and not drawer.apart:
            preload_drawing()  # matplotlib loaded beside the science, not in the report stage
        # -- read --------------------------------------------------------------------------
        say(0.0, "reading")
        t0 = time.perf_counter()
        field_cloud, inputs, name = _read_field_cloud(cloud, out, name)
        timings["read"] = time.perf_counter() - t0

        # -- reconstruct -------------------------------------------------------------------
        t0 = time.perf_counter()
        model, written = _reconstruct_stage(field_cloud, params, threads, out, say)
        timings["reconstruct"] = time.perf_counter() - t0

        # -- scan --------------------------------------------------------------------------
        t0 = time.perf_counter()
        scanned = _scan_stage(model, written, params, threads, out, say)
        timings["scan"] = time.perf_counter() - t0

        # -- compare -----------------------------------------------------------------------
        tolerance, vs_mesh, vs_field = _compare_stage(
            cloud,
            field_cloud,
            inputs,
            scanned,
            params,
            threads,
            out,
            say,
            timings,
            on_mesh=_early_drawing(drawer, field_cloud, scanned, params, out),
        )

        # -- report ------------------------------------------------------------------------
        say(0.72, "drawing the reports")
        t0 = time.perf_counter()
        # no garbage collection while drawing (its many small cycles collected after it);
        # each PNG encoded and written by a thread while the next figure is drawn
        with gc_paused(), writing_behind():
            clouds, viewer = _draw_reports(
                field_cloud, scanned, vs_mesh, vs_field, tolerance, out, params, say, level, drawer
            )
        summary = _run_summary(
            name,
            inputs,
            params,
            threads,
            model,
            written,
            tolerance,
            clouds,
            scanned,
            vs_mesh,
            vs_field,
        )
        summary["report_level"] = level
        if level == "none":  # no comparison report: its files go, its page's links with them
            for key in ("vs_mesh_report", "vs_field_report"):
                summary["files"].pop(key)
        summary["summary_text"] = _summary_texts(out, level)
        summary["report_drawing"] = {
            "processes": drawer.processes,
            "seconds": drawer.seconds,
            "fallback": drawer.fallback,
        }
        timings["report"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_all
        summary["timings_s"] = timings
        if ref_table is not None:
            summary["reference_qsm"] = {
                "path": _relative(reference_qsm, out),
                **reference_qsm_figures(ref_table, model.figures),
                "sha256": file_sha256(reference_qsm),
            }
    write_text(out / "report.html", run_page(summary, __version__, viewer))
    _write_json(out / "run.json", summary)
    say(1.0, "done")
    return RunResult(
        outdir=out,
        report_html=out / "report.html",
        run_json=out / "run.json",
        summary=_jsonable(summary),
    )


def _check_inputs(
    cloud: Cloud | np.ndarray | str | Path, reference_qsm: str | Path | None
) -> CylinderTable | None:
    """Fail before any work on a missing cloud file or a missing or unreadable reference
    QSM; return the reference's table (None without one)."""
    if isinstance(cloud, (str, Path)) and not Path(cloud).is_file():
        raise InputFormatError(f"{cloud} not found; check the path")
    if reference_qsm is None:
        return None
    from .models import read_cylinders

    if not Path(reference_qsm).is_file():
        raise InputFormatError(f"reference QSM {reference_qsm} not found; check the path")
    return read_cylinders(reference_qsm)  # a bad table fails now, not after the run


def _read_field_cloud(
    cloud: Cloud | np.ndarray | str | Path, out: Path, name: str | None
) -> tuple[Cloud, dict[str, Any], str]:
    """The read stage: the field cloud (validated), ``run.json``'s ``inputs`` and the
    tree's name (given, else the file's stem, else ``"tree"``)."""
    from .io import read_cloud

    inputs: dict[str, Any]
    if isinstance(cloud, (str, Path)):
        path = Path(cloud)
        field_cloud = read_cloud(path)
        inputs = {
            "cloud": _relative(path, out),
            "sha256": file_sha256(path),
            "bytes": path.stat().st_size,
        }
        name = name or path.stem
    elif isinstance(cloud, Cloud):
        field_cloud = cloud
        inputs = {"cloud": None}
    else:
        field_cloud = Cloud(np.asarray(cloud, dtype=np.float64))
        inputs = {"cloud": None}
    field_cloud.validate()
    inputs["points"] = len(field_cloud)
    return field_cloud, inputs, name or "tree"


def _reconstruct_stage(
    field_cloud: Cloud, params: RunParams, threads: int, out: Path, say: Progress
) -> tuple[Any, dict[str, Path]]:
    """The reconstruct stage: the model, and the files it wrote (``model.write``)."""
    from .reconstruct import reconstruct

    rp = replace(params.reconstruct, prepare=replace(params.reconstruct.prepare, threads=threads))
    model = reconstruct(field_cloud, rp, progress=scale_progress(say, 0.02, 0.35))
    return model, model.write(out)


@dataclass(frozen=True)
class _Scanned:
    """What the scan stage made and wrote, for the comparisons and the summary."""

    scene: Scene
    #: The mesh file scanned (the reconstruction's, or ``scan_mesh.ply`` at its own detail).
    mesh_name: str
    result: Any  # treesim.scan.ScanResult
    scan_path: Path
    scan_ply: Path
    summary: dict[str, Any]
    #: The scan's record in each comparison's ``inputs``.
    inputs: dict[str, Any]

    @property
    def cloud(self) -> Cloud:
        return self.result.cloud


def run_wind(spec: Any, table: Any) -> Any:
    """The wind that sways a run's scanned model: with ``spec.wind_speed_m_s > 0`` and no
    ``wind_cylinders`` given, the reconstruction's own cylinder table ``table`` (the QSM
    the scanned mesh is made of) sways under ``spec``'s wind; otherwise None (the scan
    follows ``spec`` alone: still at 0 m/s, the given table, or a still mesh and a
    warning when the reconstruction has no cylinders).

    Examples
    --------
    >>> import treesim as ts
    >>> run_wind(ts.ScannerSpec(), None) is None
    True
    """
    if spec.wind_speed_m_s <= 0 or spec.wind_cylinders is not None or table is None:
        return None
    from .scan.wind import Forcing, Wind

    forcing = Forcing(
        spec.wind_speed_m_s, spec.wind_direction_deg, spec.wind_turbulence_intensity, spec.wind_seed
    )
    return Wind(table, forcing, direction_deg=spec.wind_direction_deg)


def _scan_stage(
    model: Any, written: dict[str, Path], params: RunParams, threads: int, out: Path, say: Progress
) -> _Scanned:
    """The scan stage: the model's mesh (at the run's level of detail) scanned from the
    station rule's stations; ``scan.laz``, ``scan.ply`` and ``scan.json`` written."""
    from .io import write_cloud, write_mesh
    from .scan import stations_for

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
    wind = run_wind(sp.scanner, model.cylinders)
    result = scan_scene(
        scene, stations, sp, threads=threads, progress=scale_progress(say, 0.35, 0.5), wind=wind
    )
    if facet_lod is not None:
        result.lod["facets"] = facet_lod
    sim = result.cloud
    scan_path = write_cloud(out / "scan.laz", sim)
    # the simulated cloud exactly as compared (float64): the LAZ keeps 0.1 mm
    scan_ply = write_cloud(out / "scan.ply", sim)
    scan_summary = {
        "mesh": scanned_mesh,
        "triangles": scene.n_triangles,
        "labels_in_scene": scene.labels_present(),
        "output": scan_path.name,
        "station_rule": station_rule,
        **result.summary(),
    }
    if wind is not None:  # the sway's tree: the reconstruction's own table
        scan_summary["wind_cylinders"] = written.get("cylinders", Path("cylinders.csv")).name
    _write_json(out / "scan.json", scan_summary)
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
    return _Scanned(scene, scanned_mesh, result, scan_path, scan_ply, scan_summary, scan_inputs)


def _compare_stage(
    cloud: Cloud | np.ndarray | str | Path,
    field_cloud: Cloud,
    inputs: dict[str, Any],
    scanned: _Scanned,
    params: RunParams,
    threads: int,
    out: Path,
    say: Progress,
    timings: dict[str, float],
    on_mesh: Callable[[Any], None] | None = None,
) -> tuple[dict[str, Any], Any, Any]:
    """The compare stage: the run's τ, then the simulated cloud against the mesh it was
    scanned from (``vs_mesh/``) and against the field cloud (``vs_field/``); each one's
    time goes into ``timings``. Returns τ's record and the two comparisons."""
    from .compare import compare, write_comparison

    say(0.5, "comparing with the mesh")
    t0 = time.perf_counter()
    tolerance = run_tolerance(field_cloud, params)
    cp = replace(params.compare, nthreads=threads, tolerance_m=tolerance["tolerance_m"])
    vs_mesh = compare(scanned.cloud, scanned.scene, params=cp)
    vs_mesh.tolerance_rule = tolerance["rule"]
    in_mesh = {
        "cloud": f"../{scanned.scan_ply.name}",
        "reference": f"../{scanned.mesh_name}",
        "scan": scanned.inputs,
    }
    write_comparison(vs_mesh, out / "vs_mesh", inputs=in_mesh, formats=(".laz",))
    timings["compare_mesh"] = time.perf_counter() - t0
    if on_mesh is not None:  # what can be drawn now, beside the next comparison
        on_mesh(vs_mesh)
    say(0.62, "comparing with the field cloud")
    t0 = time.perf_counter()
    vs_field = compare(scanned.cloud, field_cloud, params=cp)
    vs_field.tolerance_rule = tolerance["rule"]
    in_field = {
        "cloud": f"../{scanned.scan_ply.name}",
        "reference": _relative(cloud, out / "vs_field")
        if isinstance(cloud, (str, Path))
        else "field cloud (memory)",
        "reference_sha256": inputs.get("sha256"),
        "scan": scanned.inputs,
    }
    write_comparison(vs_field, out / "vs_field", inputs=in_field, formats=(".laz",))
    timings["compare_field"] = time.perf_counter() - t0
    return tolerance, vs_mesh, vs_field


def _draw_reports(
    field_cloud: Cloud,
    scanned: _Scanned,
    vs_mesh: Any,
    vs_field: Any,
    tolerance: dict[str, Any],
    out: Path,
    params: RunParams,
    say: Progress,
    level: str = "full",
    drawer: BackgroundDrawer | None = None,
) -> tuple[dict[str, Any], Any]:
    """Each comparison's report (drawn from what the written files hold, taken from
    memory, so that drawing them again gives the same report), the clouds side by side,
    and the run page's viewer payload, as ``level`` says (``full``, ``summary``: no PNG
    plot, ``none``: no report, no viewer). Returns the clouds' record and the payload
    (None under ``none``)."""
    from .report import build_report, remove_report

    mesh_data = ReportData.from_comparison(vs_mesh)
    if level == "none":
        for key in ("vs_mesh", "vs_field"):
            remove_report(out / key)
        return _clouds_side_by_side(
            field_cloud, scanned.cloud, mesh_data, tolerance, out, params, draw=False
        ), None
    if level == "summary" or drawer is None:
        rp = replace(params.report, plots=level == "full")
        for key, comparison in (("vs_mesh", vs_mesh), ("vs_field", vs_field)):
            if key == "vs_field":
                say(0.86, "drawing the reports")
            # what the folder holds, from memory: the clouds are not read back
            build_report(ReportData.from_written(comparison, out / key), out / key, params=rp)
        clouds = _clouds_side_by_side(
            field_cloud, scanned.cloud, mesh_data, tolerance, out, params, draw=level == "full"
        )
    else:  # full: what the drawer has not drawn yet, then every piece waited for
        if not drawer.apart:  # inline: drawn here, in the report stage's time
            _early_drawing(drawer, field_cloud, scanned, params, out, inline=True)(vs_mesh)
        drawer.submit("vs_field", draw_report, *_report_job(vs_field, out / "vs_field", params))
        clouds = _clouds_side_by_side(
            field_cloud, scanned.cloud, mesh_data, tolerance, out, params, draw=None
        )
    viewer = run_viewer_payload(
        mesh_data,
        ReportData.from_comparison(vs_field),
        max_points=params.report.max_view_points,
        seed=params.report.seed,
    )
    if drawer is not None and level == "full":
        say(0.86, "drawing the reports")
        clouds["figure"] = drawer.results()["clouds"]
    return clouds, viewer


def _early_drawing(
    drawer: BackgroundDrawer,
    field_cloud: Cloud,
    scanned: _Scanned,
    params: RunParams,
    out: Path,
    *,
    inline: bool = False,
) -> Callable[[Any], None] | None:
    """What the drawer draws once the comparison with the mesh is written (its report and
    the clouds side by side), beside the comparison with the field cloud; None when the
    drawer draws inline (then the report stage draws them, ``inline``)."""
    if not (drawer.apart or inline):
        return None

    def submit(vs_mesh: Any) -> None:
        rp = params.report
        drawer.submit("vs_mesh", draw_report, *_report_job(vs_mesh, out / "vs_mesh", params))
        drawer.submit(
            "clouds",
            draw_clouds,
            field_cloud.points,
            scanned.cloud.points,
            out / "clouds.png",
            ReportData.from_comparison(vs_mesh).origin,
            rp,
        )

    return submit


def _report_job(comparison: Any, folder: Path, params: RunParams) -> tuple[Any, ...]:
    """:func:`~treesim.report.draw_report`'s arguments for a comparison just written to
    ``folder``: what the folder holds, taken from memory (:meth:`ReportData.from_written`;
    a drawing process is sent the arrays, pickled, rather than read the files again)."""
    return folder, params.report, ReportData.from_written(comparison, folder)


def _run_summary(
    name: str,
    inputs: dict[str, Any],
    params: RunParams,
    threads: int,
    model: Any,
    written: dict[str, Path],
    tolerance: dict[str, Any],
    clouds: dict[str, Any],
    scanned: _Scanned,
    vs_mesh: Any,
    vs_field: Any,
) -> dict[str, Any]:
    """``run.json``'s content, less what the report stage adds after it (the summary
    texts, the timings and the reference QSM)."""
    result = scanned.result
    mesh_fig = {k: v for k, v in vs_mesh.to_dict().items() if k in COMPARISON_FIGURES}
    field_fig = {k: v for k, v in vs_field.to_dict().items() if k in COMPARISON_FIGURES}
    return {
        "kind": "treesim.run",
        "name": name,
        "inputs": inputs,
        "parameters": params.to_dict(),
        "params_hash": params_hash(params),
        "threads": threads,
        "software": software_versions(),
        "reconstruction": dict(model.figures),
        "tolerance": tolerance,
        "clouds": clouds,
        "scan": {
            "points": len(scanned.cloud),
            "rays_cast": result.rays_cast,
            "stations": [s.to_dict() for s in result.station_stats],
            "station_rule": scanned.summary["station_rule"],
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
            "scan": scanned.scan_path.name,
            "scan_float64": scanned.scan_ply.name,
            "scan_json": "scan.json",
            **({"clouds": clouds["figure"]} if clouds["figure"] else {}),
            "vs_mesh": "vs_mesh/comparison.json",
            "vs_field": "vs_field/comparison.json",
            "vs_mesh_report": "vs_mesh/report.html",
            "vs_field_report": "vs_field/report.html",
            "report": "report.html",
        },
    }


def _clouds_side_by_side(
    field: Cloud,
    sim: Cloud,
    vs_mesh: ReportData,
    tolerance: dict[str, Any],
    out: Path,
    params: RunParams,
    *,
    draw: bool | None = True,
) -> dict[str, Any]:
    """The field and simulated clouds' sizes and densities in one table, and (``draw``)
    ``clouds.png``: both in the same views on the same axes (the comparison with the
    mesh's display origin); ``draw`` None: drawn apart (:func:`draw_clouds`)."""

    area = vs_mesh.summary["reference"].get("area_m2")

    def facts(c: Cloud, spacing: float) -> dict[str, Any]:
        z = c.points[:, 2]
        return {
            "points": len(c),
            "point_spacing_m": spacing,
            "points_per_m2": len(c) / area if area else None,
            "height_m": float(z.max() - z.min()),
        }

    def _cloud_table() -> dict[str, Any]:
        return {
            "field": facts(field, tolerance["field_point_spacing_m"]),
            "simulated": facts(sim, vs_mesh.summary["point_spacing_m"]),
            "mesh_area_m2": area,
        }

    figure = out / "clouds.png"
    if draw is None:  # drawn apart (draw_clouds, the drawer's): the table only
        return {**_cloud_table(), "figure": None}
    if not draw:  # no plots (summary, none): the table only, and no stale figure
        figure.unlink(missing_ok=True)
        return {**_cloud_table(), "figure": None}
    return {
        **_cloud_table(),
        "figure": draw_clouds(field.points, sim.points, figure, vs_mesh.origin, params.report),
    }


def draw_clouds(
    field_m: np.ndarray, sim_m: np.ndarray, figure: Path, origin: np.ndarray, rp: Any
) -> str | None:
    """``clouds.png``: the field and simulated clouds (points ``field_m``, ``sim_m``) in
    the same views on the same axes, ``origin`` subtracted for display; its file name, or
    None (and no file) when ``rp.plots`` is off."""
    from .report import figures

    if not rp.plots:
        figure.unlink(missing_ok=True)
        return None
    figures.clouds_side_by_side(
        [
            ("field cloud", field_m, figures.FIELD_COLOUR),
            ("simulated cloud", sim_m, figures.SIMULATED_COLOUR),
        ],
        figure,
        origin=origin,
        max_points=rp.max_plot_points,
        seed=rp.seed,
        dpi=rp.dpi,
    )
    return figure.name


def _relative(path: str | Path, base: str | Path) -> str:
    """``path`` relative to folder ``base`` (POSIX separators), so that a record stays
    true when an output folder and its inputs move together; absolute where no relative
    path exists (another drive)."""
    import os

    try:
        return Path(os.path.relpath(Path(path).resolve(), Path(base).resolve())).as_posix()
    except ValueError:
        return Path(path).resolve().as_posix()


def _summary_texts(out: Path, level: str = "full") -> dict[str, str]:
    """Each comparison's summary paragraph: its report's, or (``level`` none, no report)
    the same words made from its ``comparison.json``."""
    from .report.text import summary_paragraph

    texts = {}
    for key in ("vs_mesh", "vs_field"):
        name, pick = (
            ("comparison.json", summary_paragraph)
            if level == "none"
            else ("report.json", lambda r: r["summary"])
        )
        try:
            texts[key] = pick(json.loads((out / key / name).read_text()))
        except (OSError, ValueError, KeyError):
            texts[key] = ""
    return texts
