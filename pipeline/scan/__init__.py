"""The virtual terrestrial laser scanner.

``scan(scene, stations, spec)`` casts each station's rays at a :class:`~treesim.scene.Scene`
and returns the simulated cloud; :func:`estimate_scan` says beforehand what it will cost
(rays, points, file size, time: :mod:`treesim.scan.estimate`); :func:`stations_for`
places stations by the station rule; :func:`pulse_times_s` and :func:`station_duration_s`
say when each pulse leaves the scanner and how long a station's scan takes
(:mod:`treesim.scan.timing`).
The scanner's settings (:class:`~treesim.params.ScannerSpec`) and instruments live in the
parameter model, :mod:`treesim.params`. ``Scene``, ``MeshPart``, ``label_from_name``
(:mod:`treesim.scene`) and ``load_mesh``, ``load_scene`` (:mod:`treesim.io.mesh`) are
re-exported for convenience: what the scanner scans, and how it is read.
"""

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:  # for readers of the source (type checkers, the API reference)
    from ..io.mesh import load_mesh, load_scene
    from ..params import INSTRUMENTS, RETURN_MODES, InstrumentPreset, ScannerSpec, instrument
    from ..scene import MeshPart, Scene, label_from_name
    from .estimate import ScanEstimate, estimate_scan
    from .result import SCAN_FIELDS, ScanResult, StationStats, scan_fields, scan_metadata
    from .stations import Station, ring_around, ring_layout, station_distance_m, stations_for
    from .timing import pulse_times_s, station_duration_s
    from .trace import scan

#: Every name, imported on first use (PEP 562): a module that needs one part of the
#: scanner (the station layouts of a plan, a command's options) loads only that part.
_LAZY = {
    **dict.fromkeys(("load_mesh", "load_scene"), "..io.mesh"),
    **dict.fromkeys(
        ("INSTRUMENTS", "RETURN_MODES", "InstrumentPreset", "ScannerSpec", "instrument"),
        "..params",
    ),
    **dict.fromkeys(("MeshPart", "Scene", "label_from_name"), "..scene"),
    **dict.fromkeys(("ScanEstimate", "estimate_scan"), ".estimate"),
    **dict.fromkeys(
        ("SCAN_FIELDS", "ScanResult", "StationStats", "scan_fields", "scan_metadata"), ".result"
    ),
    **dict.fromkeys(
        ("Station", "ring_around", "ring_layout", "station_distance_m", "stations_for"),
        ".stations",
    ),
    "scan": ".trace",
    **dict.fromkeys(("pulse_times_s", "station_duration_s"), ".timing"),
}


__getattr__, __dir__ = lazy_names(__name__, _LAZY)


__all__ = [
    "INSTRUMENTS",
    "RETURN_MODES",
    "SCAN_FIELDS",
    "InstrumentPreset",
    "MeshPart",
    "ScanEstimate",
    "ScanResult",
    "ScannerSpec",
    "Scene",
    "Station",
    "StationStats",
    "instrument",
    "estimate_scan",
    "label_from_name",
    "load_mesh",
    "load_scene",
    "ring_around",
    "pulse_times_s",
    "ring_layout",
    "scan",
    "scan_fields",
    "scan_metadata",
    "station_distance_m",
    "station_duration_s",
    "stations_for",
]
