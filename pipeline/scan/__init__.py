"""The virtual terrestrial laser scanner."""

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
from .scene import MeshPart, Scene, label_from_name, load_mesh, load_scene
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
