"""The whole loop for one tree: reconstruct → scan the model → compare → report.

``run_tree(cloud, params, outdir)`` takes a field point cloud of one tree and

1. reconstructs a tree mesh (:func:`pipeline.reconstruct.reconstruct`): ``tree.ply``,
   ``cylinders.csv`` (qsm), ``tree.json``;
2. scans that mesh with the virtual TLS scanner (:func:`pipeline.scan.scan`) from a ring
   of stations around it: ``scan.laz`` (0.1 mm LAZ with the per-point fields) and
   ``scan.json``;
3. compares the simulated cloud, in float64, with the mesh it was scanned from
   (``vs_mesh/``: how well the scan design samples the model) and with the original field
   cloud (``vs_field/``: how close the simulation comes to the real scan):
   ``comparison.json`` and the distance clouds in each folder;
4. draws a report per comparison (``vs_*/report.html`` and plots) and one run page,
   ``report.html``, that presents both;

and writes ``run.json`` last: the parameters, software versions, ``timings_s`` per stage,
and the figures under ``reconstruction`` (``tree.json``'s names), ``scan``, ``vs_mesh`` and
``vs_field`` (``comparison.json``'s names).

**Stations.** Unless ``ScanParams.distance_m`` is given, the ``n_stations`` stations
stand evenly on a circle around the centre of the mesh's bounding box, the first on +x,
at the horizontal distance ``max(min_distance_m, 1.5 × crown diameter, 0.5 × height)``
(default ``min_distance_m`` 5 m), ``height_m`` (1.5 m) above the mesh's lowest point.
The crown diameter is the mean of the mesh's x and y extents and the height its z extent:
1.5 crown diameters from the centre keeps the whole crown in front of the scanner at about
one crown diameter from its edge, and half the height keeps the top below ~63° elevation
(the vertical field of view reaches 90°, but resolution on the crown top falls with
range); 5 m is a usual minimum for small trees.

**Parameters** are one frozen :class:`RunParams` nesting
:class:`~pipeline.reconstruct.ReconstructParams`, :class:`ScanParams` (stations and a
:class:`~pipeline.scan.ScannerSpec`), :class:`~pipeline.compare.CompareParams` and
:class:`~pipeline.report.ReportParams`. :func:`preset` gives the ``draft``, ``standard``
and ``fine`` presets (their cost and accuracy are measured in :data:`PRESET_MEASUREMENTS`),
:func:`load_config` reads a TOML file, and :func:`apply_settings` applies flat settings
(command-line flags, manifest columns).
"""

from __future__ import annotations

import hashlib
import html
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ._system import cpu_count
from .atomic import write_text
from .cloud import Cloud
from .compare import COMPARISON_FIGURES, CompareParams
from .errors import InputFormatError, InvalidParameterError
from .jsonio import json_ready as _jsonable
from .jsonio import write_json as _write_json
from .reconstruct import PrepareParams, ReconstructParams
from .report import ReportParams
from .scan import ScannerSpec

__all__ = [
    "PRESETS",
    "PRESET_MEASUREMENTS",
    "RunParams",
    "RunResult",
    "ScanParams",
    "SETTINGS",
    "apply_settings",
    "file_sha256",
    "load_config",
    "params_hash",
    "preset",
    "run_tree",
    "station_distance_m",
    "to_toml",
]

Progress = Callable[[float, str], None]


