"""Scanning a plot station by station, loading only the trees each station can record,
and each tree's figures in the plot context.

:func:`scan_plot` casts each station alone (:func:`treesim.steps.scan_scene` with the
plot's :meth:`~treesim.plot.Plot.frame` and ``station_offset``), into a scene of only
the trees whose bounding box it can record and the terrain triangles within its range.
A tree whose box lies wholly beyond ``max_range_m`` or outside the field of view can
neither return nor occlude a return (any ray into the tree enters its box first), so it
is never built or loaded for that station: the points are those of the whole plot's
scan (same frame, same per-station random draws; tested bit for bit). Trees are built
lazily, kept while a later station needs them and within ``cache_triangles``, and
dropped otherwise, so memory follows the largest station's scene, not the plot.

:func:`tree_figures` measures each tree's points (by ``tree_id``) against its own mesh:
points, coverage at τ, AVOHD accuracy and completeness (:func:`treesim.compare.compare`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import Cloud
from ..errors import InvalidParameterError
from ..params import CompareParams, ScanParams
from ..scan import Station
from ..scan.occupancy import TriangleBounds, reachable, triangle_bounds
from ..scan.timing import station_duration_s, timing_summary
from ..scene import MeshPart, Scene
from .core import Plot
from .sectors import (
    box_corners,
    check_sectors,
    memory_advice,
    merged_lod,
    merged_stats,
    station_extent,
    station_sectors,
)

__all__ = [
    "PlotScanResult",
    "box_reachable",
    "load_tree_parts",
    "PLOT_SCAN_FILES",
    "plot_fields",
    "plot_scan_files",
    "plot_stations",
    "read_stations",
    "read_stations_csv",
    "save_tree_parts",
    "scan_plot",
    "station_trees",
    "tree_figures",
    "write_figures_csv",
]

Progress = Callable[[float, str], None]
#: Default bound on the triangles of built trees kept between stations.
CACHE_TRIANGLES = 20_000_000

_BOX_FACES = np.array(
    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
)  # fmt: skip
_TOP = [2, 3]  # rows of _BOX_FACES on z = max (corners 1, 3, 5, 7 have z = max)


def box_reachable(bounds: np.ndarray, station: Station, spec: Any, origin: np.ndarray) -> bool:
    """Whether ``station`` scanning with ``spec`` can record anything inside the box
    ``bounds`` (2, 3), or have a ray stopped by it. False only when the whole box lies
    beyond ``max_range_m`` or outside the field of view (with the scanner's own pointing
    margins, widened): then no triangle in it is loaded by a scan either.

    ``origin`` is the local frame's origin (the scan's float32 error grows with the
    distance from it; the margin used here is five times the scan's)."""
    lo, hi = np.asarray(bounds, dtype=np.float64)
    pos = station.position
    if np.all(pos >= lo - 1e-3) and np.all(pos <= hi + 1e-3):
        return True
    corners = box_corners(bounds) - pos
    rel = corners @ station.rotation
    b = triangle_bounds(rel[_BOX_FACES])
    # one box-wide bound: the top face's halves carry the azimuths of the whole box's
    # footprint; elevations and the distance are the extremes over all faces
    top = np.asarray(_TOP)
    union = TriangleBounds(
        az_lo=b.az_lo[top],
        az_hi=b.az_hi[top],
        full_az=b.full_az[top] | bool(b.full_az.any()),
        el_lo=np.full(2, b.el_lo.min()),
        el_hi=np.full(2, b.el_hi.max()),
        d_min=np.full(2, b.d_min.min()),
    )
    o = pos - origin
    radius = float(np.abs(np.asarray(bounds) - origin).max()) * math.sqrt(3.0)
    err = 1e-4 * (radius + float(np.linalg.norm(o))) + 1e-6
    return bool(reachable(union, spec, abs_error_m=err).any())


def station_trees(
    plot: Plot, station: Station, spec: Any, origin: np.ndarray | None = None
) -> dict[str, list[int]]:
    """The plot's trees a station can record (``loaded``) and those it cannot, and why
    (``beyond_range``: the whole box farther than ``max_range_m``; ``outside_fov``).
    Builds each tree once to know its bounds (see :meth:`Plot.tree_bounds`)."""
    origin = plot.frame().origin_array if origin is None else origin
    out: dict[str, list[int]] = {"loaded": [], "beyond_range": [], "outside_fov": []}
    for tid in plot.tree_ids:
        out[_box_verdict(plot.tree_bounds(tid), station, spec, origin)].append(tid)
    return out


def _box_verdict(bounds: np.ndarray, station: Station, spec: Any, origin: np.ndarray) -> str:
    """``loaded`` (:func:`box_reachable`), else ``beyond_range`` or ``outside_fov``."""
    if box_reachable(bounds, station, spec, origin):
        return "loaded"
    if _box_distance(bounds, station.position) > spec.max_range_m:
        return "beyond_range"
    return "outside_fov"


def _box_distance(bounds: np.ndarray, p: np.ndarray) -> float:
    lo, hi = np.asarray(bounds, dtype=np.float64)
    return float(np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0)))


def _terrain_within(part: MeshPart, p: np.ndarray, range_m: float) -> MeshPart | None:
    """The terrain's triangles whose bounding box comes within ``range_m`` of ``p``
    (the rest can neither return nor occlude)."""
    tri = np.asarray(part.vertices)[part.faces]
    gap = np.maximum(np.maximum(tri.min(axis=1) - p, p - tri.max(axis=1)), 0.0)
    keep = np.einsum("ij,ij->i", gap, gap) <= range_m * range_m
    if not keep.any():
        return None
    return MeshPart(part.vertices, part.faces[keep], part.label, part.name, part.tree_id)


