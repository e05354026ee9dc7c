"""Command-line options generated from the parameter model.

:func:`param_option` adds the flag that sets one field of a parameter dataclass: its name,
type, choices, help text, unit and shown default all come from the field's
:func:`~treesim.params.param` declaration, so no command types a default or a help
text of its own. :func:`collect` gathers the options a user gave into the nested mapping
that :func:`treesim.params.merge` checks and applies, the same way as a TOML file.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the parameter model (and numpy) is imported when an option is made
    from ..params import ParamInfo, Setting

#: Attribute of a generated argparse action: the :class:`ParamInfo` it sets.
PARAM = "treesim_param"
#: Attribute of a generated argparse action: the flat :class:`Setting` it sets.
SETTING = "treesim_setting"


_NUMBER = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf|infinity|nan"
#: What a value that starts with a dash but is no option looks like: a negative number or
#: a comma-separated list of numbers whose first is negative (``-3,0,1.5``, ``-40,60``),
#: ``-inf`` and ``-nan`` included (so that their reader says what is wrong with them).
NEGATIVE_VALUE = re.compile(rf"^-(?:{_NUMBER})(?:,\s*[-+]?(?:{_NUMBER}))*$", re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (exit 2) and which reads a
    negative number or a list of numbers starting with one (``--station -3,0,1.5``) as
    an option's value, not as an unknown option (argparse alone takes only ``-3`` and
    ``-1.5``; no treesim option looks like a number)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str) -> None:  # one line, exit 2
        message = message.removeprefix("argument ")  # "--max-rays: expected ..."
        self.exit(2, f"treesim: error: {message} (see '{self.prog} --help')\n")


def number_type(
    info: ParamInfo, *, none: Any = None, element: bool = False
) -> Callable[[str], Any]:
    """The argparse ``type`` of a number field: finite, whole for an ``int``, within the
    bounds the parameter model declares (``param(ge=...)``), or a usage error saying so
    (``--max-rays: expected a whole number >= 1, got 'nan'``). Optional fields also read
    ``0`` and ``none`` as ``none`` (:meth:`ParamInfo.read`'s rule; what the flag's value is
    then: ``None`` for a parameter option, ``0`` for a flat setting, which reads it as
    ``None`` itself). ``element``: read one value of a list field (``--bpa-radius-m``,
    repeatable)."""
    optional = info.optional and not element
    parse = float if element else info.read

    def read(text: str) -> Any:
        try:
            v = parse(text)
        except (ValueError, OverflowError):
            v = math.nan  # not a number (or not a whole one): refused below
        if v is None:
            return none
        if not info.in_range(v):
            also = f", or 0/none for {info.none_means or 'none'}" if optional else ""
            raise argparse.ArgumentTypeError(f"expected {info.range_text()}{also}, got {text!r}")
        return v

    read.__name__ = info.name
    return read


def whole_number(minimum: int) -> Callable[[str], int]:
    """The argparse ``type`` of a count that is no parameter (``batch --workers``)."""

    def read(text: str) -> int:
        from ..params._fields import read_int  # when read: the parameter model needs numpy

        try:
            v = read_int(text.strip())
        except (ValueError, OverflowError):
            v = None
        if v is None or v < minimum:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {minimum}, got {text!r}")
        return v

    return read


def execution_options(parser: argparse.ArgumentParser, what: str = "tree") -> None:
    """The ``execution`` group of a command that runs many trees through the batch's
    executors: ``--executor`` (inline, local: default, dask), ``--workers``,
    ``--threads`` (per ``what``), ``--scheduler``, ``--no-progress``."""
    x = parser.add_argument_group("execution")
    x.add_argument(
        "--executor",
        choices=["inline", "local", "dask"],
        default="local",
        help="inline: this process; local: a process pool (default); dask: a Dask cluster",
    )
    x.add_argument(
        "--workers", type=whole_number(1), help="worker processes (default one per core)"
    )
    x.add_argument(
        "--threads", type=whole_number(1), help=f"threads per {what} (default cores // workers)"
    )
    x.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a running Dask scheduler (default: a local cluster); with --executor dask",
    )
    x.add_argument("--no-progress", action="store_true", help="no progress output on stderr")


def execution(args: argparse.Namespace) -> dict[str, Any]:
    """The keywords :func:`execution_options` gathered, as the batch's runners take them:
    ``executor``, ``workers``, ``threads``, ``scheduler``."""
    return {k: getattr(args, k) for k in ("executor", "workers", "threads", "scheduler")}


def station_task_options(group: Any, where: str, same: str) -> None:
    """``--executor`` (inline: default, local, dask), ``--workers``, ``--scheduler``,
    ``--cache-dir`` and ``--sectors`` of a command whose plot scans run each station as a
    task (``treesim plot scan``, ``treesim plan``'s verification), in ``group``:
    ``where`` names the stations that run, ``same`` what stays the same, bit for bit."""
    group.add_argument(
        "--executor",
        choices=["inline", "local", "dask"],
        default="inline",
        help=f"where {where} run: inline (this process, one after another: default), "
        "local (a process pool) or dask (a Dask cluster); each station then a task that "
        f"builds only the trees it can record ({same}, bit for bit)",
    )
    group.add_argument(
        "--workers",
        type=whole_number(1),
        metavar="N",
        help="worker processes of local or a local dask cluster (default one per core)",
    )
    group.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a running Dask scheduler (default: a local cluster); with --executor dask",
    )
    group.add_argument(
        "--cache-dir",
        metavar="DIR",
        help="the folder the station tasks' trees are built into and read from (default a "
        "temporary one; with --scheduler, a folder every worker reads at the same path)",
    )
    group.add_argument(
        "--sectors",
        type=whole_number(1),
        metavar="N",
        help="scan each station in N azimuth sectors (each a task of its own with an "
        "executor), each loading only the trees it can record: a fraction of a station's "
        "geometry in memory at once (default 1; one ray a pulse only)",
    )


def floats_type(n: int, what: str) -> Callable[[str], tuple[float, ...]]:
    """The argparse ``type`` of ``n`` comma-separated finite numbers (``"-40,90"``) for
    the option ``what``, or a usage error (exit 2)."""

    def read(text: str) -> tuple[float, ...]:
        try:
            vals = tuple(float(v) for v in text.replace(" ", "").split(","))
        except ValueError:
            vals = ()
        if len(vals) != n or not all(math.isfinite(v) for v in vals):
            raise argparse.ArgumentTypeError(
                f"expected {n} finite numbers separated by commas, got {text!r}"
            )
        return vals

    read.__name__ = what.lstrip("-")
    return read


def _metavar(info: ParamInfo) -> str:
    from ..params._fields import read_int

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
    from ..params import field_info

    info = field_info(cls, name, path=path)
    t = info.base_type
    kw: dict[str, Any] = {"dest": "param:" + ".".join(info.path), "default": argparse.SUPPRESS}
    if t == "bool":
        # --NAME and --no-NAME where the default may be on; a bare --NAME where it is off
        turn_off = info.optional or info.default is True
        kw["action"] = argparse.BooleanOptionalAction if turn_off else "store_const"
        if not turn_off:
            kw["const"] = True
    elif t.startswith("tuple[float,...]"):
        kw.update(action="append", type=number_type(info, element=True), metavar=metavar or "VALUE")
    elif t.startswith("tuple"):
        n = t.split("[", 1)[1].count(",") + 1
        kw.update(
            type=floats_type(n, flag or info.cli_flag), metavar=metavar or ",".join("ABCD"[:n])
        )
    elif info.choices:
        kw["choices"] = list(info.choices)
    elif info.integer or t == "float":
        kw["type"] = number_type(info)
        kw["metavar"] = metavar or _metavar(info)
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
    from ..params import describe

    for name in names if names is not None else [i.name for i in describe(cls)]:
        if name not in exclude:
            param_option(group, cls, name, path=path)


def setting_option(group: Any, setting: Setting, *, default_text: str) -> argparse.Action:
    """Add the flag of a flat setting (``treesim run``/``batch``): its value is read by
    :func:`treesim.params.apply_settings`, like a manifest column."""
    info = setting.info
    unit = f"{info.unit}; " if info.unit else ""
    zero = f"; 0: {info.none_means}" if info.optional else ""
    kw: dict[str, Any] = {"dest": "setting:" + setting.name, "default": None}
    if info.choices:
        kw["choices"] = list(info.choices)
    elif info.integer or info.base_type == "float":
        kw["type"] = number_type(info, none=0)  # Setting.convert reads 0 as None
        kw["metavar"] = _metavar(info)
    else:
        kw["type"] = info.scalar
        kw["metavar"] = _metavar(info)
    help_text = f"{setting.help or info.help} ({unit}default {default_text}{zero})"
    action = group.add_argument(setting.flag, help=help_text, **kw)
    setattr(action, SETTING, setting)
    return action


def collect(args: argparse.Namespace) -> dict[str, Any]:
    """The generated options the user gave, as a nested mapping below the root dataclass."""
    from ..params import set_path

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
