"""Scanning: :func:`scan` casts each station's planned pulses and gathers the points.

A scan runs in stages, each in a module of its own:

1. planning (:mod:`treesim.scan.planning`): each station's window, the pulses of it to
   cast, the triangles to load, the ray limit and the station checks and warnings
   (:mod:`treesim.scan.checks`);
2. the estimate, when one is asked for (:mod:`treesim.scan.estimate`);
3. casting, station by station (:func:`_station`) and block by block: one ray per pulse
   (:func:`_grid_blocks`) or the beam's sub-rays (:mod:`treesim.scan.beam`, adaptive
   where it may be), through the caster's float32 scene, with float64 hits
   (:mod:`treesim.scan.caster`, which states the precision);
4. each block's returns made points and fields (:func:`_block_points`; each pulse's
   time from its line and column, :mod:`treesim.scan.timing`), kept or handed to a
   sink (:class:`_Output`);
5. the result and its account of what ran (:mod:`treesim.scan.result`).

Memory: pulses are cast in chunks of at most ``chunk_rays`` rays (about 200 bytes per
ray in flight), and with a ``sink`` each chunk's points leave as they are made, so peak
memory does not grow with the resolution or the number of points.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from ..cloud import LABEL_CODES, Cloud
from ..errors import InvalidParameterError
from ..frame import LocalFrame
from ..params import ScannerSpec
from ..scene import Scene
from .beam import (
    AdaptiveBeam,
    beam_returns,
    single_returns,
    subray_directions,
    subray_pattern,
)
from .caster import Caster, RayTables, cast_central
from .estimate import ScanEstimate, estimate_plan
from .planning import Plan, StationPlan, plan_scan
from .rays import (
    PulseGrid,
    box_window,
    column_azimuth_rad,
    directions,
    full_grid,
    hashed_normal,
    pulse_angles,
    windowed_grid,
)
from .result import ScanResult, StationStats, lod_summary, scan_fields, scan_metadata
from .stations import Station
from .timing import TIME_FIELD, PulseClock
from .wind import (
    STATION_GAP_S,
    WIND_FIELD,
    Cylinders,
    MovingScene,
    Sectors,
    Wind,
    hit_displacement_m,
    moving_warnings,
    slice_duration_s,
    wind_summary,
)

Progress = Callable[[float, str], None]
#: Receives each chunk of a scan: points (n, 3) float64 and per-point fields.
Sink = Callable[[np.ndarray, dict[str, np.ndarray]], None]
#: Bytes per ray in flight (Open3D's ≈57 B plus treesim's float64 bookkeeping).
BYTES_PER_RAY = 200
#: A block of a station's pulses, cast: its return records, the grid lines, columns and
#: float64 directions of the pulses the records index, and the pulses and rays cast.
Block = tuple[dict[str, Any], np.ndarray, np.ndarray, np.ndarray, int, int]


def scan(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec | None = None,
    *,
    window: bool = True,
    cull: bool = True,
    chunk_rays: int = 1 << 19,
    max_rays: int = 1_000_000_000,
    nthreads: int = 0,
    check_inside: bool = True,
    progress: Progress | None = None,
    sink: Sink | None = None,
    lod: str = "auto",
    estimate: Callable[[ScanEstimate], None] | None = None,
    frame: LocalFrame | None = None,
    station_offset: int = 0,
    wind: Wind | None = None,
    sink_fields: Sequence[str] | None = None,
    columns: tuple[int, int] | None = None,
) -> ScanResult:
    """Scan a scene from one or more stations.

    Parameters
    ----------
    scene : Scene
        The labelled meshes (any coordinates; georeferenced is fine).
    stations : sequence of Station
        Scanner positions; the output's ``station`` field is the index into this list.
    spec : ScannerSpec
        Scanner settings (default ``ScannerSpec()``).
    window : bool
        Cast only the pulses whose direction can reach the scene's bounds (default), or
        the whole field of view (``False``; same points, many more rays).
    cull : bool
        Within the window, cast only the cells some triangle can reach
        (:mod:`treesim.scan.occupancy`; default). Conservative: the same points, bit for
        bit, as casting the whole window.
    chunk_rays : int
        Rays cast per batch; bounds peak memory to about ``chunk_rays × 200`` bytes.
    max_rays : int
        Refuse (``ResourceLimitError``, with an estimate) a scan that needs more rays.
    nthreads : int
        Open3D threads (0: all cores).
    check_inside : bool
        Refuse stations enclosed by the geometry.
    progress : callable(fraction, message), optional
        Called after each chunk.
    sink : callable(points, fields), optional
        Receives each chunk's points (float64, the scene's coordinates) and fields as
        they are made (e.g. a :func:`treesim.io.open_cloud_writer`'s ``write``); the
        result's cloud then holds no points, so memory does not grow with the output.
    lod : {"auto", "full"}
        Level of detail. ``"auto"`` (default) models only what the scene requires:
        triangles that no station can record (beyond ``max_range_m`` or outside every
        field of view) are never loaded into the ray-casting scene, and the beam model
        follows ``spec.beam_sampling``. ``"full"`` loads everything and gives every
        pulse its sub-rays. ``result.lod`` says what ran and why.
    estimate : callable(ScanEstimate), optional
        Called once, after planning and before casting, with the scan's estimated rays,
        points, file size (as LAZ) and time, from a sample cast on this machine
        (:mod:`treesim.scan.estimate`); :func:`estimate_scan` gives it alone.
    frame : LocalFrame, optional
        The float64 origin the scene is cast around (default: the centre of its
        vertices' bounds). Scans of parts of one scene that share a frame share their
        float32 geometry: a plot scanned station by station, with only the trees each
        station can record (:func:`treesim.plot.scan.scan_plot`), gives the points of
        the whole plot's scan.
    station_offset : int
        Index of ``stations[0]`` in a longer list (a plot scanned station by station):
        the ``station`` field, the station figures and the per-station random draws
        (range noise, jitter, beam) use ``station_offset + k``, so one station scanned
        alone gives what it gives among the others.
    wind : Wind, optional
        What sways the tree and how (:class:`treesim.scan.wind.Wind`: its cylinder
        table and a turbulent wind or a steady sinusoidal sway). Default: the spec's
        ``wind_speed_m_s`` and ``wind_cylinders``; at 0 m/s (the default) the scene is
        still and the scan is today's, bit for bit. With wind, the pulses are cast in
        time slices against the tree posed at each slice's mid time
        (:func:`_scan_moving`) and each point carries ``wind_displacement_m``; without a
        cylinder table the scene stays still and the result says so in a warning.
    sink_fields : sequence of str, optional
        The fields the ``sink`` was opened with, when they include the wind's
        ``wind_displacement_m`` (:func:`scan_fields` with the spec); by default a sink
        gets :func:`scan_fields` of the scene alone.
    columns : (int, int), optional
        Cast only the pulses of scan columns ``c0 <= column < c1`` (an azimuth sector
        of each station: :func:`treesim.plot.scan.scan_plot`'s ``sectors``, see
        :mod:`treesim.plot.sectors` for how close its sectors' points are to the
        station's).

    Returns
    -------
    ScanResult
        ``result.cloud`` in the scene's coordinates (float64), with per-point fields.

    Examples
    --------
    >>> import treesim as ts
    >>> scene = ts.load_scene(["tree.obj"])  # doctest: +SKIP
    >>> stations = ts.ring_layout(3, distance_m=10.0, height_m=1.5, centre_xy=(0.0, 0.0))
    >>> spec = ts.ScannerSpec(horizontal_resolution_deg=0.04, vertical_resolution_deg=0.04)
    >>> result = ts.scan(scene, stations, spec)  # doctest: +SKIP
    >>> ts.write_cloud("scan.laz", result.cloud)  # doctest: +SKIP
    """
    station_offset = _checked(chunk_rays, station_offset)
    t_all = time.perf_counter()
    wind = wind if wind is not None else Wind.from_spec(spec or ScannerSpec())
    table = wind.cylinder_table() if wind is not None else None
    if table is not None:
        assert wind is not None
        if columns is not None:
            raise InvalidParameterError("a scan with wind casts every column: give no columns")
        opts = {"window": window, "chunk_rays": chunk_rays, "max_rays": max_rays}
        opts |= {"nthreads": nthreads, "check_inside": check_inside, "progress": progress}
        opts |= {"sink": sink, "frame": frame, "station_offset": station_offset}
        opts |= {"sink_fields": sink_fields, "t_all": t_all}
        return _scan_moving(scene, stations, spec or ScannerSpec(), wind, table, **opts)
    plan = plan_scan(
        scene,
        stations,
        spec,
        window=window,
        cull=cull,
        lod=lod,
        nthreads=nthreads,
        max_rays=max_rays,
        check_inside=check_inside,
        frame=frame,
        station_offset=station_offset,
        columns=columns,
    )
    if estimate is not None:
        estimate(estimate_plan(plan, ".laz", max_rays))
    run = _Run(plan, scan_fields(scene), int(chunk_rays), sink, progress, station_offset)
    stats = [_station(run, sp, k) for k, sp in enumerate(plan.plans, start=station_offset)]
    spec, caster, culled = plan.spec, plan.caster, window and cull
    warnings = plan.warnings
    if wind is not None:  # wind, but no cylinder table: a plain mesh stays still
        warnings = [*warnings, still_warning(wind)]
    return ScanResult(
        cloud=run.output.cloud(plan.stations),
        spec=spec,
        stations=plan.stations,
        station_stats=stats,
        frame=plan.frame,
        bvh_build_s=caster.build_s if caster is not None else 0.0,
        total_s=time.perf_counter() - t_all,
        window=window,
        cull=culled,
        points_written=run.output.written,
        lod=lod_summary(lod, spec, stats, plan.geometry, culled, plan.adaptive, plan.edge),
        models=spec.active_models(),
        warnings=warnings,
    )


def still_warning(wind: Wind) -> str:
    """The warning of a windy scan of a scene without a cylinder table."""
    what = (
        f"wind {wind.forcing.speed_m_s:g} m/s" if wind.forcing is not None else "the sway asked for"
    )
    return (
        f"{what}: no cylinder table for the scene (a plain mesh has no branches to sway), "
        "so it was scanned still; give the tree's table (--wind-cylinders, or treesim "
        "model's OUT.cylinders.csv / treesim reconstruct's cylinders.csv beside the mesh)"
    )


def _scan_moving(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec,
    wind: Wind,
    table: Cylinders,
    *,
    t_all: float,
    frame: LocalFrame | None,
    sink: Sink | None,
    sink_fields: Sequence[str] | None,
    **opts: Any,
) -> ScanResult:
    """A scan of a swaying tree: each station's pulses in time slices (runs of mirror
    cycles), each slice cast against the triangles it can reach, posed at the slice's
    mid time (:class:`~treesim.scan.wind.MovingScene`), through a caster of its own
    with the still path's float64 guarantees. Beams cast every sub-ray (no adaptive
    sampling: its thin-geometry mask is made of the rest pose)."""
    frame = frame or LocalFrame.around(scene.used_vertices)
    origin = np.asarray(frame.origin, dtype=np.float64)
    moving = MovingScene(
        frame.to_local(scene.vertices),
        scene.faces,
        scene.face_label,
        scene.face_tree,
        table.shifted(origin),
        wind.model_for,
    )
    plan = plan_scan(
        scene,
        stations,
        spec,
        window=opts["window"],
        cull=False,
        lod="full",
        nthreads=opts["nthreads"],
        max_rays=opts["max_rays"],
        check_inside=opts["check_inside"],
        frame=frame,
        station_offset=opts["station_offset"],
    )
    fields = scan_fields(scene)
    if sink is None or (sink_fields is not None and WIND_FIELD in sink_fields):
        fields[WIND_FIELD] = np.dtype(np.float64)
    chunk, offset = int(opts["chunk_rays"]), opts["station_offset"]
    run = _Run(plan, fields, chunk, sink, opts["progress"], offset)
    run.caster_threads = int(opts["nthreads"])  # type: ignore[attr-defined]
    grids = [_envelope_grid(moving, sp, spec, opts["window"]) for sp in plan.plans]
    run.total_pulses = max(1, sum(g.n_pulses for g in grids))
    stats, slicing = [], []
    for j, (sp, grid) in enumerate(zip(plan.plans, grids, strict=True)):
        st, info = _moving_station(run, moving, sp, grid, opts["station_offset"] + j, wind)
        stats.append(st)
        slicing.append(info)
    lod = lod_summary("full", spec, stats, plan.geometry, False, False)
    return ScanResult(
        cloud=run.output.cloud(plan.stations),
        spec=spec,
        stations=plan.stations,
        station_stats=stats,
        frame=plan.frame,
        bvh_build_s=sum(i["bvh_build_s"] for i in slicing),
        total_s=time.perf_counter() - t_all,
        window=opts["window"],
        cull=False,
        points_written=run.output.written,
        lod=lod,
        models=spec.active_models() if wind.forcing is not None else ["wind: steady sinusoid"],
        warnings=plan.warnings + moving_warnings(moving),
        wind=wind_summary(moving, wind, slicing),
    )


def _envelope_grid(moving: MovingScene, sp: StationPlan, spec: ScannerSpec, window: bool) -> Any:
    """A station's pulses: the window of the scene with its moving vertices' bounds
    widened by how far they can move (or the whole field of view)."""
    if not window:
        return full_grid(spec)
    used = np.unique(moving.faces)
    pts = moving.v[used]
    mov = used[moving.cyl_of[used] >= 0]
    if len(mov):
        reach = float(moving.reach_v[mov].max())
        lo, hi = moving.v[mov].min(axis=0) - reach, moving.v[mov].max(axis=0) + reach
        box = np.stack([lo, hi])
        corners = box[np.array(np.meshgrid([0, 1], [0, 1], [0, 1])).reshape(3, -1).T, [0, 1, 2]]
        pts = np.concatenate([pts, corners])
    rel = (pts - sp.o) @ sp.station.rotation
    return windowed_grid(spec, box_window(rel.min(axis=0), rel.max(axis=0)))


#: Slices that share one reference pose for choosing their triangles (:class:`~treesim.
#: scan.wind.Sectors`): the tree's motion within a block widens their sectors.
SECTOR_BLOCK = 16


def _moving_station(
    run: _Run, moving: MovingScene, sp: StationPlan, grid: Any, k: int, wind: Wind
) -> tuple[StationStats, dict[str, Any]]:
    """Cast station ``k``'s pulses (``grid``) slice by slice against the tree posed at
    each slice's mid time; the station's figures and its slicing."""
    t_st = time.perf_counter()
    spec, m = run.spec, run.clock.mechanics
    tables = RayTables(spec, sp.station)
    slices, info = _station_slices(run, moving, sp, grid, k, wind)
    times = np.array([t for _, _, t in slices])
    pad = math.radians(spec.horizontal_resolution_deg + 6.0 * spec.angular_jitter_sd_deg)
    pad += spec.beam_divergence_mrad * 1e-3 + 1e-9
    counts = np.zeros(3)  # points, rays, seconds building the slices' BVHs
    # every pose of the station lies within its branches' largest tips from rest (the
    # tips computed a block at a time: memory does not grow with the slices)
    reach = np.zeros(moving.structure.nb)
    for b0 in range(0, len(slices), 256):
        tips = moving.model.tips_many(times[b0 : b0 + 256])
        reach = np.maximum(reach, np.linalg.norm(tips, axis=2).max(axis=0))
    rot = sp.station.rotation
    whole = Sectors(moving.v, moving.faces, sp.o, rot, moving.vertex_bound(reach))
    for b0 in range(0, len(slices), SECTOR_BLOCK):
        block = np.arange(b0, min(len(slices), b0 + SECTOR_BLOCK))
        tips = moving.model.tips_many(times[block])
        sel_all = np.unique(np.concatenate([slices[j][1] for j in block]))
        cand = whole.triangles(_column_runs(spec, sel_all, run.clock, m.two_sided), pad)
        sectors = _block_sectors(moving, sp, cand, block, slices, tips) if len(cand) else None
        for i, j in enumerate(block):
            lines_s, sel, t_mid = slices[j]
            sub = PulseGrid(lines_s, sel)
            tri = (
                cand[sectors.triangles(_column_runs(spec, sel, run.clock, m.two_sided), pad)]
                if sectors is not None
                else cand
            )
            if not len(tri):
                run.advance(sub.n_pulses, k)
                continue
            counts += _cast_slice(run, moving, sp, sub, tables, k, tri, (t_mid, tips[i]))
    stats = StationStats(
        index=k,
        position_m=sp.station.position_m,
        pulses_full_fov=spec.n_azimuth * spec.n_elevation,
        pulses_window=grid.n_pulses,
        pulses_cast=grid.n_pulses,
        rays_cast=int(counts[1]),
        points=int(counts[0]),
        azimuth_window_deg=sp.window.azimuth_deg,
        elevation_window_deg=sp.window.elevation_deg,
        time_s=time.perf_counter() - t_st,
        scan_duration_s=m.duration_s,
        pulses_subrays=grid.n_pulses if run.s > 1 else 0,
    )
    info["bvh_build_s"] = float(counts[2])
    return stats, info


def _block_sectors(
    moving: MovingScene,
    sp: StationPlan,
    cand: np.ndarray,
    block: np.ndarray,
    slices: list[tuple[np.ndarray, np.ndarray, float]],
    tips: np.ndarray,
) -> Sectors:
    """The sectors of triangles ``cand`` for a block of slices (``tips``: the model's
    tips at each of them): posed exactly at the block's middle slice, widened by how far
    the other slices' poses lie from it."""
    mid = len(block) // 2
    ref = block[mid]
    f = moving.faces[cand]
    mark = np.zeros(len(moving.v), dtype=bool)
    mark[f.ravel()] = True
    used = np.flatnonzero(mark)
    index = np.cumsum(mark) - 1
    model = moving.model
    at = (moving.branch[used], moving.xi[used], tips[mid], moving.phi[used])
    shift = model.displacement(slices[ref][2], *at)
    chain = model.chain_sum(np.linalg.norm(tips - tips[mid], axis=2).max(axis=0))
    bound = np.where(moving.cyl_of[used] >= 0, chain[np.maximum(moving.branch[used], 0)], 0.0)
    return Sectors(moving.v[used] + shift, index[f], sp.o, sp.station.rotation, bound)


def _cast_slice(
    run: _Run,
    moving: MovingScene,
    sp: StationPlan,
    sub: PulseGrid,
    tables: RayTables,
    k: int,
    tri: np.ndarray,
    when: tuple[float, np.ndarray],
) -> np.ndarray:
    """Cast one slice's pulses ``sub`` against triangles ``tri`` posed at ``when`` (the
    time and the model's tips then) through a caster of their own; the points go to the
    output. Returns (points, rays, seconds building the BVH)."""
    posed, faces, disp = moving.posed(when[0], tri, when[1])
    posed_scene: Any = _Posed(moving, posed, faces, tri)
    caster = Caster(posed_scene, LocalFrame(), run.caster_threads)  # type: ignore[attr-defined]
    sub_plan = StationPlan(sp.station, sp.o, sub, sp.window, sp.n_window, None, 0.0)
    sub_plan.t0 = caster.entry_distance(sp.o)
    n_points = rays = 0
    per_chunk = max(1, run.chunk_rays // run.s)
    for rec, lines, cols_r, d, n_pulses, n_rays in _grid_blocks(
        run, sub_plan, tables, k, per_chunk, caster
    ):
        if len(rec["pulse"]):
            p_local, fields = _block_points(run, sp.o, k, rec, lines, cols_r, d, caster)
            if WIND_FIELD in run.output.fields:
                prim = rec["primitive"]
                fields[WIND_FIELD] = hit_displacement_m(posed, faces, disp, prim, p_local)
            run.output.add(p_local, fields)
            n_points += len(rec["pulse"])
        rays += n_rays
        run.advance(n_pulses, k)
    return np.array([n_points, rays, caster.build_s])


def _station_slices(
    run: _Run, moving: MovingScene, sp: StationPlan, grid: Any, k: int, wind: Wind
) -> tuple[list[tuple[np.ndarray, np.ndarray, float]], dict[str, Any]]:
    """A station's time slices, each cast against the tree posed at its mid time: the
    longest that keep the motion within a slice under ``wind.slice_fraction`` of the
    point spacing where the tree can come nearest. Runs of whole mirror cycles (a
    column, and with a two-sided mirror the one opposite) where a slice lasts a cycle
    or more; else runs of lines within one column. Each slice: its lines, its columns
    and its mid time on the wind's clock (station ``k``'s scan starts
    ``k × (duration + STATION_GAP_S)``). And what was chosen, for the summary."""
    spec, clock = run.spec, run.clock
    m = clock.mechanics
    cols = np.asarray(grid.columns, dtype=np.int64)
    lines = np.asarray(grid.lines, dtype=np.int64)
    cyc = np.where(cols >= clock._front, cols - clock._half, cols) if m.two_sided else cols
    step = math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
    moved = moving.cyl_of >= 0
    near = float(np.linalg.norm(moving.v[moved] - sp.o, axis=1).min()) if moved.any() else 1.0
    # the spacing where the tree can come nearest: its rest range less its reach
    near = max(near - float(moving.reach_v.max()), 0.1 * near)
    limit = wind.slice_fraction * near * step
    span = int(cyc.max() - cyc.min() + 1) if len(cyc) else 1
    dur = slice_duration_s(moving.model, limit, span * m.line_period_s)
    t_offset = k * (m.duration_s + STATION_GAP_S)
    slices: list[tuple[np.ndarray, np.ndarray, float]] = []
    if len(lines) and len(cols):
        if dur >= m.line_period_s:
            n = int(dur // m.line_period_s)
            sid = (cyc - cyc.min()) // n
            ends = lines[[0, -1]]
            for s_id in np.unique(sid):
                sel = cols[sid == s_id]
                times = clock(np.repeat(ends, len(sel)), np.tile(sel, 2))
                mid = 0.5 * (float(times.min()) + float(times.max())) + t_offset
                slices.append((lines, sel, mid))
        else:  # a slice is shorter than a mirror cycle: runs of lines of one column
            for c in cols:
                times = clock(lines, np.full(len(lines), c))
                gid = np.floor((times - times.min()) / dur).astype(np.int64)
                for g in np.unique(gid):
                    t_g = times[gid == g]
                    mid = 0.5 * (float(t_g.min()) + float(t_g.max())) + t_offset
                    slices.append((lines[gid == g], np.array([c]), mid))
    info = {
        "station": k,
        "slices": len(slices),
        "slice_s": min(dur, span * m.line_period_s),
        "line_period_s": m.line_period_s,
        "limit_m": limit,
        "nearest_m": near,
        "wind_clock_offset_s": t_offset,
    }
    return slices, info


def _column_runs(spec: ScannerSpec, cols: np.ndarray, clock: PulseClock, two_sided: bool) -> list:
    """The azimuths (rad, scanner frame) of a slice's columns, as runs of neighbours:
    with a two-sided mirror the columns of the front half turn and those opposite."""
    if not two_sided:
        return [column_azimuth_rad(spec, cols)]
    back = cols >= clock._front
    return [column_azimuth_rad(spec, cols[~back]), column_azimuth_rad(spec, cols[back])]


class _Posed:
    """The triangles of one slice, posed: what :class:`~treesim.scan.caster.Caster`
    reads of a scene (vertices already in the scan's local frame)."""

    def __init__(self, moving: MovingScene, v: np.ndarray, faces: np.ndarray, tri: np.ndarray):
        self.vertices, self.faces = v, faces
        self.face_label = moving.face_label[tri]
        self.face_tree = None if moving.face_tree is None else moving.face_tree[tri]
        self.bounds = np.stack([v.min(axis=0), v.max(axis=0)])


def _checked(chunk_rays: int, station_offset: int) -> int:
    """Refuse a bad ``chunk_rays`` or ``station_offset``; the offset as an int. Checked
    before planning, which names stations by the offset and builds the BVH."""
    if int(chunk_rays) < 1:
        raise InvalidParameterError(f"chunk_rays must be >= 1, got {chunk_rays}")
    if isinstance(station_offset, bool) or int(station_offset) < 0:
        raise InvalidParameterError(f"station_offset must be >= 0, got {station_offset!r}")
    return int(station_offset)


class _Output:
    """Where a scan's points go: kept for the result's cloud, or handed to a sink chunk by
    chunk (in the scene's coordinates), so that memory does not grow with the output."""

    def __init__(self, frame: LocalFrame, fields: dict[str, np.dtype], sink: Sink | None):
        self.frame, self.fields, self.sink = frame, fields, sink
        self.with_trees = "tree_id" in fields
        self.points: list[np.ndarray] = []
        self.values: dict[str, list[np.ndarray]] = {k: [] for k in fields}
        #: points handed to the sink
        self.written = 0

    def add(self, p_local: np.ndarray, fields: dict[str, np.ndarray]) -> None:
        """Points (local frame) and their fields, one block's."""
        if self.sink is not None:
            self.sink(self.frame.to_global(p_local), fields)
            self.written += len(p_local)
        else:
            self.points.append(p_local)
            for name, values in fields.items():
                self.values[name].append(values)

    def cloud(self, stations: Sequence[Station]) -> Cloud:
        """The points kept, in the scene's coordinates (none with a sink)."""
        if self.points:
            points = self.frame.to_global(np.concatenate(self.points))
            fields = {k: np.concatenate(v) for k, v in self.values.items()}
        else:
            points = np.empty((0, 3))
            fields = {k: np.empty(0, dtype=v) for k, v in self.fields.items()}
        return Cloud(points, fields, scan_metadata(stations))


class _Run:
    """What the stations of one scan share while they cast: the plan, the beam's sub-ray
    pattern, each label's reflectance, the output and the progress."""

    def __init__(
        self,
        plan: Plan,
        fields: dict[str, np.dtype],
        chunk_rays: int,
        sink: Sink | None,
        progress: Progress | None,
        station_offset: int,
    ) -> None:
        spec = plan.spec
        self.plan, self.spec, self.caster = plan, spec, plan.caster
        self.s = spec.rays_per_pulse
        self.chunk_rays = chunk_rays
        self.offsets, self.weights = (
            subray_pattern(self.s, spec.beam_divergence_mrad) if self.s > 1 else (None, None)
        )
        self.reflect = np.zeros(len(LABEL_CODES))
        for name, code in LABEL_CODES.items():
            self.reflect[code] = spec.reflectance.get(name, spec.reflectance.get("other", 0.5))
        self.output = _Output(plan.frame, fields, sink)
        #: each pulse's time, from its line and column (:mod:`treesim.scan.timing`)
        self.clock = PulseClock(spec)
        self.progress = progress
        self.total_pulses = max(1, plan.pulses_cast)
        self.done_pulses = 0
        # "station 2/4" only where every station is scanned here (not a plot's one by one)
        self.of = f"/{len(plan.stations)}" if not station_offset else ""

    def advance(self, n_pulses: int, k: int) -> None:
        """Count a block's pulses as done and say so."""
        self.done_pulses += n_pulses
        if self.progress is not None:
            self.progress(self.done_pulses / self.total_pulses, f"station {k + 1}{self.of}")


def _station(run: _Run, sp: StationPlan, k: int) -> StationStats:
    """Cast station ``k``'s planned pulses, block by block, into the output."""
    t_st = time.perf_counter()
    n_points = rays_cast = 0
    tables = RayTables(run.spec, sp.station)
    beam = None
    # no thin-geometry mask (thin geometry nearly everywhere): every pulse needs its
    # sub-rays anyway, cast as the full model casts them
    if run.plan.edge:
        from .beam import EdgeBeam

        beam = EdgeBeam(run.caster, run.spec, sp, tables, k)
        blocks = beam.blocks(max(1, run.chunk_rays), run.offsets, run.weights)
    elif run.plan.adaptive and sp.thin is not None:
        beam = AdaptiveBeam(run.caster, run.spec, sp, tables, k)
        blocks = beam.blocks(max(1, run.chunk_rays), run.offsets, run.weights)
    else:
        blocks = _grid_blocks(run, sp, tables, k, max(1, run.chunk_rays // run.s))
    for rec, lines, cols, d, n_pulses, n_rays in blocks:
        if len(rec["pulse"]):
            run.output.add(*_block_points(run, sp.o, k, rec, lines, cols, d))
            n_points += len(rec["pulse"])
        rays_cast += n_rays
        run.advance(n_pulses, k)
    spec, grid = run.spec, sp.grid
    return StationStats(
        index=k,
        position_m=sp.station.position_m,
        pulses_full_fov=spec.n_azimuth * spec.n_elevation,
        pulses_window=sp.n_window,
        pulses_cast=grid.n_pulses,
        rays_cast=rays_cast,
        points=n_points,
        azimuth_window_deg=sp.window.azimuth_deg,
        elevation_window_deg=sp.window.elevation_deg,
        time_s=time.perf_counter() - t_st,
        scan_duration_s=run.clock.mechanics.duration_s,
        pulses_subrays=(
            sum(beam.reasons.values()) if beam is not None else (grid.n_pulses if run.s > 1 else 0)
        ),
        subray_reasons=(
            dict(beam.reasons)
            if beam is not None
            else ({"thin geometry everywhere": grid.n_pulses} if run.plan.adaptive else None)
        ),
    )


def _grid_blocks(
    run: _Run,
    sp: StationPlan,
    tables: RayTables,
    k: int,
    per_chunk: int,
    caster: Caster | None = None,
) -> Iterator[Block]:
    """Station ``k``'s pulses cast ``per_chunk`` at a time, every pulse alike: its grid
    ray (gathered from ``tables``, refined in float64), its jittered ray, or its
    sub-rays; through ``caster`` (default the scan's)."""
    spec, s, grid, o = run.spec, run.s, sp.grid, sp.o
    caster = run.caster if caster is None else caster
    fast = s == 1 and spec.angular_jitter_sd_deg == 0
    for a in range(0, grid.n_pulses, per_chunk):
        b = min(grid.n_pulses, a + per_chunk)
        lines, cols = grid.indices(a, b)
        n_pulses, n_rays = b - a, (b - a) * s
        if fast:
            hidx, t, prim, d_r = cast_central(caster, tables, lines, cols, o, sp.t0)
            yield single_returns(spec, t, prim), lines[hidx], cols[hidx], d_r, n_pulses, n_rays
            continue
        az, el = pulse_angles(spec, k, lines, cols)
        d = directions(az, el) @ tables.rot.T
        if s == 1:
            t, prim = caster.cast(o, d)
            rec = single_returns(spec, t, prim)
        else:
            sd = subray_directions(d, run.offsets).reshape(-1, 3)
            t, prim = caster.cast(o, sd)
            rec = beam_returns(spec, t.reshape(-1, s), prim.reshape(-1, s), sd, run.weights)
        yield rec, lines, cols, d, n_pulses, n_rays


def _block_points(
    run: _Run,
    o: np.ndarray,
    k: int,
    rec: dict[str, Any],
    lines_r: np.ndarray,
    cols_r: np.ndarray,
    d_r: np.ndarray,
    caster: Caster | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The points (local frame) and per-point fields of a block's returns ``rec`` from
    station ``k`` at ``o``: range noise, incidence, label and intensity (the triangles'
    of ``caster``, default the scan's)."""
    spec = run.spec
    caster = run.caster if caster is None else caster
    n_rec = len(rec["pulse"])
    pi = rec["pulse"]
    rng = rec["range_m"]
    if spec.range_noise_sd_m > 0:
        # independent draws per pulse and per return
        rng = rng + spec.range_noise_sd_m * hashed_normal(
            spec.seed, 1, k, lines_r[pi], cols_r[pi], sub=rec["return_number"]
        )
    rd = rec["direction"]
    ray_d = d_r[pi] if rd is None else np.where(np.isnan(rd[:, :1]), d_r[pi], rd)
    p_local = o + rng[:, None] * d_r[pi]
    prim = rec["primitive"]
    lab = caster.label[prim]
    cosi = np.abs(np.einsum("ij,ij->i", ray_d, caster.normal[prim]))
    inc = np.degrees(np.arccos(np.clip(cosi, 0.0, 1.0)))
    ref10 = np.minimum(1.0, (10.0 / np.maximum(rng, 1e-9)) ** 2)
    inten = np.clip(run.reflect[lab] * cosi * rec["energy"] * ref10, 0.0, 1.0)
    fields = {
        "station": np.full(n_rec, k, dtype=np.uint16),
        "range_m": rng.astype(np.float64),
        "incidence_deg": inc.astype(np.float32),
        "label": lab.astype(np.uint8),
        "return_number": rec["return_number"].astype(np.uint8),
        "number_of_returns": rec["number_of_returns"].astype(np.uint8),
        "intensity": np.round(inten * 65535).astype(np.uint16),
        "scan_line": lines_r[pi].astype(np.int32),
        "scan_column": cols_r[pi].astype(np.int32),
        # every return of a pulse shares the pulse's time (its line and column)
        TIME_FIELD: run.clock(lines_r[pi], cols_r[pi]),
    }
    if run.output.with_trees:
        fields["tree_id"] = caster.tree[prim].astype(np.uint32)
    return p_local, fields


__all__ = ["BYTES_PER_RAY", "scan"]
