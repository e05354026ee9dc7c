"""Casting: stations × windowed pulse grids → Open3D ``RaycastingScene`` → float64 hits.

Precision: the scene is shifted into a :class:`~pipeline.frame.LocalFrame` (float64)
before Open3D (float32) sees it; each ray starts just before the scene's bounding box
(moved forward in float64), so float32 never holds a long range; every hit is then
recomputed in float64 as the intersection of the ray with the hit triangle's plane.
Points leave in the input's coordinates as float64.

Memory: pulses are cast in chunks of at most ``chunk_rays`` rays, so peak memory is
bounded (about 200 bytes per ray in flight) whatever the resolution.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._system import cpu_count
from ..cloud import LABEL_CODES, LABEL_NAMES, Cloud
from ..errors import InvalidParameterError, ResourceLimitError, ScanError
from ..frame import LocalFrame
from ..params import ScannerSpec
from ..scene import Scene
from . import beam as beam_model
from .rays import (
    PulseGrid,
    box_window,
    column_azimuth_rad,
    directions,
    full_grid,
    hashed_normal,
    line_elevation_rad,
    pulse_angles,
    windowed_grid,
)
from .stations import Station

Progress = Callable[[float, str], None]

#: Rays Open3D casts per second per core on this kind of machine (measured, hits and
#: misses mixed); used only for the estimate printed when a scan is refused.
_EST_RAYS_PER_S = 2.0e6
#: Bytes per ray in flight (Open3D's ≈57 B plus treesim's float64 bookkeeping).
BYTES_PER_RAY = 200


@dataclass
class StationStats:
    """What one station cast and recorded."""

    index: int
    position_m: tuple[float, float, float]
    pulses_full_fov: int
    pulses_cast: int
    rays_cast: int
    points: int
    azimuth_window_deg: tuple[float, float] | None
    elevation_window_deg: tuple[float, float]
    time_s: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "position_m": list(self.position_m),
            "pulses_full_fov": self.pulses_full_fov,
            "pulses_cast": self.pulses_cast,
            "rays_cast": self.rays_cast,
            "points": self.points,
            "azimuth_window_deg": list(self.azimuth_window_deg)
            if self.azimuth_window_deg
            else None,
            "elevation_window_deg": list(self.elevation_window_deg),
            "time_s": self.time_s,
        }


@dataclass
class ScanResult:
    """A simulated cloud and how it was made.

    ``cloud.fields`` holds, per point: ``station`` (uint16), ``range_m`` (float64),
    ``incidence_deg`` (float32), ``label`` (uint8, see ``cloud.metadata['label_names']``),
    ``return_number``, ``number_of_returns`` (uint8), ``intensity`` (uint16),
    ``scan_line`` (elevation step index, int32) and ``scan_column`` (azimuth step index,
    int32).
    """

    cloud: Cloud
    spec: ScannerSpec
    stations: list[Station]
    station_stats: list[StationStats]
    frame: LocalFrame
    bvh_build_s: float
    total_s: float
    window: bool
    models: list[str] = field(default_factory=list)

    @property
    def rays_cast(self) -> int:
        return sum(s.rays_cast for s in self.station_stats)

    @property
    def rays_full_fov(self) -> int:
        return sum(s.pulses_full_fov for s in self.station_stats) * self.spec.rays_per_pulse

    def summary(self) -> dict[str, Any]:
        return {
            "points": len(self.cloud),
            "rays_cast": self.rays_cast,
            "rays_full_fov": self.rays_full_fov,
            "window": self.window,
            "bvh_build_s": self.bvh_build_s,
            "total_s": self.total_s,
            "models_active": self.models,
            "frame_origin_m": list(self.frame.origin),
            "scanner": self.spec.to_dict(),
            "stations": [s.to_dict() for s in self.station_stats],
        }


def _grid_for(
    verts_local: np.ndarray, o: np.ndarray, rot: np.ndarray, spec: ScannerSpec, window: bool
) -> tuple[PulseGrid, Any]:
    rel = (verts_local - o) @ rot  # scanner frame
    win = box_window(rel.min(axis=0), rel.max(axis=0))
    grid = windowed_grid(spec, win) if window else full_grid(spec)
    return grid, win


class _Caster:
    """The Open3D scene plus float64 triangle data for refinement."""

    def __init__(self, scene: Scene, frame: LocalFrame, nthreads: int) -> None:
        import open3d as o3d

        self.o3d = o3d
        self.nthreads = int(nthreads)
        v = frame.to_local(scene.vertices)
        f = scene.faces
        self.v0 = v[f[:, 0]]
        n = np.cross(v[f[:, 1]] - self.v0, v[f[:, 2]] - self.v0)
        self.normal = n / np.linalg.norm(n, axis=1, keepdims=True)
        self.label = scene.face_label
        self.lo, self.hi = frame.to_local(scene.bounds)
        diag = float(np.linalg.norm(self.hi - self.lo))
        self.pad = 1e-3 + 1e-5 * diag
        self.rc = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        self.rc.add_triangles(
            o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32))
        )
        t0 = time.perf_counter()
        # Open3D builds its BVH lazily on the first query: build it now, timed apart.
        self.cast(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
        self.build_s = time.perf_counter() - t0

    #: Stations nearer the scene's bounds than this cast from their own position;
    #: farther ones start every ray this close to the bounds (float32 keeps ~1e-7 of
    #: the ray's length, so 50 m costs at most ~3 µm before the float64 refinement).
    NEAR_M = 50.0

    def entry_distance(self, o: np.ndarray) -> float:
        """How far every ray from ``o`` can start without skipping any surface: the
        distance from ``o`` to the scene's (padded) bounding box, minus the pad, or 0
        when that is under ``NEAR_M``."""
        gap = np.maximum(np.maximum(self.lo - self.pad - o, o - self.hi - self.pad), 0.0)
        t0 = float(np.linalg.norm(gap)) - self.pad
        return t0 if t0 > self.NEAR_M else 0.0

    def cast_f32(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cast (n, 6) float32 rays (origin, unit direction); returns Open3D's
        ``t_hit`` (float32, inf on a miss) and primitive ids (uint32)."""
        o3c = self.o3d.core
        ans = self.rc.cast_rays(o3c.Tensor.from_numpy(rays), nthreads=self.nthreads)
        return ans["t_hit"].numpy(), ans["primitive_ids"].numpy()

    def refine(
        self, o: np.ndarray, d: np.ndarray, t_coarse: np.ndarray, pid: np.ndarray
    ) -> np.ndarray:
        """Float64 ranges: intersect each ray (``o`` + t ``d``, float64) with the plane of
        its hit triangle; keeps the float32 range where the two disagree (grazing)."""
        nrm = self.normal[pid]
        denom = np.einsum("ij,ij->i", d, nrm)
        num = np.einsum("ij,ij->i", self.v0[pid] - o, nrm)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_fine = num / denom
        ok = (np.abs(denom) > 1e-9) & (np.abs(t_fine - t_coarse) < 1e-3 + 1e-5 * t_coarse)
        return np.where(ok, t_fine, t_coarse)

    def cast(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cast rays from the point ``o`` (3,) along unit ``d`` (n, 3), float64 in and
        out: returns (t, primitive) with t = inf and primitive = -1 on a miss."""
        n = len(d)
        t0 = self.entry_distance(o)
        rays = np.empty((n, 6), dtype=np.float32)
        rays[:, :3] = o + t0 * d
        rays[:, 3:] = d
        th, pr = self.cast_f32(rays)
        t_out = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        hidx = np.flatnonzero(np.isfinite(th))
        if len(hidx):
            pid = pr[hidx].astype(np.int64)
            t_coarse = t0 + th[hidx].astype(np.float64)
            t_out[hidx] = self.refine(o, d[hidx], t_coarse, pid)
            prim[hidx] = pid
        return t_out, prim


def _check_inside(caster: _Caster, o: np.ndarray, k: int, st: Station) -> None:
    g = np.array(
        [
            [x, y, z]
            for x in (-1, 0, 1)
            for y in (-1, 0, 1)
            for z in (-1, 0, 1)
            if (x, y, z) != (0, 0, 0)
        ],
        dtype=np.float64,
    )
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    t, prim = caster.cast(o, g)
    hit = prim >= 0
    if hit.sum() < 0.9 * len(g):
        return
    back = np.einsum("ij,ij->i", g[hit], caster.normal[prim[hit]]) > 0
    if back.mean() >= 0.9:
        label = LABEL_NAMES[int(np.bincount(caster.label[prim[hit]]).argmax())]
        raise ScanError(
            f"station {k} at {tuple(round(c, 3) for c in st.position_m)} is inside the "
            f"{label} geometry (nearest surface {t[hit].min():.3f} m away in every "
            "direction); move it outside the mesh"
        )


def scan(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec | None = None,
    *,
    window: bool = True,
    chunk_rays: int = 1 << 19,
    max_rays: int = 1_000_000_000,
    nthreads: int = 0,
    check_inside: bool = True,
    progress: Progress | None = None,
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

    Returns
    -------
    ScanResult
        ``result.cloud`` in the scene's coordinates (float64), with per-point fields.
    """
    spec = spec or ScannerSpec()
    stations = list(stations)
    if not stations:
        raise InvalidParameterError("give at least one station")
    if int(chunk_rays) < 1:
        raise InvalidParameterError(f"chunk_rays must be >= 1, got {chunk_rays}")
    t_all = time.perf_counter()
    frame = LocalFrame.around(scene.used_vertices)
    verts_used = frame.to_local(scene.used_vertices)
    s = spec.rays_per_pulse
    plans = []
    for st in stations:
        o = frame.to_local(st.position)
        rot = st.rotation
        grid, win = _grid_for(verts_used, o, rot, spec, window)
        plans.append((o, rot, grid, win))
    total_rays = sum(p[2].n_pulses for p in plans) * s
    if total_rays > max_rays:
        secs = total_rays / (_EST_RAYS_PER_S * max(1, nthreads or cpu_count()))
        raise ResourceLimitError(
            f"this scan needs {total_rays:.3g} rays ({len(stations)} station"
            f"{'s' if len(stations) > 1 else ''} at "
            f"{spec.horizontal_resolution_deg}°×{spec.vertical_resolution_deg}°"
            f"{f', {s} sub-rays per pulse' if s > 1 else ''}), about "
            f"{_human_time(secs)} here, over the limit of {max_rays:.3g}; coarsen the "
            "resolution or raise max_rays (--max-rays); memory stays bounded either way"
        )
    caster = _Caster(scene, frame, nthreads)
    if check_inside:
        for k, (o, _, _, _) in enumerate(plans):
            _check_inside(caster, o, k, stations[k])
    offsets, weights = (
        beam_model.subray_pattern(s, spec.beam_divergence_mrad) if s > 1 else (None, None)
    )
    reflect = np.zeros(len(LABEL_CODES))
    for name, code in LABEL_CODES.items():
        reflect[code] = spec.reflectance.get(name, spec.reflectance.get("other", 0.5))
    out: dict[str, list[np.ndarray]] = {k: [] for k in _FIELDS}
    pts: list[np.ndarray] = []
    stats: list[StationStats] = []
    done_rays = 0
    per_chunk = max(1, int(chunk_rays) // s)
    for k, (o, rot, grid, win) in enumerate(plans):
        t_st = time.perf_counter()
        n_points = 0
        fast = s == 1 and spec.angular_jitter_sd_deg == 0
        t0 = caster.entry_distance(o)
        station = stations[k]
        level = station.pitch_deg == 0 and station.roll_deg == 0
        for a in range(0, grid.n_pulses, per_chunk):
            b = min(grid.n_pulses, a + per_chunk)
            if fast:
                t, prim, lines_r, cols_r, d_r = _fast_block(
                    caster, spec, grid, a, b, o, t0, rot, station.heading_deg, level
                )
                rec = _single_returns(spec, t, prim)
            else:
                lines, cols = grid.indices(a, b)
                az, el = pulse_angles(spec, k, lines, cols)
                d = directions(az, el) @ rot.T
                if s == 1:
                    t, prim = caster.cast(o, d)
                    rec = _single_returns(spec, t, prim)
                else:
                    sd = beam_model.subray_directions(d, offsets).reshape(-1, 3)
                    t, prim = caster.cast(o, sd)
                    rec = _beam_returns(spec, t.reshape(-1, s), prim.reshape(-1, s), sd, weights)
                lines_r, cols_r, d_r = lines, cols, d
            n_rec = len(rec["pulse"])
            if n_rec:
                pi = rec["pulse"]
                rng = rec["range_m"]
                if spec.range_noise_sd_m > 0:
                    # independent draws per pulse and per return
                    rng = rng + spec.range_noise_sd_m * hashed_normal(
                        spec.seed, 1, k, lines_r[pi], cols_r[pi], sub=rec["return_number"]
                    )
                ray_d = rec["direction"] if rec["direction"] is not None else d_r[pi]
                p_local = o + rng[:, None] * d_r[pi]
                pts.append(p_local)
                prim = rec["primitive"]
                lab = caster.label[prim]
                cosi = np.abs(np.einsum("ij,ij->i", ray_d, caster.normal[prim]))
                inc = np.degrees(np.arccos(np.clip(cosi, 0.0, 1.0)))
                ref10 = np.minimum(1.0, (10.0 / np.maximum(rng, 1e-9)) ** 2)
                inten = np.clip(reflect[lab] * cosi * rec["energy"] * ref10, 0.0, 1.0)
                out["station"].append(np.full(n_rec, k, dtype=np.uint16))
                out["range_m"].append(rng.astype(np.float64))
                out["incidence_deg"].append(inc.astype(np.float32))
                out["label"].append(lab.astype(np.uint8))
                out["return_number"].append(rec["return_number"].astype(np.uint8))
                out["number_of_returns"].append(rec["number_of_returns"].astype(np.uint8))
                out["intensity"].append(np.round(inten * 65535).astype(np.uint16))
                out["scan_line"].append(lines_r[pi].astype(np.int32))
                out["scan_column"].append(cols_r[pi].astype(np.int32))
                n_points += n_rec
            done_rays += (b - a) * s
            if progress is not None:
                progress(done_rays / max(total_rays, 1), f"station {k + 1}/{len(stations)}")
        full = spec.n_azimuth * spec.n_elevation
        stats.append(
            StationStats(
                index=k,
                position_m=stations[k].position_m,
                pulses_full_fov=full,
                pulses_cast=grid.n_pulses,
                rays_cast=grid.n_pulses * s,
                points=n_points,
                azimuth_window_deg=win.azimuth_deg,
                elevation_window_deg=win.elevation_deg,
                time_s=time.perf_counter() - t_st,
            )
        )
    if pts:
        points = frame.to_global(np.concatenate(pts))
        fields = {k: np.concatenate(v) for k, v in out.items()}
    else:
        points = np.empty((0, 3))
        fields = {k: np.empty(0, dtype=_FIELDS[k]) for k in _FIELDS}
    cloud = Cloud(
        points,
        fields,
        {
            "label_names": dict(LABEL_NAMES),
            "source": "treesim scan",
            "stations": [st.to_dict() for st in stations],
        },
    )
    return ScanResult(
        cloud=cloud,
        spec=spec,
        stations=stations,
        station_stats=stats,
        frame=frame,
        bvh_build_s=caster.build_s,
        total_s=time.perf_counter() - t_all,
        window=window,
        models=spec.active_models(),
    )


_FIELDS: dict[str, Any] = {
    "station": np.uint16,
    "range_m": np.float64,
    "incidence_deg": np.float32,
    "label": np.uint8,
    "return_number": np.uint8,
    "number_of_returns": np.uint8,
    "intensity": np.uint16,
    "scan_line": np.int32,
    "scan_column": np.int32,
}


def _fast_block(
    caster: _Caster,
    spec: ScannerSpec,
    grid: PulseGrid,
    a: int,
    b: int,
    o: np.ndarray,
    t0: float,
    rot: np.ndarray,
    heading_deg: float,
    level: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cast pulses ``a:b`` of a grid with no per-pulse randomness.

    The grid is separable (azimuth × elevation), so float32 rays are built by
    broadcasting column and line terms, and the float64 work (directions, refinement)
    is done for the hits only. Returns (t, primitive, line, column, direction) of hits.
    """
    nl = len(grid.lines)
    ca, cb = a // nl, (b - 1) // nl + 1
    off = a - ca * nl
    hdeg = heading_deg if level else 0.0
    az = column_azimuth_rad(spec, grid.columns[ca:cb], hdeg)
    el = line_elevation_rad(spec, grid.lines)
    ce, se = np.cos(el).astype(np.float32), np.sin(el).astype(np.float32)
    cz, sz = np.cos(az).astype(np.float32), np.sin(az).astype(np.float32)
    rays = np.empty((cb - ca, nl, 6), dtype=np.float32)
    np.multiply(cz[:, None], ce[None, :], out=rays[:, :, 3])
    np.multiply(sz[:, None], ce[None, :], out=rays[:, :, 4])
    rays[:, :, 5] = se[None, :]
    if not level:
        rays[:, :, 3:] = rays[:, :, 3:] @ rot.T.astype(np.float32)
    if t0 > 0:
        np.multiply(rays[:, :, 3:], np.float32(t0), out=rays[:, :, :3])
        rays[:, :, :3] += o.astype(np.float32)
    else:
        rays[:, :, :3] = o.astype(np.float32)
    rays = rays.reshape(-1, 6)[off : off + (b - a)]
    th, pr = caster.cast_f32(np.ascontiguousarray(rays))
    hidx = np.flatnonzero(np.isfinite(th))
    f = hidx + off
    lines = grid.lines[f % nl]
    cols = grid.columns[ca + f // nl]
    az_h = column_azimuth_rad(spec, cols, hdeg)
    el_h = line_elevation_rad(spec, lines)
    d = directions(az_h, el_h)
    if not level:
        d = d @ rot.T
    pid = pr[hidx].astype(np.int64)
    t = caster.refine(o, d, t0 + th[hidx].astype(np.float64), pid)
    return t, pid, lines, cols, d


def _in_range(spec: ScannerSpec, t: np.ndarray) -> np.ndarray:
    return np.isfinite(t) & (t >= spec.min_range_m) & (t <= spec.max_range_m)


def _single_returns(spec: ScannerSpec, t: np.ndarray, prim: np.ndarray) -> dict[str, Any]:
    keep = _in_range(spec, t) & (prim >= 0)
    idx = np.flatnonzero(keep)
    one = np.ones(len(idx), dtype=np.int64)
    return {
        "pulse": idx,
        "range_m": t[idx],
        "primitive": prim[idx],
        "direction": None,  # the pulse direction
        "energy": np.ones(len(idx)),
        "return_number": one,
        "number_of_returns": one,
    }


def _beam_returns(
    spec: ScannerSpec, t: np.ndarray, prim: np.ndarray, sd: np.ndarray, weights: np.ndarray
) -> dict[str, Any]:
    p, s = t.shape
    t = np.where(_in_range(spec, t) & (prim >= 0), t, np.inf)
    g = beam_model.group_returns(t, weights, spec.range_resolution_m)
    keep = beam_model.select_returns(g, spec.return_mode)
    pulse = g["pulse"][keep]
    sub = g["subray"][keep]
    flat = pulse * s + sub
    return {
        "pulse": pulse,
        "range_m": g["range_m"][keep],
        "primitive": prim.reshape(-1)[flat],
        "direction": sd[flat],
        "energy": g["energy"][keep],
        "return_number": g["return_number"][keep],
        "number_of_returns": g["number_of_returns"][keep],
    }


def _human_time(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    if seconds < 172800:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


__all__ = ["scan", "ScanResult", "StationStats", "BYTES_PER_RAY"]
