"""treesim's library: reconstruct trees, scan them virtually, compare the clouds.

The facade: read and write clouds (``read_cloud``, ``write_cloud``), ``reconstruct`` a
tree mesh, ``scan`` it with the virtual scanner, ``compare`` clouds with meshes or clouds,
``build_report``, and the whole loop for one tree (``run_tree``) or many (``run_batch``),
or a grid of settings on trees, timed and scored (``run_sweep``). Forest plots: a ``Plot``
of ``PlotTree`` on a ``Terrain``, read and written as files (``read_plot``,
``write_plot``) or generated as a stand (``generate_stand``), scanned station by station
(``scan_plot``) and measured per tree (``tree_figures``), or made from a field plot's
cloud as a digital twin (``plot_from_cloud``; many plots: ``plots_from_clouds``) and its
simulated scan checked against the field scan (``validate_scans`` with
``ValidateParams``); scan planning: where to stand and how often
(``plan_scans``, ``write_plan``).

Examples
--------
>>> import treesim as ts
>>> ts.run_preset("draft").scan.scanner.horizontal_resolution_deg > 0
True
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._lazy import keep_functions, mirror_submodules
from ._version import __version__
from .errors import TreesimError

if TYPE_CHECKING:  # for readers of the source (type checkers, the API reference)
    from .batch import BatchResult, run_batch
    from .cloud import LABEL_CODES, Cloud
    from .compare import compare
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
    from .plan import PlanParams, PlanResult, plan_scans
    from .plan.outputs import write_plan
    from .plot import Plot, PlotTree, Terrain
    from .plot.generate import StandParams, generate_stand
    from .plot.io import read_plot, write_plot
    from .plot.scan import PlotScanResult, scan_plot, tree_figures
    from .plot.validate import ValidateParams, ValidationResult, validate_scans
    from .reconstruct import reconstruct
    from .report import build_report
    from .run import RunResult, run_tree
    from .scan import Station, ring_layout, scan
    from .scene import Scene
    from .sweep import SweepResult, run_sweep
    from .twin import PlotsResult, TwinParams, TwinResult, plot_from_cloud, plots_from_clouds

#: Every name of the facade but the version and the base error, imported on first use
#: (PEP 562): every ``treesim`` command imports this package, and what a stage needs (numpy,
#: laspy, the stage's own modules, the TOML reader) should not slow down the others, nor
#: ``--help`` (tests/architecture/test_startup.py, tests/sweep/test_import.py).
_LAZY = {
    **dict.fromkeys(("BatchResult", "run_batch"), ".batch"),
    **dict.fromkeys(("LABEL_CODES", "Cloud"), ".cloud"),
    "compare": ".compare",
    "LocalFrame": ".frame",
    **dict.fromkeys(("load_scene", "read_cloud", "write_cloud"), ".io"),
    **dict.fromkeys(
        (
            "CompareParams",
            "ReconstructParams",
            "RunParams",
            "ScannerSpec",
            "ScanParams",
            "load_config",
            "run_preset",
        ),
        ".params",
    ),
    **dict.fromkeys(("PlanParams", "PlanResult", "plan_scans"), ".plan"),
    "write_plan": ".plan.outputs",
    **dict.fromkeys(("Plot", "PlotTree", "Terrain"), ".plot"),
    **dict.fromkeys(("StandParams", "generate_stand"), ".plot.generate"),
    **dict.fromkeys(("read_plot", "write_plot"), ".plot.io"),
    **dict.fromkeys(("PlotScanResult", "scan_plot", "tree_figures"), ".plot.scan"),
    **dict.fromkeys(("ValidateParams", "ValidationResult", "validate_scans"), ".plot.validate"),
    "reconstruct": ".reconstruct",
    "build_report": ".report",
    **dict.fromkeys(("RunResult", "run_tree"), ".run"),
    **dict.fromkeys(("Station", "ring_layout", "scan"), ".scan"),
    "Scene": ".scene",
    **dict.fromkeys(("SweepResult", "run_sweep"), ".sweep"),
    **dict.fromkeys(
        ("TwinParams", "TwinResult", "plot_from_cloud", "PlotsResult", "plots_from_clouds"),
        ".twin",
    ),
}

#: Subpackages that share their name with their verb: ``treesim.scan`` is the function
#: ``scan`` (as it was when the facade imported it eagerly), also after the subpackage
#: ``treesim.scan`` is loaded (the import system binds a loaded subpackage to its
#: parent's attribute of that name).
_VERBS = frozenset(("scan", "reconstruct", "compare"))


keep_functions(__name__, _VERBS)


def __getattr__(name: str) -> Any:
    """Import a name of the facade, or a subpackage, when it is first used (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        if name.startswith("__"):
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        try:  # ``treesim.io`` after a bare ``import treesim``, as when the facade was eager
            return importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # found directly from now on
    if name in _VERBS:  # `import treesim.scan.beam as beam` reads `beam` off the function
        mirror_submodules(__name__, name, value)
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "LABEL_CODES",
    "BatchResult",
    "Cloud",
    "CompareParams",
    "LocalFrame",
    "PlanParams",
    "PlanResult",
    "Plot",
    "PlotScanResult",
    "PlotTree",
    "PlotsResult",
    "ReconstructParams",
    "RunParams",
    "RunResult",
    "ScanParams",
    "ScannerSpec",
    "Scene",
    "StandParams",
    "Station",
    "SweepResult",
    "Terrain",
    "TreesimError",
    "TwinParams",
    "TwinResult",
    "ValidateParams",
    "ValidationResult",
    "__version__",
    "build_report",
    "compare",
    "generate_stand",
    "load_config",
    "load_scene",
    "plan_scans",
    "plot_from_cloud",
    "plots_from_clouds",
    "read_cloud",
    "read_plot",
    "reconstruct",
    "ring_layout",
    "run_batch",
    "run_preset",
    "run_sweep",
    "run_tree",
    "scan",
    "scan_plot",
    "tree_figures",
    "validate_scans",
    "write_cloud",
    "write_plan",
    "write_plot",
]
