"""The settings ``treesim run`` and ``batch`` share: preset, config file, flat settings."""

from __future__ import annotations

import argparse
import textwrap
from typing import Any

from ..params import (
    DEFAULT_RUN_PRESET,
    RUN_PRESETS,
    SETTINGS,
    RunParams,
    ScanParams,
    apply_settings,
    info_at,
    load_config,
    run_preset,
)
from ._options import setting_option, settings_given

_SCAN = ScanParams()
STATION_RULE = (
    textwrap.fill(
        f"Stations: --stations N (default {_SCAN.n_stations}) stand evenly on a ring around "
        f"the tree's centre, the first on +x, at max({_SCAN.min_distance_m:g} m, 1.5 x crown "
        "diameter, 0.5 x height) from it (crown diameter and height from the reconstructed "
        f"mesh's extent) unless --distance-m is given, {_SCAN.height_m:g} m above the tree's "
        "lowest point (--height-m).",
        88,
    )
    + "\n"
)

CONFIG_HELP = f"""\
Settings come from the preset (default {DEFAULT_RUN_PRESET}), then the --config TOML file, then the
flags. 'treesim run --print-params [--preset P] [--config F]' prints a complete TOML file
to start from; its tables are [reconstruct] ([reconstruct.prepare], [reconstruct.qsm]),
[scan] ([scan.scanner]: any ScannerSpec field), [compare] and [report].
"""


def _preset_default(path: tuple[str, ...]) -> str:
    values: dict[str, Any] = {}
    info = info_at(RunParams, path)
    for name, p in RUN_PRESETS.items():
        node: Any = p
        for k in path:
            node = getattr(node, k)
        values[name] = node
    if all(v == info.default for v in values.values()):
        return info.default_text(with_unit=False)
    return "the preset's: " + ", ".join(
        f"{name} {'none' if v is None else v}" for name, v in values.items()
    )


def add_settings(p: argparse.ArgumentParser) -> None:
    """The preset, ``--config`` and one flag per flat setting (:data:`SETTINGS`)."""
    g = p.add_argument_group("settings (override the preset and --config)")
    g.add_argument(
        "--preset",
        choices=list(RUN_PRESETS),
        help=f"the run preset to start from (default {DEFAULT_RUN_PRESET})",
    )
    g.add_argument("--config", metavar="FILE", help="a TOML file of settings")
    for setting in SETTINGS.values():
        setting_option(g, setting, default_text=_preset_default(setting.paths[0]))


def params_from_args(args: argparse.Namespace, *, with_threads: bool = True) -> RunParams:
    """RunParams from the run preset, then ``--config``, then the flags."""
    base = run_preset(args.preset) if args.preset else None
    params = load_config(args.config, base=base) if args.config else (base or run_preset())
    params = apply_settings(params, settings_given(args))
    threads = getattr(args, "param:threads", None) if with_threads else None
    if threads is not None:
        params = params.with_threads(threads)
    return params
