"""The run's parameters: stations and scanner (:class:`ScanParams`), the whole loop
(:class:`RunParams`), the run presets and the settings hash."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

from ..errors import InvalidParameterError
from ..jsonio import json_ready
from ._fields import check_bounds, param, walk
from .compare import CompareParams, ReportParams
from .reconstruct import PrepareParams, ReconstructParams
from .scanner import ScannerSpec, resolution_fields

__all__ = [
    "DEFAULT_RUN_PRESET",
    "LODS",
    "RUN_PRESETS",
    "RunParams",
    "ScanParams",
    "execution_only_paths",
    "params_hash",
    "run_preset",
]

Lod = Literal["auto", "full"]
#: Levels of detail of a scan (:attr:`ScanParams.lod`).
LODS: tuple[str, ...] = ("auto", "full")


@dataclass(frozen=True, kw_only=True)
class ScanParams:
    """Where the virtual scanner stands and how it scans.

    Parameters
    ----------
    n_stations : int
        Stations evenly spaced on a ring around the tree (3: three scans 120° apart).
    distance_m : float, optional
        Horizontal distance of the stations from the tree's centre; default the station
        rule ``max(min_distance_m, 1.5 × crown diameter, 0.5 × height)``
        (:mod:`treesim.scan.stations`).
    min_distance_m : float
        Smallest distance the rule gives.
    height_m : float
        Instrument height above the tree's lowest point.
    start_angle_deg : float
        Polar angle of the first station, counter-clockwise from +x.
    scanner : ScannerSpec
        Angular resolution, fields of view, ranges, optional beam and noise models.
    lod : {"auto", "full"}
        Level of detail (:func:`treesim.scan.scan`): ``"auto"`` models only what the
        scene requires and says why in the scan's summary; ``"full"`` models everything
        everywhere (every beam sub-ray, every triangle, the QSM mesh's full facets).
    chunk_rays : int
        Rays cast per batch (bounds memory at ~200 B per ray; results do not depend on it).
    max_rays : int
        Refuse a scan needing more rays than this.

    Examples
    --------
    >>> import treesim as ts
    >>> ts.ScanParams(n_stations=4, height_m=1.6).n_stations
    4
    """

    n_stations: int = param(3, help="stations on the ring", flag="--stations", ge=1, le=64)
    distance_m: float | None = param(
        None,
        help="station distance from the scene's centre",
        unit="m",
        none_means="the station rule",
        gt=0,
        le=10_000,
    )
    min_distance_m: float = param(
        5.0, help="smallest distance the station rule gives", unit="m", gt=0, le=10_000
    )
    height_m: float = param(
        1.5,
        help="instrument height above the scene's lowest point",
        unit="m",
        ge=-1_000,
        le=1_000,
    )
    start_angle_deg: float = param(
        0.0,
        help="polar angle of the first station, counter-clockwise from +x",
        unit="deg",
        ge=-360,
        le=360,
    )
    scanner: ScannerSpec = param(help="the scanner", factory=ScannerSpec)
    lod: Lod = param(
        "auto",
        help="level of detail: auto models only what the scene requires (rays where "
        "geometry can be, beam sub-rays where footprints straddle edges, no geometry no "
        "station can record, QSM facets from the projected size); full models everything "
        "everywhere",
        choices=LODS,
    )
    chunk_rays: int = param(
        1 << 19,
        help="rays per batch; bounds memory at ~200 B per ray",
        execution_only=True,
        ge=1,
    )
    max_rays: int = param(
        1_000_000_000, help="refuse scans needing more rays than this", execution_only=True, ge=1
    )

    def __post_init__(self) -> None:
        check_bounds(self)
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
        Name of the run preset these parameters started from (a label, for the record).

    Examples
    --------
    >>> import treesim as ts
    >>> params = ts.run_preset("draft")
    >>> params.scan.n_stations
    3
    """

    reconstruct: ReconstructParams = param(help="reconstruction", factory=ReconstructParams)
    scan: ScanParams = param(help="stations and scanner", factory=ScanParams)
    compare: CompareParams = param(help="comparison", factory=CompareParams)
    report: ReportParams = param(help="reports", factory=ReportParams)
    threads: int = param(
        0, help="threads for every stage (0: all cores)", execution_only=True, ge=0
    )
    preset: str | None = param(
        None,
        help="the run preset these settings started from",
        none_means="custom",
        execution_only=True,
    )

    def __post_init__(self) -> None:
        check_bounds(self)
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
        return json_ready(asdict(self))

    def with_threads(self, threads: int) -> RunParams:
        """A copy that uses ``threads`` threads in every stage."""
        return replace(self, threads=int(threads))


def execution_only_paths() -> tuple[tuple[str, ...], ...]:
    """Fields that decide only how fast a run goes, never its result (the model's
    ``execution_only`` flag): left out of :func:`params_hash`."""
    return tuple(info.path for info in walk(RunParams) if info.execution_only)


def params_hash(params: RunParams) -> str:
    """SHA-256 of the settings that decide a run's result (not threads or chunk sizes)."""
    d = params.to_dict()
    for path in execution_only_paths():
        node = d
        for key in path[:-1]:
            node = node.get(key, {})
        node.pop(path[-1], None)
    text = json.dumps(d, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _run_presets() -> dict[str, RunParams]:
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
            scan=ScanParams(scanner=ScannerSpec(**resolution_fields(resolution_deg))),
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


#: The run presets by name: ``draft`` (a quick look), ``standard`` (the default),
#: ``fine``. Each is a point of the committed sweep ``benchmarks/sweeps/presets.toml``; its
#: measured cost and accuracy: :func:`treesim.params.preset_measurements`.
RUN_PRESETS: dict[str, RunParams] = _run_presets()


#: The run preset used when none is named (the CLI, ``run_tree``, ``run_batch``, TOML).
DEFAULT_RUN_PRESET = "standard"


def run_preset(name: str = DEFAULT_RUN_PRESET) -> RunParams:
    """The run preset called ``name`` (``draft``, ``standard`` or ``fine``; default
    :data:`DEFAULT_RUN_PRESET`).

    Parameters
    ----------
    name : str, optional
        ``draft``, ``standard`` or ``fine``.

    Returns
    -------
    RunParams

    Raises
    ------
    InvalidParameterError
        If no run preset has that name.

    Examples
    --------
    >>> import treesim as ts
    >>> ts.run_preset("fine").preset
    'fine'
    """
    try:
        return RUN_PRESETS[name]
    except KeyError:
        raise InvalidParameterError(
            f"unknown preset {name!r}; the run presets are {', '.join(RUN_PRESETS)}"
        ) from None
