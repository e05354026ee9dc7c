"""Field metadata: every parameter carries its help text and unit once.

A parameter dataclass declares each field with :func:`param`; the command line, the TOML
file (:mod:`treesim.params.settings`), ``--print-params`` and the service's JSON schemas
read the help, unit and default from here (:func:`describe`), so none of them types a
default or a help text of its own.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from collections.abc import Callable, Iterator
from dataclasses import MISSING, dataclass, fields, is_dataclass
from typing import Any

from ..errors import InvalidParameterError

__all__ = [
    "MAX_INT",
    "MAX_REAL",
    "NONE_WORDS",
    "ParamInfo",
    "check_bounds",
    "describe",
    "field_info",
    "finite",
    "param",
    "read_int",
    "walk",
]

#: The largest magnitude of a real-valued parameter declared without a bound on that side:
#: every number is bounded, so no setting reaches a computation as 1e308 and overflows.
MAX_REAL = 1e9
#: The largest magnitude of an integer parameter declared without a bound on that side
#: (JSON's largest safe integer, 2**53 - 1: what every client reads exactly).
MAX_INT = 2**53 - 1

#: Words that stand for ``None`` ("the rule", "off") in text settings.
NONE_WORDS = ("none", "off", "auto")


def read_int(value: Any) -> int:
    """An integer from a number, or from text also written as ``1e9`` or ``2e6``."""
    if not isinstance(value, str):
        return int(value)
    try:
        return int(value)
    except ValueError:
        v = float(value)
        if not v.is_integer():
            raise ValueError(f"not an integer: {value!r}") from None
        return int(v)


def param(
    default: Any = MISSING,
    *,
    help: str,
    unit: str | None = None,
    factory: Callable[[], Any] | None = None,
    choices: tuple[str, ...] | None = None,
    none_means: str | None = None,
    execution_only: bool = False,
    flag: str | None = None,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
) -> Any:
    """A dataclass field with its documentation.

    Parameters
    ----------
    default : object
        The default value (or ``factory`` for mutable and nested defaults).
    help : str
        One line for ``--help``, the TOML file and the JSON schema; no default in it.
    unit : str, optional
        The unit (``m``, ``deg``, ``mrad``, ``s``, ...); ``None`` for counts and names.
    choices : tuple of str, optional
        The allowed values of a text field.
    none_means : str, optional
        What ``None`` stands for ("derived from the point spacing", "off", ...).
    execution_only : bool
        True when the field decides only how fast a run goes, never its result
        (threads, chunk sizes): left out of the run's settings hash.
    flag : str, optional
        The command-line flag when it is not ``--`` + the field name with dashes.
    ge, gt, le, lt : float, optional
        The natural range of a number (greater or equal, greater, less or equal, less
        than): the dataclass checks it (:func:`check_bounds`) and the command line
        refuses a value outside it while it reads the flag. ``None`` stays allowed for
        optional fields.
    """
    metadata = {
        "help": help,
        "unit": unit,
        "choices": choices,
        "none_means": none_means,
        "execution_only": execution_only,
        "flag": flag,
        "bounds": (ge, gt, le, lt),
    }
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


@dataclass(frozen=True)
class ParamInfo:
    """What the parameter model says about one field.

    Attributes
    ----------
    owner : type
        The dataclass the field belongs to.
    name : str
    path : tuple of str
        Field names from the root dataclass down to this field.
    default : object
        The default value (``factory()`` for factory fields).
    type : str
        The annotation as written (``"float | None"``, ``"int"``, ...).
    help, unit, choices, none_means, execution_only, flag
        As given to :func:`param`.
    bounds : (4,) tuple of float or None
        ``ge``, ``gt``, ``le``, ``lt`` as given to :func:`param`; a number's side left
        open is closed at :data:`MAX_REAL` (:data:`MAX_INT` for an integer), so every
        number has a range.
    """

    owner: type
    name: str
    path: tuple[str, ...]
    default: Any
    type: str
    help: str
    unit: str | None
    choices: tuple[str, ...] | None
    none_means: str | None
    execution_only: bool
    flag: str | None
    bounds: tuple[float | None, float | None, float | None, float | None] = (None,) * 4

    @property
    def optional(self) -> bool:
        """Whether ``None`` is an allowed value."""
        return "None" in self.type

    @property
    def base_type(self) -> str:
        """The annotation without spaces and ``| None``: ``"int"``, ``"tuple[float,float]"``."""
        return self.type.replace(" ", "").replace("|None", "")

    @property
    def scalar(self) -> Callable[[Any], Any] | None:
        """How one value is read from text (:func:`read_int`, ``float``, ``str``), or
        ``None`` for booleans, tuples, tables and nested dataclasses."""
        t = self.base_type
        if t.startswith(("bool", "tuple", "dict")) or is_dataclass(self.default):
            return None
        return {"int": read_int, "float": float}.get(t, str)

    def read(self, value: Any) -> Any:
        """The field's value from text (a flag, a manifest cell) or a number; optional
        fields read :data:`NONE_WORDS` and ``0`` as ``None``."""
        if isinstance(value, str):
            value = value.strip()
            if self.optional and value.lower() in NONE_WORDS:
                return None
        v = (self.scalar or str)(value)
        return None if self.optional and v == 0 else v

    @property
    def cli_flag(self) -> str:
        """The command-line flag that sets this field."""
        return self.flag or "--" + self.name.replace("_", "-")

    def default_text(self, *, with_unit: bool = True) -> str:
        """The default as a reader sees it: ``"0.04 deg"``, ``"derived from ..."``."""
        d = self.default
        if d is None:
            return self.none_means or "none"
        if isinstance(d, bool):
            return "on" if d else "off"
        if isinstance(d, (tuple, list)):
            text = ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in d)
        elif isinstance(d, float):
            text = f"{d:g}"
        elif isinstance(d, int):
            text = str(d)
        else:
            text = str(d)
        return f"{text} {self.unit}" if self.unit and with_unit else text

    @property
    def integer(self) -> bool:
        """Whether the field holds a whole number."""
        return self.base_type == "int"

    def range_text(self) -> str:
        """The values a number may take, as a reader says it: ``"a whole number >= 1"``,
        ``"a number in (0, 45]"``, ``"a finite number"`` (a side closed only at
        :data:`MAX_REAL` or :data:`MAX_INT` reads as open: see :meth:`cap_text`)."""
        ge, gt, le, lt = (None if b is not None and abs(b) == self._cap else b for b in self.bounds)
        what = "a whole number" if self.integer else "a number"
        lo = ("[", ge) if ge is not None else ("(", gt) if gt is not None else None
        hi = ("]", le) if le is not None else (")", lt) if lt is not None else None
        if lo and hi:
            return f"{what} in {lo[0]}{_num(lo[1])}, {_num(hi[1])}{hi[0]}"
        if lo:
            return f"{what} {'>=' if lo[0] == '[' else '>'} {_num(lo[1])}"
        if hi:
            return f"{what} {'<=' if hi[0] == ']' else '<'} {_num(hi[1])}"
        return what if self.integer else "a finite number"

    @property
    def _cap(self) -> float:
        return MAX_INT if self.integer else MAX_REAL

    def cap_text(self, value: Any) -> str:
        """`` (at most <cap> in magnitude)`` when ``value`` is past the cap every number
        has (:data:`MAX_REAL`, :data:`MAX_INT`), else ""."""
        if not any(b is not None and abs(b) == self._cap for b in self.bounds):
            return ""  # the declared range says it all
        try:
            v = float(value)
        except OverflowError:  # an int beyond any float
            past = True
        except (TypeError, ValueError):  # not a number: the range says what is wanted
            past = False
        else:
            past = not math.isnan(v) and abs(v) > self._cap  # NaN is no magnitude
        return f" (at most {_num(self._cap)} in magnitude)" if past else ""

    def in_range(self, value: float) -> bool:
        """Whether the number ``value`` is finite, whole for an integer field, and within
        the declared bounds."""
        ge, gt, le, lt = self.bounds
        try:
            v = float(value)
        except OverflowError:  # an int beyond any float: out of every range
            return False
        return (
            math.isfinite(v)
            and (not self.integer or v.is_integer())
            and (ge is None or v >= ge)
            and (gt is None or v > gt)
            and (le is None or v <= le)
            and (lt is None or v < lt)
        )

    def help_text(self) -> str:
        """``help (unit; default ...)``: the line ``--help`` prints."""
        unit = f"{self.unit}; " if self.unit else ""
        return f"{self.help} ({unit}default {self.default_text(with_unit=False)})"


def _default(f: dataclasses.Field) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return None


def field_info(cls: type, name: str, *, path: tuple[str, ...] = ()) -> ParamInfo:
    """The :class:`ParamInfo` of field ``name`` of dataclass ``cls``."""
    for f in fields(cls):
        if f.name == name:
            return _info(cls, f, path + (name,))
    raise KeyError(f"{cls.__name__} has no field {name!r}")


def _info(cls: type, f: dataclasses.Field, path: tuple[str, ...]) -> ParamInfo:
    md = f.metadata
    if "help" not in md:
        raise TypeError(f"{cls.__name__}.{f.name} is declared without param(help=...)")
    return ParamInfo(
        owner=cls,
        name=f.name,
        path=path,
        default=_default(f),
        type=str(f.type),
        help=md["help"],
        unit=md["unit"],
        choices=md["choices"],
        none_means=md["none_means"],
        execution_only=md["execution_only"],
        flag=md["flag"],
        bounds=_closed(md.get("bounds", (None,) * 4), str(f.type)),
    )


def _num(b: float) -> str:
    """A bound as text: ``0.5``, ``1e+09``, ``2^53 - 1``."""
    if abs(b) == MAX_INT:
        return "-(2^53 - 1)" if b < 0 else "2^53 - 1"
    return f"{b:g}"


def _closed(bounds: tuple[Any, Any, Any, Any], annotation: str) -> tuple[Any, Any, Any, Any]:
    """A number field's bounds with an open side closed at ±:data:`MAX_REAL` (±:data:`MAX_INT`
    for an integer field); other fields' as declared."""
    base = annotation.replace(" | None", "").replace("None | ", "").strip()
    if base.startswith(("tuple[", "list[")):
        base = base.split("[", 1)[1].split(",")[0].strip(" ]")
    if base not in ("int", "float"):
        return bounds
    cap = MAX_INT if base == "int" else MAX_REAL
    ge, gt, le, lt = bounds
    if ge is None and gt is None:
        ge = -cap
    if le is None and lt is None:
        le = cap
    return (ge, gt, le, lt)


