"""What a scan gives back: the cloud's fields, the per-station figures, the result.

:class:`ScanResult` holds the simulated cloud and how it was made (:class:`StationStats`
per station; :func:`lod_summary`, the account of which models ran, where and why, in
``ScanResult.lod``). :data:`SCAN_FIELDS` and :func:`scan_fields` name the per-point
fields (what a streaming writer declares before the points), :func:`scan_metadata` the
cloud's metadata.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cloud import LABEL_NAMES, Cloud
from ..frame import LocalFrame
from ..params import ScannerSpec
from ..scene import Scene
from .stations import Station
from .timing import TIME_CONVENTION, TIME_FIELD, timing_summary


@dataclass
class StationStats:
    """What one station cast and recorded."""

    index: int
    position_m: tuple[float, float, float]
    pulses_full_fov: int
    pulses_window: int
    pulses_cast: int
    rays_cast: int
    points: int
    azimuth_window_deg: tuple[float, float] | None
    elevation_window_deg: tuple[float, float]
    time_s: float
    #: pulses given sub-rays (beam model), and why (adaptive sampling)
    pulses_subrays: int = 0
    subray_reasons: dict[str, int] | None = None
    #: how long the station's scan takes in the field: the scanner's mechanics
    #: (:func:`treesim.scan.timing.station_duration_s`), not the points' times
    scan_duration_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "position_m": list(self.position_m),
            "pulses_full_fov": self.pulses_full_fov,
            "pulses_window": self.pulses_window,
            "pulses_cast": self.pulses_cast,
            "rays_cast": self.rays_cast,
            "points": self.points,
            "azimuth_window_deg": list(self.azimuth_window_deg)
            if self.azimuth_window_deg
            else None,
            "elevation_window_deg": list(self.elevation_window_deg),
            "time_s": self.time_s,
            "scan_duration_s": self.scan_duration_s,
            "pulses_subrays": self.pulses_subrays,
            **({"subray_reasons": dict(self.subray_reasons)} if self.subray_reasons else {}),
        }


@dataclass
class ScanResult:
    """A simulated cloud and how it was made.

    ``cloud.fields`` holds, per point: ``station`` (uint16), ``range_m`` (float64),
    ``incidence_deg`` (float32), ``label`` (uint8, see ``cloud.metadata['label_names']``),
    ``return_number``, ``number_of_returns`` (uint8), ``intensity`` (uint16),
    ``scan_line`` (elevation step index, int32), ``scan_column`` (azimuth step index,
    int32) and ``time_s`` (float64, seconds since the station's scan started, from the
    scanner's mechanics: :mod:`treesim.scan.timing`); and ``tree_id`` (uint32) when the
    scene's parts carry tree ids (a plot).
    """

    cloud: Cloud
    spec: ScannerSpec
    stations: list[Station]
    station_stats: list[StationStats]
    frame: LocalFrame
    bvh_build_s: float
    total_s: float
    window: bool
    cull: bool = False
    points_written: int = 0
    lod: dict[str, Any] = field(default_factory=dict)
    models: list[str] = field(default_factory=list)
    #: one-line sentences: the scan ran, but maybe not as meant (:mod:`treesim.scan.checks`)
    warnings: list[str] = field(default_factory=list)
    #: a windy scan's account: the sway model, the tree's figures, each station's time
    #: slices (:func:`treesim.scan.wind.wind_summary`); None for a still scan
    wind: dict[str, Any] | None = None

    @property
    def n_points(self) -> int:
        """Points made: in ``cloud``, or handed to the sink."""
        return len(self.cloud) + self.points_written

    @property
    def rays_cast(self) -> int:
        return sum(s.rays_cast for s in self.station_stats)

    @property
    def rays_full_fov(self) -> int:
        return sum(s.pulses_full_fov for s in self.station_stats) * self.spec.rays_per_pulse

    def summary(self) -> dict[str, Any]:
        return {
            "points": self.n_points,
            "rays_cast": self.rays_cast,
            "rays_full_fov": self.rays_full_fov,
            "pulses_window": sum(s.pulses_window for s in self.station_stats),
            "pulses_cast": sum(s.pulses_cast for s in self.station_stats),
            "window": self.window,
            "cull": self.cull,
            "lod": self.lod,
            "bvh_build_s": self.bvh_build_s,
            "total_s": self.total_s,
            "models_active": self.models,
            "warnings": list(self.warnings),
            "frame_origin_m": list(self.frame.origin),
            "scanner": self.spec.to_dict(),
            "timing": timing_summary(self.spec),
            "stations": [s.to_dict() for s in self.station_stats],
            **({"wind": self.wind} if self.wind is not None else {}),
        }


def scan_metadata(stations: Sequence[Station]) -> dict[str, Any]:
    """The metadata of a simulated cloud (what a writer records before the points)."""
    return {
        "label_names": dict(LABEL_NAMES),
        "source": "treesim scan",
        "stations": [st.to_dict() for st in stations],
        "time": TIME_CONVENTION,
    }


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
    TIME_FIELD: np.float64,
}
#: The fields of a simulated cloud and their types (what a streaming writer declares);
#: a scene whose parts carry tree ids adds ``tree_id`` (see :func:`scan_fields`).
SCAN_FIELDS: dict[str, np.dtype] = {k: np.dtype(v) for k, v in _FIELDS.items()}


#: The field a scan of a plot adds (see :func:`scan_fields`).
TREE_ID_FIELD: dict[str, np.dtype] = {"tree_id": np.dtype(np.uint32)}


#: The field a windy scan adds (see :func:`scan_fields`): the hit part's displacement
#: from its rest pose, float64 metres (:mod:`treesim.scan.wind`).
WIND_FIELDS: dict[str, np.dtype] = {"wind_displacement_m": np.dtype(np.float64)}


def scan_fields(scene: Scene, spec: ScannerSpec | None = None) -> dict[str, np.dtype]:
    """The per-point fields a scan of ``scene`` makes: :data:`SCAN_FIELDS`, plus
    ``tree_id`` (uint32; 0 where the hit part belongs to no tree) when any part of the
    scene carries a tree id (a plot), plus ``wind_displacement_m`` (float64) when
    ``spec`` blows a wind (``wind_speed_m_s > 0``; a sink opened with these fields is
    handed them when :func:`~treesim.scan.scan` is told so, ``sink_fields``)."""
    out = dict(SCAN_FIELDS) if scene.face_tree is None else {**SCAN_FIELDS, **TREE_ID_FIELD}
    if spec is not None and spec.wind_speed_m_s > 0:
        out.update(WIND_FIELDS)
    return out


def lod_summary(
    lod: str,
    spec: ScannerSpec,
    stats: list[StationStats],
    geometry: dict[str, Any],
    culled: bool,
    adaptive: bool,
    edge: bool = False,
) -> dict[str, Any]:
    """JSON-ready account of which models ran, where, and why (``adaptive``, ``edge``:
    the beam sampling the plan chose, :class:`~treesim.scan.planning.Plan`)."""
    window = sum(s.pulses_window for s in stats)
    cast = sum(s.pulses_cast for s in stats)
    out: dict[str, Any] = {"mode": lod}
    why = (
        f"cast only the cells of each station's window that some triangle can reach: "
        f"{cast:,} of {window:,} pulses"
        if culled
        else "cast the whole window rectangle"
    )
    if sum(s.points for s in stats) == 0:  # an empty scan: say why in plain words
        if geometry["loaded"] == 0:
            why = "nothing cast: no station can record any triangle (see geometry)"
        elif window == 0:
            why = "nothing cast: the scene is outside every station's field of view"
        elif cast == 0:
            why = (
                f"none of the {window:,} pulses of the stations' windows can reach a "
                f"triangle at {spec.horizontal_resolution_deg:g}°×"
                f"{spec.vertical_resolution_deg:g}° steps: the scene lies between the "
                "pulses; use a finer resolution"
            )
        else:
            why += (
                f"; none recorded an echo between {spec.min_range_m:g} and {spec.max_range_m:g} m"
            )
    out["rays"] = {"pulses_window": window, "pulses_cast": cast, "why": why}
    left = geometry["triangles"] - geometry["loaded"]
    out["geometry"] = {
        **geometry,
        "why": (
            f"{left:,} of {geometry['triangles']:,} triangles not loaded: "
            f"{geometry['beyond_range']:,} beyond {spec.max_range_m:g} m from every station, "
            f"{geometry['outside_fov']:,} outside every field of view"
            if left
            else "every triangle can be recorded by some station: all loaded"
        ),
    }
    if spec.beam_model:
        pulses = cast
        sub = sum(s.pulses_subrays for s in stats)
        reasons: dict[str, int] = {}
        for s in stats:
            for key, value in (s.subray_reasons or {}).items():
                reasons[key] = reasons.get(key, 0) + value
        step = math.radians(min(spec.horizontal_resolution_deg, spec.vertical_resolution_deg))
        ratio = spec.beam_divergence_mrad * 1e-3 / step
        out["beam"] = {
            "sampling": "adaptive" if adaptive else ("edge" if edge else "full"),
            "pulses_cast": pulses,
            "pulses_subrays": sub,
            "reasons": reasons,
            "footprint_over_spacing": ratio,
            "why": (
                f"{spec.subrays} sub-rays for {sub:,} of {pulses:,} pulses whose footprint "
                f"can straddle an edge, another surface or geometry thinner than the point "
                f"spacing (the footprint is {ratio:.2f}× the spacing at any range); the "
                "others keep their central ray"
                if adaptive
                else (
                    f"the edge model: a pulse's footprint shared out over the surfaces its "
                    f"neighbours' central rays meet; {spec.subrays} sub-rays for the {sub:,} "
                    f"of {pulses:,} pulses it could not resolve"
                )
                if edge
                else f"{spec.subrays} sub-rays for every pulse"
                + (" (lod full)" if lod == "full" else " (beam_sampling full)")
            ),
        }
    return out