@dataclass
class PlotScanResult:
    """A plot's scan.

    Attributes
    ----------
    cloud : Cloud
        The points (empty with a ``sink``) with the scan's fields, ``tree_id`` among
        them, and ``station`` numbered over all stations.
    stations : list of Station
    station_stats : list of StationStats
        As :class:`treesim.scan.ScanResult`'s, one per station.
    loading : list of dict
        Per station: ``trees_loaded`` (ids), ``trees_beyond_range``,
        ``trees_outside_fov``, ``triangles_loaded`` (trees and terrain patch),
        ``triangles_total`` (the whole plot's), ``trees_built`` (built for it: not
        held from an earlier station; none with an executor, whose tasks build each tree
        once, before the stations), ``time_s``, ``rss_before_bytes`` and
        ``rss_peak_bytes`` (the process's resident memory at the station's start and its
        peak: since that start in a station task, over the process's life inline; None
        where ``/proc`` is not there).
    lod : list of dict
        Each station's scan ``lod`` account.
    warnings : list of str
    points_written : int
        Points handed to the sink.
    total_s : float

    Examples
    --------
    >>> import treesim as ts
    >>> plot = ts.read_plot("plot/plot.toml")  # doctest: +SKIP
    >>> result = ts.scan_plot(plot, [(0.0, 0.0, 1.5), (7.0, -4.0, 1.6)])  # doctest: +SKIP
    >>> result.cloud.fields["tree_id"]  # doctest: +SKIP
    """

    cloud: Cloud
    stations: list[Station]
    station_stats: list[Any]
    loading: list[dict[str, Any]]
    lod: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    points_written: int = 0
    total_s: float = 0.0
    spec: Any = None
    models: list[str] = field(default_factory=list)
    #: time the tasks spent building the trees (once each) before the stations
    #: (``local`` and ``dask`` executors; 0 inline, where stations build their own)
    trees_build_s: float = 0.0

    @property
    def n_points(self) -> int:
        return sum(s.points for s in self.station_stats)

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures (what ``plot_scan.json`` holds about the scan): as a
        single-tree ``scan.json``, ``timing`` (the scanner's mechanics, each station's
        duration and the ``time_s`` convention: :func:`treesim.scan.timing.timing_summary`)
        and each station's ``scan_duration_s``, a station that records nothing included."""
        return {
            "points": self.n_points,
            "rays_cast": sum(s.rays_cast for s in self.station_stats),
            "scanner": self.spec.to_dict() if self.spec is not None else None,
            "timing": timing_summary(self.spec) if self.spec is not None else None,
            "models_active": list(self.models),
            "stations": [
                {**s.to_dict(), **ld}
                for s, ld in zip(self.station_stats, self.loading, strict=True)
            ],
            "lod": self.lod,
            "warnings": list(self.warnings),
            "total_s": self.total_s,
            "trees_build_s": self.trees_build_s,
        }


def _as_station(s: Any) -> Station:
    if isinstance(s, Station):
        return s
    try:
        xyz = tuple(float(c) for c in s)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"a station is a Station or (x, y, z), got {s!r}") from None
    if len(xyz) != 3:
        raise InvalidParameterError(f"a station is (x, y, z) in metres, got {s!r}")
    return Station(position_m=xyz)


def _station_needs(
    plot: Plot, placed: list[Station], spec: Any, origin: np.ndarray, cache_triangles: int
) -> tuple[dict[int, list[int]], list[dict[str, list[int]]]]:
    """Which station needs which tree (``loaded`` by :func:`_box_verdict`), and why each
    of the others is left out, per station."""
    # which station needs which tree: every tree is built once for its bounds (kept
    # within the budget, oldest dropped first)
    needs: dict[int, list[int]] = {}
    why: list[dict[str, list[int]]] = [{"beyond_range": [], "outside_fov": []} for _ in placed]
    for tid in plot.tree_ids:
        was = tid in plot.loaded
        bounds = plot.tree_bounds(tid)
        for k, st in enumerate(placed):
            verdict = _box_verdict(bounds, st, spec, origin)
            if verdict == "loaded":
                needs.setdefault(k, []).append(tid)
            else:
                why[k][verdict].append(tid)
        if not was:
            _trim(plot, set(needs.get(0, [])), int(cache_triangles), keep_last=tid)
    return needs, why


@dataclass
class _Gathered:
    """What the stations' scans give, in station order."""

    pts: list[np.ndarray] = field(default_factory=list)
    flds: list[dict[str, np.ndarray]] = field(default_factory=list)
    stats: list[Any] = field(default_factory=list)
    loading: list[dict[str, Any]] = field(default_factory=list)
    lods: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    written: int = 0
    models: list[str] = field(default_factory=list)
    trees_build_s: float = 0.0


@dataclass
class _StationScan:
    """How each station is scanned (:func:`scan_plot`'s settings)."""

    params: ScanParams
    frame: Any
    n: int
    say: Progress
    threads: int
    window: bool
    sink: Callable[[np.ndarray, dict[str, np.ndarray]], None] | None
    check_inside: bool
    #: a folder of trees saved by :func:`save_tree_parts` (a station task's): its trees
    #: are read from there rather than built
    cache_dir: str | None = None

    def __call__(
        self,
        plot: Plot,
        k: int,
        st: Station,
        ids: list[int],
        ground: MeshPart | None,
        out: _Gathered,
        release: Callable[[], None] | None = None,
        *,
        columns: tuple[int, int] | None = None,
        station_ids: list[int] | None = None,
    ) -> int:
        """Scan station ``k`` over the trees ``ids`` and the terrain within its range into
        ``out``; returns the triangles it loaded. ``release`` is called once the
        station's scene holds its own copy of the trees (the plot's built trees it no
        longer needs are dropped before the cast: one copy of the geometry casts).
        ``columns``: only that azimuth sector's pulses (:mod:`treesim.plot.sectors`);
        ``station_ids``: every tree of the station (default ``ids``), whose bounds with
        the terrain's are the scene's extent."""
        from ..steps import scale_progress, scan_scene

        spec, n, say = self.params.scanner, self.n, self.say
        parts: list[MeshPart] = []
        for tid in ids:
            if self.cache_dir is None:
                parts += plot.tree_parts(tid)
            else:
                parts += load_tree_parts(self.cache_dir, tid)
        patch = _terrain_within(ground, st.position, spec.max_range_m) if ground else None
        if patch is not None:
            parts.append(patch)
        loaded_tri = sum(plot.tree_triangles(t) for t in ids) + (
            len(patch.faces) if patch is not None else 0
        )
        say(k / n, f"station {k + 1}/{n}: {len(ids)} trees")
        if not parts:
            if release is not None:
                release()
            out.stats.append(_empty_stats(k, st, spec))
            out.lods.append({"mode": self.params.lod, "note": "nothing within range or view"})
            return loaded_tri
        # a station that sees only the terrain still labels its points (tree_id 0); a
        # sector's scene reports the whole station's bounds (the same points, bit for bit)
        extent = station_extent(plot, ids if station_ids is None else station_ids, patch)
        scene = Scene(parts, keep_tree_ids=True, extent=extent)
        del parts
        scene.parts = []  # the scan reads the merged arrays only: the parts may go
        if release is not None:
            release()
        res = scan_scene(
            scene,
            [st],
            self.params,
            threads=self.threads,
            window=self.window,
            sink=self.sink,
            progress=scale_progress(
                (lambda f, m, k=k: say(f, f"station {k + 1}/{n}")), k / n, (k + 1) / n
            ),
            frame=self.frame,
            station_offset=k,
            check_inside=self.check_inside,
            columns=columns,
        )
        del scene
        out.stats.append(res.station_stats[0])
        out.lods.append(res.lod)
        out.warnings += res.warnings
        out.models = res.models
        out.written += res.points_written
        if self.sink is None and len(res.cloud):
            out.pts.append(res.cloud.points)
            out.flds.append(res.cloud.fields)
        return loaded_tri


