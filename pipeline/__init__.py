"""treesim's library: reconstruct trees, scan them virtually, compare the clouds.

The facade: read and write clouds (``read_cloud``, ``write_cloud``), ``reconstruct`` a
tree mesh, ``scan`` it with the virtual scanner, ``compare`` clouds with meshes or clouds,
``build_report``, and the whole loop for one tree (``run_tree``) or many (``run_batch``),
or a grid of settings on trees, timed and scored (``run_sweep``).
"""

from __future__ import annotations

from ._version import __version__
from .batch import BatchResult, run_batch
from .cloud import LABEL_CODES, Cloud
from .compare import compare
from .errors import TreesimError
from .frame import LocalFrame
from .io import load_scene, read_cloud, write_cloud
from .params import (
    CompareParams,
    ReconstructParams,
    RunParams,
    ScannerSpec,
    ScanParams,
    load_config,
    run_preset,
)
from .reconstruct import reconstruct
from .report import build_report
from .run import RunResult, run_tree
from .scan import Station, ring_layout, scan
from .scene import Scene
from .sweep import SweepResult, run_sweep

__all__ = [
    "LABEL_CODES",
    "BatchResult",
    "Cloud",
    "CompareParams",
    "LocalFrame",
    "ReconstructParams",
    "RunParams",
    "RunResult",
    "ScanParams",
    "ScannerSpec",
    "Scene",
    "Station",
    "SweepResult",
    "TreesimError",
    "__version__",
    "build_report",
    "compare",
    "load_config",
    "load_scene",
    "read_cloud",
    "reconstruct",
    "ring_layout",
    "run_batch",
    "run_preset",
    "run_sweep",
    "run_tree",
    "scan",
    "write_cloud",
]
