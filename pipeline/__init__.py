"""treesim's library: reconstruct trees, scan them virtually, compare the clouds.

The facade: read and write clouds (``read_cloud``, ``write_cloud``), ``reconstruct`` a
tree mesh, ``scan`` it with the virtual scanner, ``compare`` clouds with meshes or clouds,
``build_report``, and the whole loop for one tree (``run_tree``) or many (``run_batch``).
"""

from __future__ import annotations

__version__ = "0.1.0"

from .batch import BatchResult, run_batch  # noqa: E402
from .cloud import LABEL_CODES, Cloud  # noqa: E402
from .compare import compare  # noqa: E402
from .errors import TreesimError  # noqa: E402
from .frame import LocalFrame  # noqa: E402
from .io import read_cloud, write_cloud  # noqa: E402
from .params import (  # noqa: E402
    CompareParams,
    ReconstructParams,
    RunParams,
    ScanParams,
    ScannerSpec,
    load_config,
    run_preset,
)
from .reconstruct import reconstruct  # noqa: E402
from .report import build_report  # noqa: E402
from .run import RunResult, run_tree  # noqa: E402
from .scan import Station, load_scene, ring_layout, scan  # noqa: E402

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
    "Station",
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
    "run_tree",
    "scan",
    "write_cloud",
]