def _plot_cloud(out: _Gathered, placed: list[Station]) -> Cloud:
    """The stations' points in one cloud (empty, with the plot's fields, when none)."""
    pts, flds = out.pts, out.flds
    if pts:
        return Cloud(
            np.concatenate(pts),
            {name: np.concatenate([f[name] for f in flds]) for name in flds[0]},
            _metadata(placed),
        )
    return Cloud(
        np.empty((0, 3)),
        {k: np.empty(0, dtype=v) for k, v in plot_fields().items()},
        _metadata(placed),
    )


def station_executor(
    executor: str,
    *,
    workers: int | None,
    scheduler: str | None,
    cache_dir: str | None,
    threads: int | None = None,
    n_tasks: int | None = None,
    command: str = "treesim plot scan",
) -> Any:
    """Where a plot scan's stations run (:func:`treesim.executors.plan_executor`),
    checked: a running Dask scheduler's workers need ``cache_dir``, a folder they share
    (``command``'s ``--cache-dir`` in the message).

    Examples
    --------
    >>> station_executor("inline", workers=None, scheduler=None, cache_dir=None).kind.value
    'inline'
    """
    from ..executors import plan_executor

    plan = plan_executor(
        executor, workers=workers, threads=threads, scheduler=scheduler, n_tasks=n_tasks
    )
    if plan.scheduler and cache_dir is None:
        raise InvalidParameterError(
            "a running Dask scheduler's workers read the plot's trees from a folder they "
            f"share: give cache_dir ({command} --cache-dir), a folder every worker "
            "reads and writes at the same path"
        )
    return plan


def scan_plot(
    plot: Plot,
    stations: Sequence[Any],
    params: ScanParams | None = None,
    *,
    sink: Callable[[np.ndarray, dict[str, np.ndarray]], None] | None = None,
    progress: Progress | None = None,
    threads: int = 0,
    window: bool = True,
    terrain: bool = True,
    margin_m: float = 2.0,
    cache_triangles: int = CACHE_TRIANGLES,
    check_inside: bool = True,
    executor: str = "inline",
    workers: int | None = None,
    scheduler: str | None = None,
    cache_dir: str | Path | None = None,
    sectors: int = 1,
) -> PlotScanResult:
    """Scan a plot from ``stations``, one station at a time, loading only what it can
    record (see the module notes).

    Parameters
    ----------
    plot : Plot
    stations : sequence of Station or (x, y, z)
        The ``station`` field numbers them in this order.
    params : ScanParams
        The scanner, ray budget (per station), chunking and level of detail.
    sink : callable(points, fields), optional
        Receives each chunk (e.g. a cloud writer's ``write``); the result's cloud is
        then empty.
    progress : callable(fraction, message), optional
    threads : int
        Open3D threads (0: all cores; with an executor, its threads per task).
    window : bool
        Cast only towards the scene (False: the full field of view).
    terrain : bool
        Include the terrain (over the plot's square plus ``margin_m``).
    margin_m : float
        How far the terrain reaches beyond the plot's square.
    cache_triangles : int
        Built trees kept between stations, in triangles (inline only); a tree dropped
        and needed again is rebuilt. A station's trees are dropped once its scene holds
        them, before the cast.
    check_inside : bool
        Refuse stations inside geometry (see :func:`treesim.scan.scan`).
    executor : {"inline", "local", "dask"}
        Where the stations run (:mod:`treesim.executors`, as ``batch`` and ``sweep``):
        ``inline`` one after another here; ``local`` or ``dask``: each station is a task
        that builds only the trees it can record and returns its points, merged here in
        station order (the same points, bit for bit, as inline; the trees' bounds are
        found by tasks too). A sink then receives one chunk per station (per sector with
        ``sectors``; larger ones in pieces).
    workers : int, optional
        Worker processes of ``local`` and of a local dask cluster (default one per core,
        at most one per station).
    scheduler : str, optional
        A running dask scheduler's address (``dask``; the plot's files at the same paths
        on every worker).
    cache_dir : str or Path, optional
        With ``local`` or ``dask``: the folder the trees are built into once each (compact
        files, :func:`save_tree_parts`) and read from by every station that records
        them; default a temporary folder, removed after. A remote cluster needs a folder
        every worker reads at the same path.
    sectors : int
        Scan each station in this many azimuth sectors (equal shares of its columns, in
        turn inline, each a task of its own with an executor), each loading only the
        trees its columns can record (:mod:`treesim.plot.sectors`): a fraction of a
        station's geometry held at once, and the station's points, pulse for pulse,
        except at rays through a shared edge (microns). The same ``sectors`` give the
        same points, bit for bit, on every executor. One ray a pulse only (a beam's
        pulses sample their neighbours).

    Returns
    -------
    PlotScanResult

    Examples
    --------
    >>> import treesim as ts
    >>> plot = ts.read_plot("plot/plot.toml")  # doctest: +SKIP
    >>> result = ts.scan_plot(plot, [(0.0, 0.0, 1.5), (7.0, -4.0, 1.6)])  # doctest: +SKIP
    >>> ts.write_cloud("plot_scan.laz", result.cloud)  # doctest: +SKIP
    >>> on_two = ts.scan_plot(plot, stations, executor="dask", workers=2)  # doctest: +SKIP
    """

    params = params or ScanParams()
    placed = [_as_station(s) for s in stations]
    if not placed:
        raise InvalidParameterError("give at least one station")
    if isinstance(cache_triangles, bool) or int(cache_triangles) < 0:
        raise InvalidParameterError(f"cache_triangles must be >= 0, got {cache_triangles!r}")
    sectors = check_sectors(sectors, params.scanner)
    plan = station_executor(
        executor,
        workers=workers,
        scheduler=scheduler,
        cache_dir=cache_dir,
        threads=int(threads) or None,
        n_tasks=len(placed),
    )
    t_all = time.perf_counter()
    say = progress or (lambda f, m: None)
    job = _PlotJob(plot, placed, params, window, terrain, margin_m, check_inside, sectors)
    if plan.kind.value == "inline":
        out = _scan_inline(job, say, int(threads), sink, int(cache_triangles))
    else:
        out = _scan_tasks(job, say, plan, sink, cache_dir)
    plot.release()
    cloud = _plot_cloud(out, placed)
    say(1.0, "done")
    return PlotScanResult(
        cloud=cloud,
        stations=placed,
        station_stats=out.stats,
        loading=out.loading,
        lod=out.lods,
        warnings=out.warnings,
        points_written=out.written,
        total_s=time.perf_counter() - t_all,
        spec=params.scanner,
        models=out.models,
        trees_build_s=out.trees_build_s,
    )


