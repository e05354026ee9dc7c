"""The virtual terrestrial laser scanner.

``scan(scene, stations, spec)`` casts each station's rays at a :class:`~treesim.scene.Scene`
and returns the simulated cloud; :func:`estimate_scan` says beforehand what it will cost
(rays, points, file size, time: :mod:`treesim.scan.estimate`); :func:`stations_for`
places stations by the station rule.
The scanner's settings (:class:`~treesim.params.ScannerSpec`) and instruments live in the
parameter model, :mod:`treesim.params`. ``Scene``, ``MeshPart``, ``label_from_name``
(:mod:`treesim.scene`) and ``load_mesh``, ``load_scene`` (:mod:`treesim.io.mesh`) are
re-exported for convenience: what the scanner scans, and how it is read.
"""

from ..io.mesh import load_mesh, load_scene
from ..params import INSTRUMENTS, RETURN_MODES, InstrumentPreset, ScannerSpec, instrument
from ..scene import MeshPart, Scene, label_from_name
from .estimate import ScanEstimate, estimate_scan
from .result import SCAN_FIELDS, ScanResult, StationStats, scan_fields, scan_metadata
from .stations import Station, ring_around, ring_layout, station_distance_m, stations_for
from .trace import scan

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
    "ring_layout",
    "scan",
    "scan_fields",
    "scan_metadata",
    "station_distance_m",
    "stations_for",
]
