"""The settings ``treesim run`` and ``batch`` share: preset, config file, flat settings."""

from __future__ import annotations

import argparse
from typing import Any

from ..params import (
    RUN_PRESETS,
    SETTINGS,
    RunParams,
    apply_settings,
    info_at,
    load_config,
    run_preset,
)
from ._options import setting_option, settings_given

STATION_RULE = """\
Stations: --stations N (default 3) stand evenly on a ring around the tree's centre, the
first on +x, at max(5 m, 1.5 x crown diameter, 0.5 x height) from it (crown diameter and
height from the reconstructed mesh's extent) unless --distance-m is given, 1.5 m above the
tree's lowest point (--height-m).
"""

CONFIG_HELP = """\
Settings come from the preset (default standard), then the --config TOML file, then the
flags. 'treesim run --print-params [--preset P] [--config F]' prints a complete TOML file
to start from; its tables are [reconstruct] ([reconstruct.prepare], [reconstruct.qsm]),
[scan] ([scan.scanner]: any ScannerSpec field), [compare] and [report].
"""


def _preset_default(path: tuple[str, ...]) -> str:
    values = []
    for name, p in RUN_PRESETS.items():
        node: Any = p
        for k in path:
            node = getattr(node, k)
        values.append(f"{name} {'none' if node is None else node}")
    if len({v.split(" ", 1)[1] for v in values}) == 1:
        return f"{info_at(RunParams, path).default_text(with_unit=False)}"
    return "the preset's: " + ", ".join(values)


def add_settings(p: argparse.ArgumentParser) -> None:
    """The preset, ``--config`` and one flag per flat setting (:data:`SETTINGS`)."""
    g = p.add_argument_group("settings (override the preset and --config)")
    g.add_argument(
        "--preset",
        choices=list(RUN_PRESETS),
        help="the run preset to start from (default standard)",
    )
    g.add_argument("--config", metavar="FILE", help="a TOML file of settings")
    for setting in SETTINGS.values():
        setting_option(g, setting, default_text=_preset_default(setting.paths[0]))


def params_from_args(args: argparse.Namespace, *, with_threads: bool = True) -> RunParams:
    """RunParams from the run preset, then ``--config``, then the flags."""
    base = run_preset(args.preset) if args.preset else None
    params = (
        load_config(args.config, base=base) if args.config else (base or run_preset("standard"))
    )
    params = apply_settings(params, settings_given(args))
    threads = getattr(args, "param:threads", None) if with_threads else None
    if threads is not None:
        params = params.with_threads(threads)
    return params
