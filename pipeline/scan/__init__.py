"""The virtual terrestrial laser scanner.

``Scene``, ``MeshPart``, ``label_from_name`` (:mod:`pipeline.scene`) and ``load_mesh``,
``load_scene`` (:mod:`pipeline.io.mesh`) are re-exported for convenience: what the
scanner scans, and how it is read.
"""

from ..io.mesh import load_mesh, load_scene
from ..scene import MeshPart, Scene, label_from_name
from .scanner import (
    PRESETS,
    RETURN_MODES,
    InstrumentPreset,
    ScannerSpec,
    Station,
    preset,
    ring_around,
    ring_layout,
)
from .trace import ScanResult, StationStats, scan

__all__ = [
    "PRESETS",
    "RETURN_MODES",
    "InstrumentPreset",
    "MeshPart",
    "ScanResult",
    "ScannerSpec",
    "Scene",
    "Station",
    "StationStats",
    "label_from_name",
    "load_mesh",
    "load_scene",
    "preset",
    "ring_around",
    "ring_layout",
    "scan",
]
