"""The parameter model: every setting treesim takes, with its help text, unit and default.

One frozen keyword-only dataclass per stage, nested into :class:`RunParams`::

    RunParams
    ├── reconstruct: ReconstructParams ── prepare: PrepareParams, qsm: QSMParams
    ├── scan: ScanParams ──────────────── scanner: ScannerSpec
    ├── compare: CompareParams
    └── report: ReportParams

Each field is declared with :func:`param` (help, unit, what ``None`` means, whether it only
changes speed), and everything that shows or reads settings is generated from that: the
command line's options (:mod:`treesim.cli`), TOML files and ``--print-params``
(:mod:`.settings`), batch manifests (:data:`SETTINGS`) and the service's JSON schemas
(:func:`json_schema`). Nothing else types a default.

treesim has three kinds of preset, named apart:

* **run presets** (:data:`RUN_PRESETS`, :func:`run_preset`): ``draft``, ``standard``,
  ``fine``: whole :class:`RunParams`, traded between speed and accuracy;
* **instruments** (:data:`INSTRUMENTS`, :func:`instrument`): a real scanner's published
  figures, giving a :class:`ScannerSpec`;
* **tree species** (:data:`treesim.models.SPECIES`): procedural tree models.

This package imports only :mod:`treesim.errors` and :mod:`treesim.jsonio`: every stage
may import it.
"""

from __future__ import annotations

from importlib import resources

from ._fields import ParamInfo, describe, field_info, param, walk
from .compare import CompareParams, ReportParams
from .reconstruct import METHODS, MIN_CLOUD_POINTS, PrepareParams, QSMParams, ReconstructParams
from .run import (
    DEFAULT_RUN_PRESET,
    LODS,
    RUN_PRESETS,
    RunParams,
    ScanParams,
    execution_only_paths,
    params_hash,
    run_preset,
)
from .scanner import (
    BEAM_SAMPLINGS,
    DEFAULT_REFLECTANCE,
    GENERIC_TLS,
    INSTRUMENTS,
    RETURN_MODES,
    InstrumentPreset,
    ScannerSpec,
    instrument,
    model_fields,
    resolution_fields,
)
from .settings import (
    SETTINGS,
    Setting,
    apply_settings,
    info_at,
    json_schema,
    load_config,
    merge,
    params_from_dict,
    read_toml,
    scan_params,
    set_path,
    to_toml,
)

__all__ = [
    "BEAM_SAMPLINGS",
    "DEFAULT_REFLECTANCE",
    "LODS",
    "DEFAULT_RUN_PRESET",
    "GENERIC_TLS",
    "INSTRUMENTS",
    "METHODS",
    "MIN_CLOUD_POINTS",
    "RETURN_MODES",
    "RUN_PRESETS",
    "SETTINGS",
    "CompareParams",
    "InstrumentPreset",
    "ParamInfo",
    "PrepareParams",
    "QSMParams",
    "ReconstructParams",
    "ReportParams",
    "RunParams",
    "ScanParams",
    "ScannerSpec",
    "Setting",
    "apply_settings",
    "describe",
    "execution_only_paths",
    "field_info",
    "info_at",
    "instrument",
    "json_schema",
    "load_config",
    "merge",
    "model_fields",
    "param",
    "params_from_dict",
    "read_toml",
    "params_hash",
    "preset_measurements",
    "resolution_fields",
    "run_preset",
    "scan_params",
    "set_path",
    "to_toml",
    "walk",
]


def preset_measurements() -> str:
    """What each run preset costs and how accurate it is, as measured by the committed
    sweep (``benchmarks/bench_sweep.py``) and written by ``benchmarks/preset_table.py``
    (the file ``pipeline/data/preset_measurements.txt``; printed in ``treesim run --help``)."""
    return (resources.files("treesim") / "data" / "preset_measurements.txt").read_text("utf-8")