@dataclass
class _PlotJob:
    """A plot scan's settings, shared by the inline loop and the station tasks."""

    plot: Plot
    placed: list[Station]
    params: ScanParams
    window: bool
    terrain: bool
    margin_m: float
    check_inside: bool
    sectors: int = 1

    def ground(self, plot: Plot) -> MeshPart | None:
        return plot.terrain_part(self.margin_m) if self.terrain else None

    def total_triangles(self, ground: MeshPart | None) -> int:
        plot = self.plot
        return sum(plot.tree_triangles(t) for t in plot.tree_ids) + (
            len(ground.faces) if ground is not None else 0
        )

    def units(
        self, plot: Plot, needs: dict[int, list[int]]
    ) -> list[tuple[int, tuple[int, int] | None, list[int]]]:
        """Each station's sectors, in order: ``(station, columns, trees)``
        (:func:`~treesim.plot.sectors.station_sectors`; one a station, its columns None,
        without sectors)."""
        spec = self.params.scanner
        return [
            (k, cols, ids)
            for k, st in enumerate(self.placed)
            for cols, ids in station_sectors(plot, st, spec, needs.get(k, []), self.sectors)
        ]

    def loading(
        self, k: int, ids: list[int], why: list[dict[str, list[int]]], built: list[int]
    ) -> dict[str, Any]:
        """Station ``k``'s loading figures (its triangles and time added by the caller)."""
        return {
            "trees_loaded": list(ids),
            "trees_beyond_range": why[k]["beyond_range"],
            "trees_outside_fov": why[k]["outside_fov"],
            "trees_built": built,
        }


def _scan_inline(
    job: _PlotJob, say: Progress, threads: int, sink: Any, cache_triangles: int
) -> _Gathered:
    """The stations (and their sectors) one after another in this process, trees kept
    between them within ``cache_triangles``."""
    plot, placed, spec = job.plot, job.placed, job.params.scanner
    frame = plot.frame()
    n = len(placed)
    say(0.0, "placing the trees")
    needs, why = _station_needs(plot, placed, spec, frame.origin_array, cache_triangles)
    ground = job.ground(plot)
    total_tri = job.total_triangles(ground)
    units = job.units(plot, needs)
    last_use = {tid: u for u, (_, _, ids) in enumerate(units) for tid in ids}
    scan_station = _StationScan(
        job.params, frame, n, say, threads, job.window, sink, job.check_inside
    )
    out = _Gathered()
    _advise(job, units, ground, 1, out, say)
    for k, st in enumerate(placed):
        t_st = time.perf_counter()
        before = _rss_bytes()
        mine = _of_station(units, k)
        built: list[int] = []
        loaded = []
        w0 = len(out.warnings)
        for u in mine:
            _, columns, ids = units[u]
            built += [t for t in ids if t not in plot.loaded]

            def release(u: int = u) -> None:
                # drop what no later sector needs, then keep the rest within the budget
                plot.release([t for t in plot.loaded if last_use.get(t, -1) <= u])
                upcoming = set(units[u + 1][2]) if u + 1 < len(units) else set()
                _trim(plot, upcoming, cache_triangles)

            loaded.append(
                scan_station(
                    plot, k, st, ids, ground, out, release,
                    columns=columns, station_ids=needs.get(k, []),
                )
            )  # fmt: skip
            release()
        out.warnings[w0:] = _once(out.warnings[w0:])  # a station's sectors say a thing once
        _merge_sectors(out, mine, units)
        out.loading.append(
            {
                **job.loading(k, needs.get(k, []), why, built),
                **_sector_loading(loaded, total_tri),
                "time_s": time.perf_counter() - t_st,
                **_memory(before),
            }
        )
    return out


def _advise(
    job: _PlotJob,
    units: list[tuple[int, Any, list[int]]],
    ground: MeshPart | None,
    concurrent: int,
    out: _Gathered,
    say: Progress,
) -> None:
    """Warn (in ``out`` and at once through ``say``) when the largest scene of ``units``,
    ``concurrent`` at once, would not fit the memory available
    (:func:`~treesim.plot.sectors.memory_advice`)."""
    from .._system import available_memory_bytes

    g = len(ground.faces) if ground is not None else 0
    tri = [sum(job.plot.tree_triangles(t) for t in ids) + g for _, _, ids in units]
    advice = memory_advice(tri, concurrent, job.sectors, available_memory_bytes())
    if advice is not None:
        out.warnings.append(advice)
        say(0.0, f"warning: {advice}")


def _of_station(units: list[tuple[int, Any, list[int]]], k: int) -> list[int]:
    """The indices of station ``k``'s units (its sectors, in order)."""
    return [u for u, unit in enumerate(units) if unit[0] == k]


def _once(said: list[str]) -> list[str]:
    """``said`` without repeats, in order."""
    return list(dict.fromkeys(said))


def _merge_sectors(
    out: _Gathered, mine: list[int], units: list[tuple[int, Any, list[int]]]
) -> None:
    """The last ``len(mine)`` stats and lods of ``out`` (one station's sectors) merged
    into the station's."""
    m = len(mine)
    if m > 1:
        out.stats[-m:] = [merged_stats(out.stats[-m:])]
        out.lods[-m:] = [merged_lod(out.lods[-m:], [units[u][1] for u in mine])]


def _sector_loading(loaded: list[int], total_tri: int) -> dict[str, Any]:
    """A station's triangle figures: ``triangles_loaded`` (the most held at once: its
    largest sector) and, with sectors, each sector's."""
    row: dict[str, Any] = {
        "triangles_loaded": int(max(loaded)),
        "triangles_total": int(total_tri),
    }
    if len(loaded) > 1:
        row["sector_triangles_loaded"] = [int(x) for x in loaded]
    return row


def _scan_tasks(
    job: _PlotJob, say: Progress, plan: Any, sink: Any, cache_dir: str | Path | None
) -> _Gathered:
    """Each station a task on ``plan``'s executor; results merged in station order. The
    trees are built once each, by tasks, into a folder of compact files (``cache_dir``,
    or a temporary folder removed after) that the station tasks read them from."""
    import shutil
    import tempfile

    from ..executors import open_executor

    made = None
    if cache_dir is None:
        made = cache_dir = tempfile.mkdtemp(prefix="treesim-plot-trees-")
    try:
        with open_executor(plan) as ex:
            return _run_station_tasks(job, say, plan, ex, sink, str(cache_dir))
    finally:
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)