# -- parameters -------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class ScanParams:
    """Where the virtual scanner stands and how it scans.

    Parameters
    ----------
    n_stations : int
        Stations evenly spaced on a ring around the tree (3: three scans 120° apart).
    distance_m : float, optional
        Horizontal distance of the stations from the tree's centre; default the rule
        ``max(min_distance_m, 1.5 × crown diameter, 0.5 × height)`` (see the module doc).
    min_distance_m : float
        Smallest distance the rule gives.
    height_m : float
        Instrument height above the tree's lowest point.
    start_angle_deg : float
        Polar angle of the first station, counter-clockwise from +x.
    scanner : ScannerSpec
        Angular resolution, fields of view, ranges, optional beam and noise models.
    chunk_rays : int
        Rays cast per batch (bounds memory at ~200 B per ray; results do not depend on it).
    max_rays : int
        Refuse a scan needing more rays than this.
    """

    n_stations: int = 3
    distance_m: float | None = None
    min_distance_m: float = 5.0
    height_m: float = 1.5
    start_angle_deg: float = 0.0
    scanner: ScannerSpec = field(default_factory=ScannerSpec)
    chunk_rays: int = 1 << 19
    max_rays: int = 1_000_000_000

    def __post_init__(self) -> None:
        if isinstance(self.n_stations, bool) or int(self.n_stations) != self.n_stations:
            raise InvalidParameterError(f"n_stations must be an integer, got {self.n_stations!r}")
        if not 1 <= self.n_stations <= 64:
            raise InvalidParameterError(f"n_stations must be in [1, 64], got {self.n_stations}")
        if self.distance_m is not None and not (
            math.isfinite(self.distance_m) and self.distance_m > 0
        ):
            raise InvalidParameterError(
                f"distance_m must be a positive distance in metres, got {self.distance_m}"
            )
        if not (math.isfinite(self.min_distance_m) and self.min_distance_m > 0):
            raise InvalidParameterError(f"min_distance_m must be > 0, got {self.min_distance_m}")
        for name in ("height_m", "start_angle_deg"):
            if not math.isfinite(getattr(self, name)):
                raise InvalidParameterError(f"{name} must be a finite number")
        if int(self.chunk_rays) < 1 or int(self.max_rays) < 1:
            raise InvalidParameterError("chunk_rays and max_rays must be >= 1")
        if not isinstance(self.scanner, ScannerSpec):
            raise InvalidParameterError("scanner must be a ScannerSpec")


