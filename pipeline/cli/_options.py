"""Command-line options generated from the parameter model.

:func:`param_option` adds the flag that sets one field of a parameter dataclass: its name,
type, choices, help text, unit and shown default all come from the field's
:func:`~pipeline.params.param` declaration, so no command types a default or a help
text of its own. :func:`collect` gathers the options a user gave into the nested mapping
that :func:`pipeline.params.merge` checks and applies, the same way as a TOML file.
"""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import InvalidParameterError
from ..params import ParamInfo, Setting, describe, field_info, set_path
from ..params._fields import read_int

#: Attribute of a generated argparse action: the :class:`ParamInfo` it sets.
PARAM = "treesim_param"
#: Attribute of a generated argparse action: the flat :class:`Setting` it sets.
SETTING = "treesim_setting"


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (exit 2)."""

    def error(self, message: str) -> None:  # one line, exit 2
        self.exit(2, f"treesim: error: {message} (see '{self.prog} --help')\n")


def floats(text: str, n: int, what: str) -> tuple[float, ...]:
    """``n`` comma-separated numbers (``"-40,90"``), or a one-line error naming ``what``."""
    try:
        vals = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        vals = ()
    if len(vals) != n:
        raise InvalidParameterError(f"{what} must be {n} numbers separated by commas, got {text!r}")
    return vals


def _metavar(info: ParamInfo) -> str:
    if info.scalar is read_int:
        return "N"
    if info.scalar is float:
        return (info.unit or "x").upper()
    return info.name.upper()


def param_option(
    group: Any,
    cls: type,
    name: str,
    *,
    path: tuple[str, ...] = (),
    flag: str | None = None,
    metavar: str | None = None,
    required: bool = False,
) -> argparse.Action:
    """Add the option that sets field ``name`` of ``cls`` (at ``path`` below the root).

    The option's default is left unset (``argparse.SUPPRESS``): a flag not given leaves the
    model's default (or the preset's, or the config file's) in force. ``--help`` shows the
    model's help, unit and default. Optional fields read ``0`` and ``none`` as ``None``.
    """
    info = field_info(cls, name, path=path)
    t = info.base_type
    kw: dict[str, Any] = {"dest": "param:" + ".".join(info.path), "default": argparse.SUPPRESS}
    if t == "bool":
        kw["action"] = argparse.BooleanOptionalAction if info.optional else "store_const"
        if not info.optional:
            kw["const"] = True
    elif t.startswith("tuple[float,...]"):
        kw.update(action="append", type=float, metavar=metavar or "VALUE")
    elif t.startswith("tuple"):
        n = t.split("[", 1)[1].count(",") + 1
        flag_name = flag or info.cli_flag

        def read(text: str) -> tuple[float, ...]:
            return floats(text, n, flag_name)

        kw.update(type=read, metavar=metavar or ",".join("ABCD"[:n]))
    elif info.choices:
        kw["choices"] = list(info.choices)
    else:
        kw["type"] = info.read if info.optional else info.scalar
        kw["metavar"] = metavar or _metavar(info)
    help_text = info.help_text()
    if info.optional and t != "bool":
        if info.default is None:
            help_text = help_text[:-1] + "; also given as 0 or none)"
        else:
            help_text = help_text[:-1] + "; 0 or none: " + (info.none_means or "none") + ")"
    if required:
        kw["required"] = True
        help_text = info.help
    action = group.add_argument(flag or info.cli_flag, help=help_text, **kw)
    setattr(action, PARAM, info)
    return action


def param_options(
    group: Any,
    cls: type,
    names: list[str] | None = None,
    *,
    path: tuple[str, ...] = (),
    exclude: tuple[str, ...] = (),
) -> None:
    """:func:`param_option` for each of ``names`` (default: every field of ``cls`` but
    ``exclude``)."""
    for name in names if names is not None else [i.name for i in describe(cls)]:
        if name not in exclude:
            param_option(group, cls, name, path=path)


def setting_option(group: Any, setting: Setting, *, default_text: str) -> argparse.Action:
    """Add the flag of a flat setting (``treesim run``/``batch``): its value is read by
    :func:`pipeline.params.apply_settings`, like a manifest column."""
    info = setting.info
    unit = f"{info.unit}; " if info.unit else ""
    zero = f"; 0: {info.none_means}" if info.optional else ""
    kw: dict[str, Any] = {"dest": "setting:" + setting.name, "default": None}
    if info.choices:
        kw["choices"] = list(info.choices)
    else:
        kw["type"] = info.scalar
        kw["metavar"] = _metavar(info)
    help_text = f"{setting.help or info.help} ({unit}default {default_text}{zero})"
    action = group.add_argument(setting.flag, help=help_text, **kw)
    setattr(action, SETTING, setting)
    return action


def collect(args: argparse.Namespace) -> dict[str, Any]:
    """The generated options the user gave, as a nested mapping below the root dataclass."""
    nested: dict[str, Any] = {}
    for dest, value in vars(args).items():
        if dest.startswith("param:"):
            set_path(nested, tuple(dest[len("param:") :].split(".")), value)
    return nested


def settings_given(args: argparse.Namespace) -> dict[str, Any]:
    """The flat settings the user gave (``--resolution-deg`` ...), by setting name."""
    return {
        dest[len("setting:") :]: v
        for dest, v in vars(args).items()
        if dest.startswith("setting:") and v is not None
    }
