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
from .caster import RayTables, cast_central
from .estimate import ScanEstimate, estimate_plan
from .planning import Plan, StationPlan, plan_scan
from .rays import directions, hashed_normal, pulse_angles
from .result import ScanResult, StationStats, lod_summary, scan_fields, scan_metadata
from .stations import Station
from .timing import TIME_FIELD, PulseClock

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
    )
    if estimate is not None:
        estimate(estimate_plan(plan, ".laz", max_rays))
    run = _Run(plan, scan_fields(scene), int(chunk_rays), sink, progress, station_offset)
    stats = [_station(run, sp, k) for k, sp in enumerate(plan.plans, start=station_offset)]
    spec, caster, culled = plan.spec, plan.caster, window and cull
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
        lod=lod_summary(lod, spec, stats, plan.geometry, culled, plan.adaptive),
        models=spec.active_models(),
        warnings=plan.warnings,
    )


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
    if run.plan.adaptive and sp.thin is not None:
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
    run: _Run, sp: StationPlan, tables: RayTables, k: int, per_chunk: int
) -> Iterator[Block]:
    """Station ``k``'s pulses cast ``per_chunk`` at a time, every pulse alike: its grid
    ray (gathered from ``tables``, refined in float64), its jittered ray, or its
    sub-rays."""
    spec, caster, s, grid, o = run.spec, run.caster, run.s, sp.grid, sp.o
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
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The points (local frame) and per-point fields of a block's returns ``rec`` from
    station ``k`` at ``o``: range noise, incidence, label and intensity."""
    spec, caster = run.spec, run.caster
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