@dataclass(frozen=True, kw_only=True)
class RunParams:
    """Everything that decides one run of the loop.

    Parameters
    ----------
    reconstruct : ReconstructParams
        Method (qsm, poisson, bpa), preparation, QSM and mesh settings.
    scan : ScanParams
        Stations and scanner.
    compare : CompareParams
        Tolerance, surface sampling (its ``nthreads`` is replaced by ``threads``).
    report : ReportParams
        Plot resolution and subsample sizes.
    threads : int
        Threads for Open3D and the neighbour searches of every stage (0: all cores of the
        process). Executors set it so that workers × threads ≤ cores; results do not
        depend on it.
    preset : str, optional
        Name of the preset these parameters started from (a label, for the record).
    """

    reconstruct: ReconstructParams = field(default_factory=ReconstructParams)
    scan: ScanParams = field(default_factory=ScanParams)
    compare: CompareParams = field(default_factory=CompareParams)
    report: ReportParams = field(default_factory=ReportParams)
    threads: int = 0
    preset: str | None = None

    def __post_init__(self) -> None:
        if isinstance(self.threads, bool) or int(self.threads) != self.threads:
            raise InvalidParameterError(f"threads must be an integer, got {self.threads!r}")
        if self.threads < 0:
            raise InvalidParameterError(f"threads must be >= 0 (0: all cores), got {self.threads}")
        for name, cls in (
            ("reconstruct", ReconstructParams),
            ("scan", ScanParams),
            ("compare", CompareParams),
            ("report", ReportParams),
        ):
            if not isinstance(getattr(self, name), cls):
                raise InvalidParameterError(f"{name} must be a {cls.__name__}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (tuples as lists, ``None`` kept)."""
        return _jsonable(asdict(self))

    def with_threads(self, threads: int) -> RunParams:
        """A copy that uses ``threads`` threads in every stage."""
        return replace(self, threads=int(threads))


#: Settings that only decide how fast a run goes, never its result: left out of
#: :func:`params_hash`.
EXECUTION_ONLY = (
    ("threads",),
    ("preset",),
    ("reconstruct", "prepare", "threads"),
    ("reconstruct", "timeout_s"),
    ("compare", "nthreads"),
    ("scan", "chunk_rays"),
    ("scan", "max_rays"),
)


def params_hash(params: RunParams) -> str:
    """SHA-256 of the settings that decide a run's result (not threads or chunk sizes)."""
    d = params.to_dict()
    for path in EXECUTION_ONLY:
        node = d
        for key in path[:-1]:
            node = node.get(key, {})
        node.pop(path[-1], None)
    text = json.dumps(d, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def file_sha256(path: str | Path, *, chunk_bytes: int = 1 << 22) -> str:
    """SHA-256 of a file's content (read in chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk_bytes):
            h.update(block)
    return h.hexdigest()


def _presets() -> dict[str, RunParams]:
    def make(
        name: str,
        *,
        resolution_deg: float,
        facets: int,
        voxel_m: float,
        max_samples: int,
        report: ReportParams,
    ) -> RunParams:
        return RunParams(
            reconstruct=ReconstructParams(
                facets=facets, prepare=PrepareParams(voxel_size_m=voxel_m)
            ),
            scan=ScanParams(
                scanner=ScannerSpec(
                    horizontal_resolution_deg=resolution_deg,
                    vertical_resolution_deg=resolution_deg,
                )
            ),
            compare=CompareParams(max_samples=max_samples),
            report=report,
            preset=name,
        )

    return {
        "draft": make(
            "draft",
            resolution_deg=0.08,
            facets=16,
            voxel_m=0.01,
            max_samples=200_000,
            report=ReportParams(max_view_points=10_000, max_plot_points=30_000, dpi=80),
        ),
        "standard": make(
            "standard",
            resolution_deg=0.04,
            facets=32,
            voxel_m=0.005,
            max_samples=1_000_000,
            report=ReportParams(),
        ),
        "fine": make(
            "fine",
            resolution_deg=0.02,
            facets=64,
            voxel_m=0.005,
            max_samples=2_000_000,
            report=ReportParams(),
        ),
    }


#: The presets by name: ``draft`` (a quick look), ``standard`` (the default), ``fine``.
PRESETS: dict[str, RunParams] = _presets()

#: What each preset costs and how accurate it is, measured with
#: ``benchmarks/bench_presets.py`` (printed in ``treesim run --help``).
PRESET_MEASUREMENTS = """\
Presets: what they set, and their cost and accuracy as measured on 2026-11-23 with
benchmarks/bench_presets.py (x86_64, 2 cores, Python 3.11, open3d 0.20; one tree per
process; time of the whole loop with its reports, imports excluded; 'p95 sim->field': 95 %
of the simulated points lie this close to the field cloud):

  preset    scan step  facets  mesh volume vs cylinders  voxel  mesh samples
  draft     0.08 deg   16      -2.6 %                    10 mm  <= 200k
  standard  0.04 deg   32      -0.64 %                    5 mm  <= 1M
  fine      0.02 deg   64      -0.16 %                    5 mm  <= 2M

  bundled coffee tree (14,667 points, 3.7 m; no truth):
  preset    time    peak mem  simulated points  p95 sim->field  wood volume
  draft      4.0 s   336 MB      32,618            17.5 mm        20.2 L
  standard   6.9 s   431 MB     131,443            17.1 mm        20.1 L
  fine      10.4 s   523 MB     526,172            17.1 mm        20.1 L

  procedural sapling (truth: DBH 3.06 cm, 2.95 L) scanned at 0.02 deg, 2 mm noise
  (342,773 points):
  preset    time    peak mem  simulated points  p95 sim->field  DBH error  volume error
  draft      5.4 s   375 MB      15,051             3.2 mm       -0.3 mm     +0.7 %
  standard  10.9 s   474 MB      62,642             2.4 mm       -0.1 mm     +5.8 %
  fine      16.4 s   584 MB     250,607             2.4 mm       -0.1 mm     +5.8 %

  About half of each run is drawing the two reports' plots.
"""


def preset(name: str) -> RunParams:
    """The preset called ``name`` (``draft``, ``standard`` or ``fine``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise InvalidParameterError(
            f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}"
        ) from None


# -- settings from TOML, flags and manifests ---------------------------------------------
def _float_or_none(text: Any) -> float | None:
    v = float(text)
    return None if v == 0 else v


#: Flat settings (command-line flags ``--NAME`` with dashes, manifest columns) and the
#: nested fields each sets, with the converter applied to its text.
SETTINGS: dict[str, tuple[tuple[tuple[str, ...], ...], Callable[[Any], Any], str]] = {
    "method": ((("reconstruct", "method"),), str, "reconstruction method: qsm, poisson, bpa"),
    "facets": ((("reconstruct", "facets"),), int, "facets per cylinder ring of the QSM mesh"),
    "voxel_m": (
        (("reconstruct", "prepare", "voxel_size_m"),),
        _float_or_none,
        "voxel size for downsampling the field cloud (0: off)",
    ),
    "depth": ((("reconstruct", "poisson_depth"),), int, "Poisson octree depth"),
    "stations": ((("scan", "n_stations"),), int, "stations on the ring"),
    "distance_m": (
        (("scan", "distance_m"),),
        _float_or_none,
        "station distance from the tree (0: the size rule)",
    ),
    "height_m": ((("scan", "height_m"),), float, "instrument height above the tree base"),
    "resolution_deg": (
        (
            ("scan", "scanner", "horizontal_resolution_deg"),
            ("scan", "scanner", "vertical_resolution_deg"),
        ),
        float,
        "horizontal and vertical angular step of the scanner",
    ),
}


def apply_settings(params: RunParams, settings: Mapping[str, Any], *, where: str = "") -> RunParams:
    """Apply flat settings (see :data:`SETTINGS`) to ``params``.

    Parameters
    ----------
    params : RunParams
    settings : mapping of str -> value
        Values may be text (manifest cells); empty text and ``None`` are skipped.
    where : str
        Prefix for error messages (e.g. ``"manifest.csv row 3: "``).
    """
    nested: dict[str, Any] = {}
    for key, value in settings.items():
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        if key not in SETTINGS:
            raise InvalidParameterError(
                f"{where}unknown setting {key!r}; known: {', '.join(SETTINGS)}"
            )
        paths, convert, _ = SETTINGS[key]
        try:
            v = convert(value.strip() if isinstance(value, str) else value)
        except (TypeError, ValueError):
            raise InvalidParameterError(f"{where}{key}: cannot read {value!r}") from None
        for path in paths:
            node = nested
            for k in path[:-1]:
                node = node.setdefault(k, {})
            node[path[-1]] = v
    return _merge(params, nested, where)


def _annotation_allows_none(f: Any) -> bool:
    return "None" in str(f.type)


def _coerce(value: Any, current: Any, f: Any, name: str) -> Any:
    if value is None or (isinstance(value, str) and value.lower() in ("none", "auto")):
        if _annotation_allows_none(f):
            return None
        if value is None:
            raise InvalidParameterError(f"{name} needs a value")
    if isinstance(current, bool) or str(f.type) == "bool":
        if not isinstance(value, bool):
            raise InvalidParameterError(f"{name} must be true or false, got {value!r}")
        return value
    if isinstance(value, list):
        return tuple(value)
    if isinstance(current, (int, float)) and not isinstance(current, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InvalidParameterError(f"{name} must be a number, got {value!r}")
        if isinstance(current, int) and "float" not in str(f.type) and value != int(value):
            raise InvalidParameterError(f"{name} must be an integer, got {value!r}")
        return int(value) if isinstance(current, int) and "float" not in str(f.type) else value
    return value


def _merge(obj: Any, mapping: Mapping[str, Any], where: str = "", prefix: str = "") -> Any:
    """A copy of dataclass ``obj`` with the (nested) ``mapping`` applied, validated."""
    known = {f.name: f for f in fields(obj)}
    changes: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if key not in known:
            section = f"[{prefix[:-1]}]" if prefix else "the top level"
            raise InvalidParameterError(
                f"{where}unknown setting {key!r} in {section}; known: {', '.join(known)}"
            )
        current = getattr(obj, key)
        if is_dataclass(current):
            if not isinstance(value, Mapping):
                raise InvalidParameterError(f"{where}{name} must be a table ([{name}])")
            changes[key] = _merge(current, value, where, f"{name}.")
        else:
            changes[key] = _coerce(value, current, known[key], name)
    if not changes:
        return obj
    try:
        return replace(obj, **changes)
    except InvalidParameterError as exc:
        section = f" in [{prefix[:-1]}]" if prefix else ""
        raise InvalidParameterError(f"{where}{exc}{section}") from None
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(
            f"{where}bad value in [{prefix[:-1] or 'top'}]: {exc}"
        ) from None


def params_from_dict(
    data: Mapping[str, Any], *, base: RunParams | None = None, where: str = ""
) -> RunParams:
    """RunParams from a nested mapping (a parsed TOML file).

    A top-level ``preset`` key picks the base preset (unless ``base`` is given); every
    other key overrides a field of it. Unknown keys are errors.
    """
    data = dict(data)
    name = data.pop("preset", None)
    if base is None:
        base = preset(str(name)) if name is not None else preset("standard")
    return _merge(base, data, where)


def load_config(path: str | Path, *, base: RunParams | None = None) -> RunParams:
    """Read RunParams from a TOML file (see :func:`to_toml` for its shape).

    Raises
    ------
    InputFormatError
        If the file is missing or not valid TOML.
    InvalidParameterError
        If a key is unknown or a value is out of range.
    """
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        try:
            import tomli as tomllib  # type: ignore[no-redef]
        except ModuleNotFoundError:
            raise InvalidParameterError(
                "reading --config needs Python 3.11 or 'pip install tomli'"
            ) from None
    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"config file {p} not found; check the path")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"config file {p} could not be read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputFormatError(f"config file {p} is not valid TOML: {exc}") from None
    return params_from_dict(data, base=base, where=f"{p.name}: ")


def to_toml(params: RunParams) -> str:
    """The parameters as a TOML file :func:`load_config` reads back (``None``, "derived
    from the data" or "off", is written as the string ``"none"``)."""
    d = params.to_dict()
    d.pop("preset", None)
    lines = [f'preset = "{params.preset}"' if params.preset else '# preset = "standard"']

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    def table(name: str, node: dict[str, Any]) -> None:
        scalars = {k: v for k, v in node.items() if not isinstance(v, dict) or k == "reflectance"}
        subs = {k: v for k, v in node.items() if k not in scalars}
        if name:
            lines.append("")
            lines.append(f"[{name}]")
        for k, v in scalars.items():
            if v is None:
                lines.append(f'{k} = "none"  # derived from the data, or off')
            elif isinstance(v, dict):
                inner = ", ".join(f"{kk} = {value(vv)}" for kk, vv in v.items())
                lines.append(f"{k} = {{ {inner} }}")
            else:
                lines.append(f"{k} = {value(v)}")
        for k, v in subs.items():
            table(f"{name}.{k}" if name else k, v)

    table("", d)
    return "\n".join(lines) + "\n"


def station_distance_m(
    crown_diameter_m: float, height_m: float, *, min_distance_m: float = 5.0
) -> float:
    """The default station distance: ``max(min_distance_m, 1.5 × crown diameter,
    0.5 × height)``."""
    return float(max(min_distance_m, 1.5 * crown_diameter_m, 0.5 * height_m))


# -- the result ---------------------------------------------------------------------------
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


#: Stages timed in ``run.json``'s ``timings_s`` (plus ``total``).
STAGES = ("read", "reconstruct", "scan", "compare_mesh", "compare_field", "report")


def software_versions() -> dict[str, str]:
    """Versions of Python, treesim and every library a run uses."""
    from ._version import software_versions as base

    return base("pymeshlab", "trimesh", "matplotlib")


def _scene_from_model(model: Any) -> Any:
    from .scene import Scene

    return Scene.from_labelled_mesh(
        model.vertices, model.faces, model.face_label, name_prefix="reconstruction:"
    )


def _sub(progress: Progress | None, lo: float, hi: float) -> Progress | None:
    if progress is None:
        return None

    def say(fraction: float, message: str) -> None:
        progress(lo + (hi - lo) * min(max(fraction, 0.0), 1.0), message)

    return say


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
    from .io import read_cloud, write_cloud
    from .reconstruct import reconstruct
    from .report import build_report
    from .scan import ring_around, scan

    params = params or preset("standard")
    if not isinstance(params, RunParams):
        raise InvalidParameterError(f"params must be RunParams, got {type(params).__name__}")
    say = progress or (lambda f, m: None)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    threads = int(params.threads) or cpu_count()
    timings: dict[str, float] = {}
    t_all = time.perf_counter()

    # -- read ------------------------------------------------------------------------------
    say(0.0, "reading")
    t0 = time.perf_counter()
    inputs: dict[str, Any]
    if isinstance(cloud, (str, Path)):
        path = Path(cloud)
        if not path.is_file():
            raise InputFormatError(f"{path} not found; check the path")
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
    model = reconstruct(field_cloud, rp, progress=_sub(say, 0.02, 0.35))
    written = model.write(out)
    timings["reconstruct"] = time.perf_counter() - t0

    # -- scan ------------------------------------------------------------------------------
    t0 = time.perf_counter()
    scene = _scene_from_model(model)
    lo, hi = scene.bounds
    ext = hi - lo
    crown_d = float(0.5 * (ext[0] + ext[1]))
    height = float(ext[2])
    sp = params.scan
    if sp.distance_m is not None:
        distance, rule = float(sp.distance_m), "given"
    else:
        distance = station_distance_m(crown_d, height, min_distance_m=sp.min_distance_m)
        rule = (
            f"max({sp.min_distance_m:g} m, 1.5 × crown diameter {crown_d:.3g} m, "
            f"0.5 × height {height:.3g} m)"
        )
    stations = ring_around(
        scene.bounds,
        sp.n_stations,
        distance_m=distance,
        height_m=sp.height_m,
        start_angle_deg=sp.start_angle_deg,
    )
    say(0.35, "scanning")
    result = scan(
        scene,
        stations,
        sp.scanner,
        chunk_rays=int(sp.chunk_rays),
        max_rays=int(sp.max_rays),
        nthreads=threads,
        progress=_sub(say, 0.35, 0.5),
    )
    sim = result.cloud
    scan_path = write_cloud(out / "scan.laz", sim)
    scan_summary = {
        "mesh": written["mesh"].name,
        "triangles": scene.n_triangles,
        "labels_in_scene": scene.labels_present(),
        "output": scan_path.name,
        "station_rule": {
            "distance_m": distance,
            "rule": rule,
            "crown_diameter_m": crown_d,
            "height_m": height,
            "n_stations": sp.n_stations,
            "height_above_base_m": sp.height_m,
        },
        **result.summary(),
    }
    _write_json(out / "scan.json", scan_summary)
    timings["scan"] = time.perf_counter() - t0
    scan_inputs = {
        "source": "scan.json",
        "scanner": sp.scanner.to_dict(),
        "models_active": result.models,
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
        "reference": f"../{written['mesh'].name}",
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
    write_text(out / "report.html", _run_page(summary, __version__))
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


# -- the run page -------------------------------------------------------------------------
def _len(v: Any) -> str:
    from .report.text import length

    return length(v) if isinstance(v, (int, float)) else "–"


def _pct(v: Any) -> str:
    from .report.text import percent

    return percent(v) if isinstance(v, (int, float)) else "–"


def _num(v: Any, unit: str = "", scale: float = 1.0, digits: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return f"{v:,}{unit}"
    if isinstance(v, float):
        return f"{v * scale:.{digits}g}{unit}"
    return html.escape(str(v))


_CSS = """
body{font:15px/1.45 system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222;padding:0 1em}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.6em 0}td,th{padding:.25em .8em;border-bottom:1px solid #eee;
text-align:right}th:first-child,td:first-child{text-align:left}.muted{color:#777}
.cards{display:flex;gap:1.5em;flex-wrap:wrap}.card{flex:1 1 420px}img{max-width:100%}
a{color:#0a58ca}code{background:#f4f4f4;padding:0 .2em}
"""


def _run_page(s: dict[str, Any], version: str) -> str:
    """A small self-contained page: the tree, the scan, both comparisons, links."""
    esc = html.escape
    rec = s["reconstruction"]
    sc = s["scan"]
    rule = sc["station_rule"]
    rows_tree = [
        ("method", esc(str(s["parameters"]["reconstruct"]["method"]))),
        ("DBH", _num(rec.get("dbh_m"), " cm", 100)),
        ("height", _num(rec.get("height_m"), " m")),
        ("wood volume", _num(rec.get("volume_total_m3"), " L", 1000)),
        (
            "stem / branch volume",
            f"{_num(rec.get('volume_stem_m3'), ' L', 1000)} / "
            f"{_num(rec.get('volume_branch_m3'), ' L', 1000)}",
        ),
        ("cylinders", _num(rec.get("n_cylinders"))),
        ("triangles", _num(rec.get("n_triangles"))),
        ("watertight", _num(rec.get("watertight"))),
        (
            "field points (used)",
            f"{_num(rec.get('points_input'))} ({_num(rec.get('points_used'))})",
        ),
    ]
    spec = s["parameters"]["scan"]["scanner"]
    rows_scan = [
        (
            "stations",
            f"{rule['n_stations']} on a ring, {rule['distance_m']:.2f} m out "
            f"({esc(rule['rule'])}), {rule['height_above_base_m']:g} m high",
        ),
        (
            "angular step",
            f"{spec['horizontal_resolution_deg']:g}° × {spec['vertical_resolution_deg']:g}°",
        ),
        ("rays cast", _num(sc["rays_cast"])),
        ("simulated points", _num(sc["points"])),
        ("models", esc(", ".join(sc["models_active"]) or "geometry only")),
    ]
    t = s["timings_s"]
    rows_time = [(k.replace("_", " "), f"{t[k]:.2f} s") for k in (*STAGES, "total") if k in t]

    def cmp_rows(c: dict[str, Any]) -> str:
        a, m = c["accuracy"], c["completeness"]
        rows = [
            (
                "accuracy: mean / p95 / max",
                f"{_len(a['mean_m'])} / {_len(a['p95_m'])} / {_len(a['max_m'])}",
            ),
            (
                "completeness: mean / p95 / max",
                f"{_len(m['mean_m'])} / {_len(m['p95_m'])} / {_len(m['max_m'])}",
            ),
            ("coverage within τ", f"{_pct(c['coverage'])} (τ = {_len(c['tolerance_m'])})"),
            ("Hausdorff", _len(c["hausdorff_m"])),
            ("Chamfer", _len(c["chamfer_m"])),
        ]
        return "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows)

    def table(rows: list[tuple[str, str]]) -> str:
        return (
            "<table>" + "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows) + "</table>"
        )

    cards = []
    for key, title, what, view in (
        (
            "vs_mesh",
            "Simulated scan vs the tree mesh",
            "how well the scan design samples the model",
            "views_completeness.png",  # where the mesh was not seen
        ),
        (
            "vs_field",
            "Simulated scan vs the field cloud",
            "how close the simulation comes to the real scan",
            "views_accuracy.png",  # where the simulation departs from the field cloud
        ),
    ):
        cards.append(
            f'<div class="card"><h2>{title}</h2><p class="muted">{what}</p>'
            f"<p>{esc(s['summary_text'].get(key, ''))}</p>"
            f"<table>{cmp_rows(s[key])}</table>"
            f'<p><a href="{key}/report.html">full report</a> · '
            f'<a href="{key}/comparison.json">comparison.json</a></p>'
            f'<a href="{key}/report.html"><img src="{key}/{view}" '
            f'alt="distances ({key})"></a></div>'
        )
    files = "".join(
        f'<li><a href="{esc(v)}">{esc(v)}</a></li>' for v in dict.fromkeys(s["files"].values())
    )
    return f"""<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>treesim run: {esc(s["name"])}</title><style>{_CSS}</style></head><body>
<h1>treesim run: {esc(s["name"])}</h1>
<p class="muted">field cloud {esc(str(s["inputs"].get("cloud") or "in memory"))} ·
preset {esc(str(s["parameters"].get("preset") or "custom"))} · treesim {esc(version)}</p>
<div class="cards"><div class="card"><h2>Reconstruction</h2>{table(rows_tree)}</div>
<div class="card"><h2>Virtual scan</h2>{table(rows_scan)}</div></div>
<div class="cards">{"".join(cards)}</div>
<h2>Time per stage</h2>{table(rows_time)}
<h2>Files</h2><ul>{files}<li><a href="run.json">run.json</a> (parameters, versions,
timings, every figure)</li></ul></body></html>
"""
