"""Planning a scan: each station's window, the pulses of it to cast, the triangles to load.

Which pulses: each station's window (the angular rectangle of the scene's bounding box,
:func:`~treesim.scan.rays.box_window`), narrowed to the cells some triangle can reach
(:mod:`treesim.scan.occupancy`; the same points, bit for bit). Under ``lod="auto"``
triangles no station can record are never loaded into the caster, and the beam model's
adaptive sampling (:class:`~treesim.scan.beam.AdaptiveBeam`) gets each station's mask of
thin geometry. :func:`plan_scan` does all :func:`treesim.scan.scan` and
:func:`treesim.scan.estimate_scan` do before they cast, the ray limit and the station
checks (:mod:`treesim.scan.checks`) included, and returns a :class:`Plan`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..frame import LocalFrame
from ..params import LODS, ScannerSpec
from ..scene import Scene
from . import checks
from .caster import Caster, float32_error_m, triangle_chunks
from .occupancy import (
    Occupancy,
    face_bounds,
    face_rows,
    occupancy_grid,
    reachable,
    thin_mask,
)
from .rays import PulseGrid, box_window, full_grid, windowed_grid
from .stations import Station


@dataclass
class StationPlan:
    """One station, planned: where it stands and the pulses it casts."""

    station: Station
    #: its position in the local frame
    o: np.ndarray
    #: the pulses to cast (the window, or its cells some triangle can reach)
    grid: Any
    #: the window's angles (:func:`~treesim.scan.rays.box_window`) and its pulses
    window: Any
    n_window: int
    #: adaptive beam sampling's thin-geometry keys (None: thin everywhere, or no mask)
    thin: np.ndarray | None
    #: how far forward its rays start (:meth:`~treesim.scan.caster.Caster.entry_distance`)
    t0: float


@dataclass
class Plan:
    """A scan, planned: what :func:`~treesim.scan.scan` casts, station by station."""

    spec: ScannerSpec
    stations: list[Station]
    frame: LocalFrame
    caster: Caster | None
    plans: list[StationPlan]
    geometry: dict[str, Any]
    adaptive: bool
    plan_s: float
    #: what ran but may not be what was meant (stations on surfaces, lost precision)
    warnings: list[str]
    #: the beam's edge model casts (``beam_sampling="edge"`` under ``lod="auto"``; with
    #: ``lod="full"`` every pulse gets its sub-rays)
    edge: bool = False

    @property
    def pulses_cast(self) -> int:
        return sum(p.grid.n_pulses for p in self.plans)


def plan_scan(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec | None,
    *,
    window: bool,
    cull: bool,
    lod: str,
    nthreads: int,
    max_rays: int | None,
    check_inside: bool,
    frame: LocalFrame | None = None,
    station_offset: int = 0,
    columns: tuple[int, int] | None = None,
) -> Plan:
    """Each station's window and the pulses of it to cast, the triangles to load and the
    ray-casting scene: everything :func:`~treesim.scan.scan` and
    :func:`~treesim.scan.estimate_scan` do before they cast (``spec`` None:
    ``ScannerSpec()``). ``max_rays`` None: no limit (an estimate reports it instead).
    ``frame`` None: one around the scene's vertices; ``station_offset`` is added to the
    station indices in messages; ``columns`` ``(c0, c1)`` keeps only the pulses of scan
    columns ``c0 <= column < c1`` (an azimuth sector)."""
    spec = spec or ScannerSpec()
    stations = list(stations)
    if not stations:
        raise InvalidParameterError("give at least one station")
    t_all = time.perf_counter()
    frame = frame or LocalFrame.around(scene.used_vertices)
    verts_used = frame.to_local(scene.used_vertices)
    s = spec.rays_per_pulse
    if lod not in LODS:
        raise InvalidParameterError(f"lod must be one of {', '.join(LODS)}, got {lod!r}")
    adaptive = s > 1 and spec.beam_sampling == "adaptive" and lod == "auto"
    origins = [frame.to_local(st.position) for st in stations]
    windows = [
        _grid_for(verts_used, o, st.rotation, spec, window, columns)
        for o, st in zip(origins, stations, strict=True)
    ]
    # the limit is checked on the window with every sub-ray (an upper bound: culling
    # and adaptive sampling cast fewer), before any triangle is read
    upper = sum(grid.n_pulses for grid, _ in windows) * s
    checks.check_ray_limit(upper, len(stations), spec, max_rays, nthreads)
    radius = float(np.linalg.norm(verts_used, axis=1).max()) if len(verts_used) else 0.0
    del verts_used  # a float64 copy (~12 B a triangle): gone before the caster is built
    # one station: the occupancy grid takes the bounds that choose the triangles to load
    # (the same triangles, bounded once: issue 25)
    shared = _Shared.of(origins, windows[0][0], spec, window and cull, lod, radius)
    keep, geometry = _reachable_triangles(scene, frame, stations, spec, lod, radius, shared)
    if shared is not None and shared.occupancy is not None and geometry["loaded"]:
        shared.cast = shared.occupancy.grid()  # its raster goes before the caster comes
    caster = Caster(scene, frame, nthreads, keep) if geometry["loaded"] else None
    plans = []
    for o, st, (window_grid, win) in zip(origins, stations, windows, strict=True):
        if caster is None:  # nothing any station can record: a valid empty scan
            grid, thin = PulseGrid(np.empty(0, np.int64), np.empty(0, np.int64)), None
        else:
            grid, thin = _grid_plan(
                caster, window_grid, o, st.rotation, spec, window and cull, adaptive, radius,
                shared,
            )  # fmt: skip
        t0 = caster.entry_distance(o) if caster is not None else 0.0
        plans.append(StationPlan(st, o, grid, win, window_grid.n_pulses, thin, t0))
    del shared
    warnings = checks.precision_warnings(scene, caster, radius)
    if caster is not None:
        for k, sp in enumerate(plans, start=station_offset):
            if check_inside:
                checks.check_inside(caster, sp.o, k, sp.station)
            warnings += checks.station_warnings(caster, sp.o, k, sp.station)
    plan_s = time.perf_counter() - t_all
    edge = s > 1 and spec.beam_sampling == "edge" and lod == "auto"
    return Plan(spec, stations, frame, caster, plans, geometry, adaptive, plan_s, warnings, edge)


def _grid_for(
    verts_local: np.ndarray,
    o: np.ndarray,
    rot: np.ndarray,
    spec: ScannerSpec,
    window: bool,
    columns: tuple[int, int] | None = None,
) -> tuple[PulseGrid, Any]:
    """A station's pulse grid (its window of the scene's vertices, or, without ``window``,
    the whole field of view; only ``columns`` ``(c0, c1)`` when given) and the window's
    angles."""
    rel = (verts_local - o) @ rot  # scanner frame
    # column by column (the same figures, ten times faster than along axis 0)
    lo, hi = (np.array([ext(rel[:, k]) for k in range(3)]) for ext in (np.min, np.max))
    win = box_window(lo, hi)
    grid = windowed_grid(spec, win) if window else full_grid(spec)
    if columns is not None:
        c = grid.columns
        grid = PulseGrid(grid.lines, c[(c >= columns[0]) & (c < columns[1])])
    return grid, win


@dataclass
class _Shared:
    """A one-station plan's occupancy grid, fed with the bounds of the triangles it
    loads while they are chosen (``occupancy``; None where the grid is not culled), and
    the pulses it gives (``cast``)."""

    occupancy: Occupancy | None
    cast: Any = None

    @classmethod
    def of(
        cls,
        origins: Sequence[np.ndarray],
        grid: PulseGrid,
        spec: ScannerSpec,
        culled: bool,
        lod: str,
        radius_m: float,
    ) -> _Shared | None:
        """None unless one station (its origin in the local frame) plans with
        ``lod="auto"`` (else the occupancy grid bounds the loaded triangles itself)."""
        if len(origins) != 1 or lod != "auto":
            return None
        occ = None
        if culled and grid.n_pulses:
            err = float32_error_m(radius_m, origins[0])
            occ = Occupancy(spec, grid, _azimuth_ref(spec, grid), abs_error_m=err)
        return cls(occ)


def _azimuth_ref(spec: ScannerSpec, grid: PulseGrid) -> float:
    """An azimuth (deg) in the widest gap between the window's columns: the occupancy
    grid measures column angles from it without wrapping."""
    h0, hres = spec.horizontal_fov_deg[0], spec.horizontal_resolution_deg
    ang = np.sort((h0 + grid.columns * hres) % 360.0)
    gaps = np.diff(np.concatenate([ang, [ang[0] + 360.0]]))
    g = int(np.argmax(gaps))
    return float(ang[g] + 0.5 * gaps[g])


def _reachable_triangles(
    scene: Scene,
    frame: LocalFrame,
    stations: Sequence[Station],
    spec: ScannerSpec,
    lod: str,
    radius_m: float,
    shared: _Shared | None = None,
) -> tuple[np.ndarray | None, dict[str, Any]]:
    """The triangles to load (None: all) and what was left out, and why. With
    ``shared`` (one station), its occupancy grid is fed each loaded triangle's bounds."""
    n = scene.n_triangles
    info: dict[str, Any] = {"triangles": n, "loaded": n, "beyond_range": 0, "outside_fov": 0}
    if lod != "auto" or n == 0:
        return None, info
    v = frame.to_local(scene.vertices)
    f = scene.faces
    keep = np.zeros(n, dtype=bool)
    near = np.zeros(n, dtype=bool)
    for st in stations:
        o = frame.to_local(st.position)
        rel = (v - o) @ st.rotation
        err = float32_error_m(radius_m, o)
        # a chunk of triangles at a time: the bounds' temporaries are ~200 B a triangle
        for a, b in triangle_chunks(n):
            fa = f[a:b]
            bounds = face_bounds(rel, fa)
            reach = reachable(bounds, spec, abs_error_m=err)
            keep[a:b] |= reach
            near[a:b] |= bounds.d_min <= spec.max_range_m
            if shared is not None and shared.occupancy is not None:
                corners = lambda sel, fa=fa, rel=rel: face_rows(rel, fa[sel])  # noqa: E731
                shared.occupancy.add(bounds, corners, keep=reach)
            del bounds, reach
        del rel
    info.update(
        loaded=int(keep.sum()),
        beyond_range=int((~near).sum()),
        outside_fov=int((near & ~keep).sum()),
    )
    return (None if keep.all() else keep), info


