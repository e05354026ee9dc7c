"""treesim's library: reconstruct trees, scan them virtually, compare the clouds.

The facade grows with the project; today it holds reading and writing clouds, the
scanner and the tree-model (cylinder table) tools.
"""

from __future__ import annotations

__version__ = "0.1.0"

from .cloud import LABEL_CODES, Cloud  # noqa: E402
from .errors import TreesimError  # noqa: E402
from .frame import LocalFrame  # noqa: E402
from .io import read_cloud, write_cloud  # noqa: E402
from .scan import ScannerSpec, Station, load_scene, ring_layout, scan  # noqa: E402

__all__ = [
    "LABEL_CODES",
    "Cloud",
    "LocalFrame",
    "ScannerSpec",
    "Station",
    "TreesimError",
    "__version__",
    "load_scene",
    "read_cloud",
    "ring_layout",
    "scan",
    "write_cloud",
]