def _run_station_tasks(
    job: _PlotJob, say: Progress, plan: Any, ex: Any, sink: Any, cache_dir: str
) -> _Gathered:
    """:func:`_scan_tasks` on the open executor ``ex``."""
    from ..executors import slots

    plot, placed, spec = job.plot, job.placed, job.params.scanner
    frame = plot.frame()
    n = len(placed)
    out = _Gathered()
    say(0.0, f"building {len(plot.trees)} trees on {plan.describe()}")
    ids = plot.tree_ids
    size = max(1, -(-len(ids) // (2 * slots(plan, ex))))
    chunks = [ids[a : a + size] for a in range(0, len(ids), size)]
    blank = plot.blank()
    t0 = time.perf_counter()
    for fut in [ex.submit(_tree_facts_task, blank, c, cache_dir) for c in chunks]:
        for tid, facts in fut.result().items():
            plot.set_tree_facts(tid, facts)
    out.trees_build_s = time.perf_counter() - t0
    needs, why = _station_needs(plot, placed, spec, frame.origin_array, 0)
    total_tri = job.total_triangles(job.ground(plot))
    task = _StationTask(job.params, frame, n, plan.threads, job.window, job.check_inside, cache_dir)
    sent = plot.blank()  # with the trees' facts: no task builds a tree
    for tid in ids:
        sent.set_tree_facts(tid, plot.tree_facts(tid))
    task_job = _PlotJob(sent, [], job.params, *_job_tail(job))
    units = job.units(plot, needs)
    _advise(job, units, job.ground(plot), min(slots(plan, ex), len(units)), out, say)
    futures = [
        ex.submit(task, task_job, k, placed[k], ids_u, columns, needs.get(k, []), u)
        for u, (k, columns, ids_u) in enumerate(units)
    ]
    say(0.0, f"{n} stations ({len(units)} tasks) on {plan.describe()}")
    for k in range(n):
        mine = _of_station(units, k)
        rs, said = [], []
        for u in mine:
            r = futures[u].result()
            out.stats.append(r["stats"])
            out.lods.append(r["lod"])
            said += r["warnings"]
            out.models = r["models"] or out.models
            _take_points(r, sink, out)
            rs.append({key: r[key] for key in ("loaded_tri", "time_s", "memory")})
            futures[u] = None  # type: ignore[call-overload]  # its points may go
        out.warnings += _once(said)  # a station's sectors say a thing once
        _merge_sectors(out, mine, units)
        ids_k = needs.get(k, [])
        # the memory of the task that rose most over its start (with sectors)
        top = max(rs, key=lambda r: _rise(r["memory"]))
        out.loading.append(
            {
                **job.loading(k, ids_k, why, []),
                **_sector_loading([r["loaded_tri"] for r in rs], total_tri),
                "time_s": sum(r["time_s"] for r in rs),
                **top["memory"],
            }
        )
        say((k + 1) / n, f"station {k + 1}/{n}: {len(ids_k)} trees")
    return out


def _rise(memory: dict[str, int | None]) -> int:
    """A task's peak memory over its start (0 where not known)."""
    a, b = memory.get("rss_before_bytes"), memory.get("rss_peak_bytes")
    return b - a if a is not None and b is not None else 0


def _job_tail(job: _PlotJob) -> tuple[bool, bool, float, bool, int]:
    return job.window, job.terrain, job.margin_m, job.check_inside, job.sectors


def _tree_facts_task(
    plot: Plot, ids: list[int], cache_dir: str | None = None
) -> dict[int, dict[str, Any]]:
    """Build each tree of ``ids`` once and return what the parent needs to place it
    (:meth:`Plot.tree_facts`), saving its mesh into ``cache_dir`` when given
    (:func:`save_tree_parts`), then dropping it."""
    out = {}
    for tid in ids:
        if cache_dir is not None:
            save_tree_parts(cache_dir, tid, plot.tree_parts(tid))
        out[tid] = plot.tree_facts(tid)
        plot.release([tid])
    return out


def save_tree_parts(folder: str | Path, tree_id: int, parts: Sequence[MeshPart]) -> Path:
    """Save a built tree's parts into ``folder`` compactly (float64 vertices as they
    are, int32 triangles, one ``.npy`` each, and their labels and names) for
    :func:`load_tree_parts`: a station reads the tree there instead of building it again.

    Examples
    --------
    >>> import treesim as ts
    >>> from treesim.plot.scan import load_tree_parts, save_tree_parts
    >>> plot = ts.Plot([ts.PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species="sapling")])
    >>> save_tree_parts("cache", 1, plot.tree_parts(1))  # doctest: +SKIP
    >>> [p.label for p in load_tree_parts("cache", 1)]  # doctest: +SKIP
    ['wood']
    """
    import json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    meta = []
    for j, part in enumerate(parts):
        faces = np.asarray(part.faces)
        small = faces.size == 0 or int(faces.max()) < 2**31 - 1
        np.save(folder / f"tree-{tree_id}-{j}-v.npy", np.asarray(part.vertices, np.float64))
        np.save(folder / f"tree-{tree_id}-{j}-f.npy", faces.astype(np.int32 if small else np.int64))
        meta.append({"label": part.label, "name": part.name, "tree_id": int(part.tree_id)})
    path = folder / f"tree-{tree_id}.json"
    path.write_text(json.dumps(meta), encoding="utf-8")
    return path


def load_tree_parts(folder: str | Path, tree_id: int) -> list[MeshPart]:
    """A tree's parts as :func:`save_tree_parts` saved them (memory-mapped: a scene built
    from them copies each once, and the files' pages go with the parts)."""
    import json

    folder = Path(folder)
    meta = json.loads((folder / f"tree-{tree_id}.json").read_text(encoding="utf-8"))
    return [
        MeshPart(
            np.load(folder / f"tree-{tree_id}-{j}-v.npy", mmap_mode="r"),
            np.load(folder / f"tree-{tree_id}-{j}-f.npy", mmap_mode="r"),
            m["label"],
            m["name"],
            m["tree_id"],
        )
        for j, m in enumerate(meta)
    ]


@dataclass
class _StationTask:
    """One station's scan in a task: builds the trees ``ids`` (and the terrain), scans,
    returns the points, the station's figures and the task's memory."""

    params: ScanParams
    frame: Any
    n: int
    threads: int
    window: bool
    check_inside: bool
    cache_dir: str | None = None

    def __call__(
        self,
        job: _PlotJob,
        k: int,
        st: Station,
        ids: list[int],
        columns: tuple[int, int] | None = None,
        station_ids: list[int] | None = None,
        unit: int | None = None,
    ) -> dict[str, Any]:
        """Station ``k``'s scan over the trees ``ids`` (its sector ``columns`` of
        ``station_ids``, the task ``unit``, when given)."""
        from ..executors import task_threads

        t0 = time.perf_counter()
        before = _rss_bytes(reset=True)
        plot = job.plot
        scan_station = _StationScan(
            self.params,
            self.frame,
            self.n,
            lambda f, m: None,
            task_threads(self.threads),
            self.window,
            None,
            self.check_inside,
            self.cache_dir,
        )
        out = _Gathered()
        # the points go to files as they are cast (a station's cloud is never held here,
        # nor sent back through the executor)
        name = f"{k}" if unit is None else f"{k}-{unit}"
        files = _PointFiles(self.cache_dir, name) if self.cache_dir is not None else None
        scan_station.sink = files
        try:
            loaded_tri = scan_station(
                plot, k, st, ids, job.ground(plot), out, plot.release,
                columns=columns, station_ids=station_ids,
            )  # fmt: skip
        finally:
            saved = files.close() if files is not None else None
        plot.release()
        return {
            "stats": out.stats[0],
            "lod": out.lods[0],
            "warnings": out.warnings,
            "models": out.models,
            "points": out.pts[0] if out.pts else None,
            "fields": out.flds[0] if out.flds else None,
            "files": saved,
            "loaded_tri": loaded_tri,
            "time_s": time.perf_counter() - t0,
            "memory": _memory(before),
        }


class _PointFiles:
    """A station task's sink: each array (``xyz`` and every field) appended to a raw file
    of its own in ``folder`` as the chunks come (:func:`_take_points` reads them)."""

    def __init__(self, folder: str, name: str) -> None:
        self.prefix = Path(folder) / f"station-{name}"
        self.files: dict[str, Any] = {}
        self.kinds: dict[str, tuple[str, str, tuple[int, ...]]] = {}
        self.n = 0

    def __call__(self, points: np.ndarray, fields: dict[str, np.ndarray]) -> None:
        for name, arr in (("xyz", points), *fields.items()):
            fh = self.files.get(name)
            if fh is None:
                path = f"{self.prefix}-{len(self.files)}.bin"
                fh = self.files[name] = open(path, "wb")  # noqa: SIM115 - closed in close()
                self.kinds[name] = (path, arr.dtype.str, tuple(arr.shape[1:]))
            np.ascontiguousarray(arr).tofile(fh)
        self.n += len(points)

    def close(self) -> dict[str, Any] | None:
        """Close the files; what :func:`_take_points` reads (None: no point)."""
        for fh in self.files.values():
            fh.close()
        return {"n": self.n, "arrays": self.kinds} if self.n else None


#: Points handed to a sink at once from a station task's files.
SINK_CHUNK = 1 << 21


def _take_points(r: dict[str, Any], sink: Any, out: _Gathered) -> None:
    """A station task's points (``r``: its result) into the sink, a chunk at a time, or
    into ``out``; the task's files are removed once read."""
    saved = r.get("files")
    if saved is None:
        if r["points"] is not None:  # a task without files (none so far): the arrays
            if sink is not None:
                sink(r["points"], r["fields"])
                out.written += len(r["points"])
            else:
                out.pts.append(r["points"])
                out.flds.append(r["fields"])
        return
    n = int(saved["n"])
    maps = {
        name: np.memmap(path, dtype=np.dtype(kind), mode="r", shape=(n, *tail))
        for name, (path, kind, tail) in saved["arrays"].items()
    }
    try:
        if sink is not None:
            for a in range(0, n, SINK_CHUNK):
                chunk = {name: np.array(m[a : a + SINK_CHUNK]) for name, m in maps.items()}
                sink(chunk.pop("xyz"), chunk)
            out.written += n
        else:
            arrays = {name: np.array(m) for name, m in maps.items()}
            out.pts.append(arrays.pop("xyz"))
            out.flds.append(arrays)
    finally:
        del maps
        for path, _, _ in saved["arrays"].values():
            Path(path).unlink(missing_ok=True)


def _rss_bytes(reset: bool = False) -> int | None:
    """This process's resident memory now (Linux; None elsewhere). ``reset`` (a task's
    worker process only, never the caller's: it lowers the process's own ``ru_maxrss``)
    resets its peak (``/proc/self/clear_refs``), so that :func:`_memory` reads the
    station's own peak."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            now = next(int(x.split()[1]) * 1024 for x in fh if x.startswith("VmRSS:"))
        if reset:
            with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
                fh.write("5")
    except (OSError, StopIteration, ValueError):
        return None
    return now


def _memory(before: int | None) -> dict[str, int | None]:
    """``rss_before_bytes`` (at the station's start) and ``rss_peak_bytes`` (the
    process's peak: since the station's start in a task, over the process's life
    inline): what a station cost in memory (Linux; None elsewhere)."""
    peak = None
    if before is not None:
        try:
            with open("/proc/self/status", encoding="ascii") as fh:
                peak = next(int(x.split()[1]) * 1024 for x in fh if x.startswith("VmHWM:"))
        except (OSError, StopIteration, ValueError):
            peak = None
    return {"rss_before_bytes": before, "rss_peak_bytes": peak}


def _trim(plot: Plot, wanted: set[int], budget: int, keep_last: int | None = None) -> None:
    """Drop built trees, oldest first, until those held fit ``budget`` triangles; the
    ``wanted`` (and ``keep_last``) are dropped last."""
    held = plot.loaded
    total = sum(plot.tree_triangles(t) for t in held)
    order = [t for t in held if t not in wanted and t != keep_last] + [
        t for t in held if t in wanted and t != keep_last
    ]
    for tid in order:
        if total <= budget:
            break
        plot.release([tid])
        total -= plot.tree_triangles(tid)


def _metadata(stations: list[Station]) -> dict[str, Any]:
    from ..scan import scan_metadata

    meta = scan_metadata(stations)
    meta["source"] = "treesim plot scan"
    return meta


def _empty_stats(k: int, st: Station, spec: Any) -> Any:
    """A station that records nothing: no pulse cast, but the field scan still takes its
    time (:func:`treesim.scan.timing.station_duration_s`)."""
    from ..scan.result import StationStats

    return StationStats(
        index=k,
        position_m=st.position_m,
        pulses_full_fov=spec.n_azimuth * spec.n_elevation,
        pulses_window=0,
        pulses_cast=0,
        rays_cast=0,
        points=0,
        azimuth_window_deg=None,
        elevation_window_deg=(0.0, 0.0),
        time_s=0.0,
        scan_duration_s=station_duration_s(spec),
    )


def plot_fields() -> dict[str, np.dtype]:
    """The per-point fields of a plot's scan (what a streaming writer declares): a
    scan's, with ``tree_id``."""
    from ..scan.result import SCAN_FIELDS, TREE_ID_FIELD

    return {**SCAN_FIELDS, **TREE_ID_FIELD}


def tree_figures(
    plot: Plot,
    cloud: Cloud,
    *,
    params: CompareParams | None = None,
    progress: Progress | None = None,
) -> list[dict[str, Any]]:
    """Each tree's figures in the plot's scan: its points (``tree_id``) against its own
    mesh, both ways (:func:`treesim.compare.compare`).

    Returns one dict per tree (the plot's order): ``tree_id``, ``species``, ``x_m``,
    ``y_m``, ``points``, ``coverage`` (share of its visible surface within τ of a
    point), ``tolerance_m`` (τ: ``params.tolerance_m``, or 3 × the tree's own point
    spacing), ``accuracy_mean_m``/``accuracy_p95_m`` (points to mesh),
    ``completeness_mean_m``/``completeness_p95_m`` (mesh samples to points), the truth's
    ``dbh_m`` and ``height_m``, and ``note`` when it has too few points to measure
    (coverage 0 then). Each tree is built for it and dropped after, unless held before.

    Parameters
    ----------
    plot : Plot
        The plot that was scanned.
    cloud : Cloud
        Its scan, with the ``tree_id`` field (:func:`scan_plot`).
    params : CompareParams, optional
        The comparison's settings (τ, samples, hidden surface).
    progress : callable(fraction, message), optional

    Examples
    --------
    >>> import treesim as ts
    >>> result = ts.scan_plot(plot, stations)  # doctest: +SKIP
    >>> rows = ts.tree_figures(plot, result.cloud)  # doctest: +SKIP
    >>> [(row["tree_id"], row["coverage"]) for row in rows]  # doctest: +SKIP
    """
    from ..compare import compare
    from ..params import MIN_CLOUD_POINTS

    params = params or CompareParams()
    say = progress or (lambda f, m: None)
    tid_field = cloud.fields.get("tree_id")
    if tid_field is None:
        raise InvalidParameterError("the cloud has no tree_id field; scan the plot first")
    order = np.argsort(tid_field, kind="stable")
    sorted_ids = tid_field[order]
    rows = []
    ids = plot.tree_ids
    for i, tid in enumerate(ids):
        say(i / max(1, len(ids)), f"tree {tid}")
        a, b = np.searchsorted(sorted_ids, [tid, tid + 1])
        sel = order[a:b]
        truth = plot.truth(tid)
        row: dict[str, Any] = {
            "tree_id": tid,
            "species": plot.tree(tid).species,
            "source": plot.tree(tid).source,
            "x_m": float(plot.tree(tid).x_m),
            "y_m": float(plot.tree(tid).y_m),
            "dbh_m": truth["dbh_m"],
            "height_m": truth["height_m"],
            "triangles": truth["triangles"],
            "points": int(len(sel)),
            "coverage": 0.0,
            "tolerance_m": params.tolerance_m,
            "accuracy_mean_m": None,
            "accuracy_p95_m": None,
            "completeness_mean_m": None,
            "completeness_p95_m": None,
            "note": "",
        }
        if len(sel) < MIN_CLOUD_POINTS:
            row["note"] = f"{len(sel)} points: too few to measure (< {MIN_CLOUD_POINTS})"
        else:
            was = tid in plot.loaded
            sub = Cloud(
                cloud.points[sel],
                {k: v[sel] for k, v in cloud.fields.items()},
                dict(cloud.metadata),
            )
            cmp = compare(sub, Scene(plot.tree_parts(tid)), params=params)
            row.update(
                coverage=cmp.coverage,
                tolerance_m=cmp.tolerance_m,
                accuracy_mean_m=cmp.accuracy.mean_m,
                accuracy_p95_m=cmp.accuracy.p95_m,
                completeness_mean_m=cmp.completeness.mean_m,
                completeness_p95_m=cmp.completeness.p95_m,
            )
            if not was:
                plot.release([tid])
        rows.append(row)
    say(1.0, "done")
    return rows


#: What :func:`plot_scan_files` writes into its folder (the cloud's suffix may vary).
PLOT_SCAN_FILES = {"cloud": "plot_scan.laz", "json": "plot_scan.json", "trees": "tree_figures.csv"}
#: The per-point fields the per-tree figures keep from a plot's scan.
_FIGURE_FIELDS = ("tree_id", "station", "label")
#: Columns of ``tree_figures.csv``.
FIGURE_COLUMNS = (
    "tree_id",
    "species",
    "source",
    "x_m",
    "y_m",
    "dbh_m",
    "height_m",
    "triangles",
    "points",
    "coverage",
    "tolerance_m",
    "accuracy_mean_m",
    "accuracy_p95_m",
    "completeness_mean_m",
    "completeness_p95_m",
    "note",
)


def plot_stations(
    plot: Plot,
    *,
    positions: Sequence[Sequence[float]] | None = None,
    n: int = 3,
    distance_m: float | None = None,
    height_m: float = 1.5,
    start_angle_deg: float = 90.0,
) -> list[Station]:
    """Stations for a plot: ``positions`` as given (x, y, z in metres; (x, y) stands
    ``height_m`` above the terrain), or ``n`` on a ring around the plot centre at
    ``distance_m`` (default half the plot's radius), ``height_m`` above the terrain."""
    out = []
    if positions:
        for p in positions:
            q = [float(c) for c in p]
            if len(q) == 2:
                q.append(float(plot.terrain.height_at(q[0], q[1])) + height_m)
            out.append(_as_station(q))
        return out
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise InvalidParameterError(f"the number of stations must be >= 1, got {n!r}")
    d = 0.5 * plot.radius_m if distance_m is None else float(distance_m)
    if not (math.isfinite(d) and d >= 0):
        raise InvalidParameterError(f"distance_m must be >= 0, got {distance_m!r}")
    cx, cy = plot.centre_xy
    for k in range(int(n)):
        a = math.radians(start_angle_deg + 360.0 * k / n)
        x, y = cx + d * math.cos(a), cy + d * math.sin(a)
        out.append(Station(position_m=(x, y, float(plot.terrain.height_at(x, y)) + height_m)))
    return out


def read_stations_csv(path: str | Path, plot: Plot, height_m: float = 1.5) -> list[Station]:
    """Stations from a CSV with ``x_m``, ``y_m`` and either ``z_m`` (absolute) or
    ``height_m`` (above the terrain; default ``height_m``) columns, in file order (as
    ``treesim plan`` writes ``stations.csv``)."""
    import csv

    from ..errors import InputFormatError

    p = Path(path)
    try:
        rows = list(csv.DictReader(p.read_text(encoding="utf-8-sig").splitlines()))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{p}: cannot read the stations CSV ({exc})") from exc
    if not rows or not {"x_m", "y_m"} <= set(rows[0]):
        raise InputFormatError(
            f"{p}: a stations CSV needs x_m and y_m columns (and z_m, or height_m above "
            "the terrain) and at least one row"
        )
    out = []
    for i, r in enumerate(rows, start=2):
        try:
            x, y = float(r["x_m"]), float(r["y_m"])
            if r.get("z_m") not in (None, ""):
                out.append(_as_station((x, y, float(r["z_m"]))))
            else:
                h = float(r["height_m"]) if r.get("height_m") not in (None, "") else height_m
                out.append(_as_station((x, y, float(plot.terrain.height_at(x, y)) + h)))
        except (TypeError, ValueError) as exc:
            raise InputFormatError(f"{p}, line {i}: not a number ({exc})") from exc
    return out


def read_stations(path: str | Path, plot: Plot, height_m: float = 1.5) -> list[Station]:
    """The field's stations from ``path``: an E57 file's scan poses (where each scanner
    stood, as registered) or a stations CSV (:func:`read_stations_csv`).

    Raises
    ------
    InputFormatError
        For another kind of file, an E57 scan without a pose, or stations far from the
        plot (more than 10 radii and 100 m from its centre: another coordinate frame).

    Examples
    --------
    >>> import treesim as ts
    >>> from treesim.plot.scan import read_stations
    >>> plot = ts.read_plot("twin/plot.toml")  # doctest: +SKIP
    >>> stations = read_stations("field.e57", plot)  # doctest: +SKIP
    """
    from ..errors import InputFormatError

    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".e57":
        from ..io.e57 import read_e57_stations

        stations = [_as_station(tuple(xyz)) for xyz in read_e57_stations(p)]
    elif suffix in (".csv", ".txt"):
        stations = read_stations_csv(p, plot, height_m=height_m)
    else:
        raise InputFormatError(
            f"{p}: stations come from an E57 file's scan poses or a stations CSV (x_m, y_m "
            f"and z_m or height_m), not a {suffix or 'suffix-less'} file"
        )
    cx, cy = plot.centre_xy
    limit = 10.0 * float(plot.radius_m) + 100.0
    for i, st in enumerate(stations):
        d = math.hypot(st.position_m[0] - cx, st.position_m[1] - cy)
        if d > limit:
            raise InputFormatError(
                f"{p}: station {i} stands {d:,.0f} m from the plot's centre "
                f"({cx:.2f}, {cy:.2f}); are the stations and the plot in the same "
                "coordinate frame?"
            )
    return stations


def write_figures_csv(path: str | Path, rows: list[dict[str, Any]]) -> Path:
    """Per-tree figures as a CSV (atomically)."""
    import csv
    import io

    from ..atomic import write_text

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(FIGURE_COLUMNS)
    for r in rows:
        w.writerow(
            [
                "" if r.get(c) is None else (repr(r[c]) if isinstance(r[c], float) else r[c])
                for c in FIGURE_COLUMNS
            ]
        )
    return write_text(Path(path), buf.getvalue())


def plot_scan_files(
    plot: Plot,
    outdir: str | Path,
    params: ScanParams | None = None,
    *,
    stations: Sequence[Any],
    compare: CompareParams | None = None,
    cloud_name: str = PLOT_SCAN_FILES["cloud"],
    figures: bool = True,
    threads: int = 0,
    progress: Progress | None = None,
    cache_triangles: int = CACHE_TRIANGLES,
    executor: str = "inline",
    workers: int | None = None,
    scheduler: str | None = None,
    cache_dir: str | Path | None = None,
    sectors: int = 1,
) -> Any:
    """Scan a plot into ``outdir``: the cloud (``plot_scan.laz``, written while it is
    cast), ``plot_scan.json`` (the scan, each station's loading, each tree's truth and
    figures) and ``tree_figures.csv`` (one row per tree). Interrupted or failed, it
    leaves nothing behind (no cloud, no JSON, no CSV, no folder it made).

    ``executor``, ``workers``, ``scheduler`` and ``cache_dir`` say where the stations
    run (see :func:`scan_plot`: each station a task on local processes or a Dask
    cluster, the same cloud as inline), ``sectors`` in how many azimuth sectors; the
    per-tree figures are measured here.

    Returns a :class:`treesim.steps.StepResult` (``result``: the
    :class:`PlotScanResult`; ``details["trees"]``: the per-tree rows).
    """
    import open3d  # noqa: F401  (imported before any file exists; see steps.scan_files)

    from ..io import open_cloud_writer
    from ..jsonio import json_ready, write_json
    from ..steps import SCAN_OUTPUT_SUFFIXES, StepResult, _make_folders, _remove_folders
    from ..steps import scale_progress as scaled

    params = params or ScanParams()
    out = Path(outdir)
    cloud_path = out / cloud_name
    if cloud_path.suffix.lower() not in SCAN_OUTPUT_SUFFIXES:
        raise InvalidParameterError(
            f"{cloud_name}: write the cloud as {', '.join(SCAN_OUTPUT_SUFFIXES)} (by suffix)"
        )
    placed = [_as_station(s) for s in stations]
    say = progress or (lambda f, m: None)
    made = _make_folders(out)
    written: list[Path] = []
    try:
        t0 = time.perf_counter()
        with open_cloud_writer(
            cloud_path,
            fields=plot_fields(),
            metadata=_metadata(placed),
            origin_hint_m=plot.frame().origin_array,
            threads=int(threads),
        ) as writer:
            kept: list[tuple[np.ndarray, dict[str, np.ndarray]]] = []

            def tee(p: np.ndarray, f: dict[str, np.ndarray]) -> None:
                writer.write(p, f)
                if figures:  # the figures use the float64 points, not the file's
                    kept.append((p, {k: f[k] for k in _FIGURE_FIELDS}))

            res = scan_plot(
                plot,
                placed,
                params,
                sink=tee,
                threads=threads,
                progress=scaled(say, 0.0, 0.7 if figures else 0.95),
                cache_triangles=cache_triangles,
                executor=executor,
                workers=workers,
                scheduler=scheduler,
                cache_dir=cache_dir,
                sectors=sectors,
            )
        written.append(cloud_path)
        t_scan = time.perf_counter() - t0
        rows: list[dict[str, Any]] = []
        t_fig = 0.0
        if figures:
            t1 = time.perf_counter()
            cloud = Cloud(
                np.concatenate([p for p, _ in kept]) if kept else np.empty((0, 3)),
                {
                    k: np.concatenate([f[k] for _, f in kept])
                    if kept
                    else np.empty(0, dtype=plot_fields()[k])
                    for k in _FIGURE_FIELDS
                },
                _metadata(placed),
            )
            kept.clear()
            rows = tree_figures(plot, cloud, params=compare, progress=scaled(say, 0.7, 0.97))
            del cloud
            t_fig = time.perf_counter() - t1
        truth = [plot.truth(t) for t in plot.tree_ids]
        summary = json_ready(
            {
                "plot": {
                    "trees": len(plot.trees),
                    "radius_m": plot.radius_m,
                    "centre_xy": list(plot.centre_xy),
                    "terrain": plot.terrain.kind,
                    "facets": plot.facets,
                },
                "output": str(cloud_path),
                **res.summary(),
                "trees": rows,
                "truth": truth,
                "timings_s": {"scan": t_scan, "figures": t_fig},
            }
        )
        outputs = {"cloud": cloud_path}
        if figures:
            outputs["trees"] = write_figures_csv(out / PLOT_SCAN_FILES["trees"], rows)
            written.append(outputs["trees"])
        outputs["json"] = write_json(out / PLOT_SCAN_FILES["json"], summary)
        written.append(outputs["json"])
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        _remove_folders(made)
        raise
    say(1.0, "done")
    return StepResult(summary, outputs, res, {"trees": rows})