def describe(cls: type) -> list[ParamInfo]:
    """Every field of dataclass ``cls`` (not descending into nested dataclasses)."""
    return [_info(cls, f, (f.name,)) for f in fields(cls)]


def walk(cls: type, prefix: tuple[str, ...] = ()) -> Iterator[ParamInfo]:
    """Every leaf field of ``cls`` and of the dataclasses nested in it, depth first."""
    for f in fields(cls):
        info = _info(cls, f, prefix + (f.name,))
        if is_dataclass(info.default) and not isinstance(info.default, type):
            yield from walk(type(info.default), prefix + (f.name,))
        else:
            yield info


def check_bounds(obj: Any) -> None:
    """Raise :class:`InvalidParameterError` unless every number field (``int``,
    ``float``) of the dataclass ``obj`` holds a finite number, whole for an ``int``, within
    the bounds it was declared with (``param(ge=..., ...)``), and every text field with
    declared ``choices`` holds one of them; ``None`` passes for optional fields. Called
    first by the parameter dataclasses' ``__post_init__``, so the declared range and
    choices are the ones the model enforces (and the ones the command line checks)."""
    for info in _choice_fields(type(obj)):
        value = getattr(obj, info.name)
        if value is None and info.optional:
            continue
        if value not in info.choices:
            raise InvalidParameterError(
                f"{info.name} must be one of {', '.join(info.choices)}, got {value!r}"
            )
    for info in _number_fields(type(obj)):
        value = getattr(obj, info.name)
        if value is None and info.optional:
            continue
        many = info.base_type.startswith("tuple")
        if many and not isinstance(value, (tuple, list)):
            raise InvalidParameterError(f"{info.name} must be a list of numbers, got {value!r}")
        for v in value if many else (value,):
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not info.in_range(v):
                each = "each value of " if many else ""
                raise InvalidParameterError(
                    f"{each}{info.name} must be {info.range_text()}{info.cap_text(v)}, "
                    f"got {value!r}"
                )


@functools.cache
def _choice_fields(cls: type) -> tuple[ParamInfo, ...]:
    """The fields of dataclass ``cls`` declared with ``choices``, read once per class."""
    return tuple(info for info in describe(cls) if info.choices)


@functools.cache
def _number_fields(cls: type) -> tuple[ParamInfo, ...]:
    """The fields of dataclass ``cls`` that :func:`check_bounds` checks, read once per
    class (reading a field's description builds its default, nested dataclasses too)."""
    return tuple(
        info
        for info in describe(cls)
        if info.base_type in ("int", "float", "tuple[float,...]") and not info.choices
    )


def finite(name: str, value: float) -> float:
    """``value`` as a float, or :class:`InvalidParameterError` naming ``name``."""
    v = float(value)
    if not math.isfinite(v):
        raise InvalidParameterError(f"{name} must be a finite number, got {value!r}")
    return v