def _grid_plan(
    caster: Caster,
    grid: PulseGrid,
    o: np.ndarray,
    rot: np.ndarray,
    spec: ScannerSpec,
    culled: bool,
    adaptive: bool,
    radius_m: float,
    shared: _Shared | None = None,
) -> tuple[Any, np.ndarray | None]:
    """The pulses one station casts from its ``grid`` (the whole field of view or the
    scene's window): with ``culled``, the window's cells some triangle can reach. Returns
    them and, with ``adaptive`` beam sampling, the thin-geometry mask (else None)."""
    if grid.n_pulses == 0 or not (culled or adaptive):
        return grid, None
    abs_err = float32_error_m(radius_m, o)
    cast = grid
    if culled and shared is not None and shared.cast is not None:
        cast = shared.cast  # fed while the triangles to load were chosen
    elif culled:
        rel = (caster.v - o) @ rot  # the vertices in the scanner frame
        a_ref = _azimuth_ref(spec, grid)
        cast = occupancy_grid(rel, caster.faces, spec, grid, a_ref, abs_error_m=abs_err)
    thin = None
    if adaptive:
        # the thin-geometry mask takes the triangles all at once (72 bytes each), made
        # after the occupancy grid, which gathers them a chunk at a time
        rel = (caster.v - o) @ rot
        thin = thin_mask(
            rel[caster.faces],
            spec,
            cast,
            abs_error_m=abs_err,
            thickness_m=caster.thickness_m(),
            max_pulses=2 * cast.n_pulses,
        )
    return cast, thin
