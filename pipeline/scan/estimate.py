"""What a scan will cost, said before it runs: rays, points, file size and time.

:func:`estimate_scan` (and ``scan(..., estimate=callback)``, which calls back once before
casting) plan the scan as it will run (:func:`~treesim.scan.planning.plan_scan`: each
station's window, the cells some triangle can reach, the triangles loaded) and then
:func:`estimate_plan` casts a *sample* of the planned pulses (at most
:data:`SAMPLE_PULSES` and 1/32 of them, in blocks spread over every station's plan; cast
twice, the first warming Open3D's threads up) through the scan's own ray-casting scene,
refined as the scan refines them:

* **points** = the planned pulses × the sample's share of recorded hits;
* **rate** = the sample's rays per second: measured on this machine, for this scene,
  with the scan's thread count (nothing is cached: the sample costs ~10–50 ms, a few
  per cent of a small scan);
* **time** = the planning already done (windows, BVH, occupancy) + the planned rays at
  the sampled rate × :data:`OVERHEAD` (what a scan does per ray besides casting and
  refining: directions, fields, the writer) + the points × :data:`SECONDS_PER_POINT`;
* **file size** = the points × :data:`BYTES_PER_POINT` of the output's format.

With the beam model the rays are an upper bound (every pulse with all its sub-rays;
adaptive sampling gives sub-rays only to some) and so is the time. The estimate's
accuracy is tested (``tests/extremes/test_resolution.py``) within a factor of 1.5 for
points, 2 for the file's size and 4 for time on small scans, where fixed costs weigh
most.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from ..params import ScannerSpec
from ..scene import Scene
from .beam import in_range
from .caster import RayTables, cast_central
from .humanize import human_bytes, human_time
from .planning import Plan, plan_scan
from .stations import Station

__all__ = [
    "BYTES_PER_POINT",
    "OVERHEAD",
    "SAMPLE_PULSES",
    "SECONDS_PER_POINT",
    "ScanEstimate",
    "estimate_plan",
    "estimate_scan",
]

#: Pulses cast to sample a scan (spread over every station's plan in blocks).
SAMPLE_PULSES = 1 << 16
#: Bytes per point of a simulated cloud by output suffix (measured 2026-11-25 on scans of
#: the aspen and the coffee tree: LAZ 12.4–13.7, LAS 53.0, PLY 51.0, text 88–92; text
#: grows with the coordinates' digits, georeferenced ones included).
BYTES_PER_POINT: dict[str, float] = {
    ".laz": 14.0,
    ".las": 53.0,
    ".ply": 51.0,
    ".xyz": 100.0,
    ".txt": 100.0,
    ".csv": 100.0,
}
#: A scan's time per ray over the sample's (cast + refine) time per ray: grid
#: directions, range limits and the loop around them. The sample, cast twice (the first
#: warms Open3D's threads up), measured 2.3–2.8 M rays/s on the aspen at 0.01° against
#: 2.8 M rays/s for the whole scan's casts (2026-11-25, 2 cores).
OVERHEAD = 1.1
#: Time per recorded point besides casting: fields, intensity and the writer (LAZ on all
#: cores; measured 2026-11-25: ~0.3 µs on 2 cores).
SECONDS_PER_POINT = 0.4e-6


@dataclass(frozen=True)
class ScanEstimate:
    """A scan's size and time, before it runs.

    Attributes
    ----------
    stations : list of dict
        Per station: ``index``, ``position_m``, ``azimuth_window_deg`` (None: the whole
        turn), ``elevation_window_deg``, ``pulses_window`` and ``pulses_cast``.
    pulses_full_fov, pulses_window, pulses_cast : int
        Pulses of every field of view, of the windows, and planned (after culling).
    rays : int
        Rays to cast: ``pulses_cast`` × rays per pulse (an upper bound with an adaptive
        beam: ``rays_exact`` is False then).
    points : int
        Points expected (the sample's share of recorded hits × ``pulses_cast``).
    file_bytes : int
        Size of the output file, for ``suffix`` (a property: ``points`` ×
        :data:`BYTES_PER_POINT`).
    seconds : float
        Time of the whole scan (planning included).
    rate_rays_per_s : float
        The sample's measured rate (cast and refine; 0 when nothing was sampled).
    """

    stations: list[dict[str, Any]]
    pulses_full_fov: int
    pulses_window: int
    pulses_cast: int
    rays: int
    rays_exact: bool
    points: int
    hit_fraction: float
    sample_pulses: int
    rate_rays_per_s: float
    plan_s: float
    seconds: float
    suffix: str
    max_rays: int | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def over_limit(self) -> bool:
        """Whether the scan needs more rays than ``max_rays`` (it would be refused)."""
        return self.max_rays is not None and self.rays_upper > self.max_rays

    @property
    def rays_upper(self) -> int:
        """The rays the ``max_rays`` limit is checked on: every window pulse, every
        sub-ray (what a scan counts before culling)."""
        return int(self.pulses_window * (self.rays / max(self.pulses_cast, 1)))

    @property
    def file_bytes(self) -> int:
        """Size of the output file, for ``suffix`` (LAZ's for a suffix not listed)."""
        per_point = BYTES_PER_POINT.get(self.suffix.lower(), BYTES_PER_POINT[".laz"])
        return int(self.points * per_point)

    def for_suffix(self, suffix: str) -> ScanEstimate:
        """The same estimate with the file size of another output format."""
        return replace(self, suffix=suffix.lower())

    def line(self) -> str:
        """One line: rays, points, file size, time and the rate it was measured at."""
        rays = f"{self.rays:,} rays" if self.rays_exact else f"at most {self.rays:,} rays"
        rate = (
            f"{self.rate_rays_per_s / 1e6:.2g} M rays/s measured here"
            if self.rate_rays_per_s > 0
            else "nothing to sample"
        )
        return (
            f"{len(self.stations)} station{'s' if len(self.stations) != 1 else ''}, "
            f"{rays} ({self.pulses_cast:,} of {self.pulses_window:,} window pulses), "
            f"~{self.points:,} points, ~{human_bytes(self.file_bytes)} as {self.suffix}, "
            f"~{human_time(self.seconds)} ({rate})"
        )

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["file_bytes"] = self.file_bytes
        out["over_limit"] = self.over_limit
        return out


def estimate_scan(
    scene: Scene,
    stations: Sequence[Station],
    spec: ScannerSpec | None = None,
    *,
    window: bool = True,
    cull: bool = True,
    lod: str = "auto",
    nthreads: int = 0,
    max_rays: int | None = 1_000_000_000,
    suffix: str = ".laz",
) -> ScanEstimate:
    """What :func:`~treesim.scan.scan` with these settings would cast, record, write and
    take, without scanning: the scan is planned as it would run and a sample of its
    pulses is cast here (see the notes of this module). Nothing is written.

    Parameters
    ----------
    scene, stations, spec, window, cull, lod, nthreads
        As for :func:`~treesim.scan.scan`.
    max_rays : int, optional
        The limit :func:`~treesim.scan.scan` would apply; the estimate says whether it is exceeded
        (``over_limit``) instead of refusing.
    suffix : str
        The output's format, for the file size (``.laz``, ``.las``, ``.ply``, ``.xyz``).

    Returns
    -------
    ScanEstimate
    """
    plan = plan_scan(
        scene,
        stations,
        spec,
        window=window,
        cull=cull,
        lod=lod,
        nthreads=nthreads,
        max_rays=None,
        check_inside=False,
    )
    return estimate_plan(plan, suffix.lower(), max_rays)


def estimate_plan(plan: Plan, suffix: str, max_rays: int | None) -> ScanEstimate:
    """The size and time of a planned scan (:func:`~treesim.scan.planning.plan_scan`) from
    a sample of its planned pulses, cast and refined here (see the notes of this module);
    ``suffix``: the output's format, ``max_rays``: the limit to report."""
    spec, stations = plan.spec, plan.stations
    s = spec.rays_per_pulse
    total = plan.pulses_cast
    hits = sampled = 0
    secs = 0.0
    caster = plan.caster
    # at most 1/32 of the scan (cast twice: a few % of a small scan's time)
    budget = min(SAMPLE_PULSES, max(1024, total // 32))
    for sp in plan.plans:
        grid = sp.grid
        m = min(grid.n_pulses, round(budget * grid.n_pulses / max(total, 1)))
        if caster is None or m == 0:
            continue
        n_blocks = max(1, m // 256)
        size = m // n_blocks
        starts = np.arange(n_blocks) * (grid.n_pulses - size) // max(n_blocks - 1, 1)
        picked = [grid.indices(int(a), int(a) + size) for a in starts]
        lines = np.concatenate([p[0] for p in picked])
        cols = np.concatenate([p[1] for p in picked])
        tables = RayTables(spec, sp.station)
        if not sampled:  # warm up (threads, the neighbour table): the scan pays it once
            cast_central(caster, tables, lines, cols, sp.o, sp.t0)
        t_start = time.perf_counter()
        _, t, prim, _ = cast_central(caster, tables, lines, cols, sp.o, sp.t0)
        secs += time.perf_counter() - t_start
        hits += int((in_range(spec, t) & (prim >= 0)).sum())
        sampled += len(lines)
    rate = sampled / secs if secs > 0 else 0.0
    fraction = hits / sampled if sampled else 0.0
    points = int(round(fraction * total))
    rays = total * s
    seconds = plan.plan_s + (rays * OVERHEAD / rate if rate > 0 else 0.0)
    seconds += points * SECONDS_PER_POINT
    per_station = []
    for k, sp in enumerate(plan.plans):
        win = sp.window
        per_station.append(
            {
                "index": k,
                "position_m": list(sp.station.position_m),
                "azimuth_window_deg": list(win.azimuth_deg) if win.azimuth_deg else None,
                "elevation_window_deg": list(win.elevation_deg),
                "pulses_window": sp.n_window,
                "pulses_cast": sp.grid.n_pulses,
            }
        )
    notes = []
    if s > 1:
        notes.append(
            f"{s} sub-rays per pulse counted for every pulse"
            + (": adaptive sampling casts fewer" if plan.adaptive else "")
        )
    if spec.wind_speed_m_s > 0 and spec.wind_cylinders:
        # the slices are chosen from the sway model while casting; a still scan's rate
        # is what a sample can measure here
        notes.append(
            f"wind {spec.wind_speed_m_s:g} m/s: the time is a still scan's; a swaying tree "
            "is cast in time slices, each against its own scene, and takes several times "
            "longer (benchmarks/bench_wind.py measures the factor)"
        )
    return ScanEstimate(
        stations=per_station,
        pulses_full_fov=spec.n_azimuth * spec.n_elevation * len(stations),
        pulses_window=sum(p.n_window for p in plan.plans),
        pulses_cast=total,
        rays=rays,
        rays_exact=not plan.adaptive,
        points=points,
        hit_fraction=fraction,
        sample_pulses=sampled,
        rate_rays_per_s=rate,
        plan_s=plan.plan_s,
        seconds=seconds,
        suffix=suffix,
        max_rays=max_rays,
        notes=notes,
    )
