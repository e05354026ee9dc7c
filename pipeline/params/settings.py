"""The settings language: flat settings, TOML files, ``--print-params`` and JSON schemas.

Three ways to say what a run should do, all read and checked by the same code:

* **flat settings** (:data:`SETTINGS`): a handful of named knobs, the ``treesim run`` and
  ``batch`` flags (``--resolution-deg``) and the columns of a batch manifest
  (``resolution_deg``); each names the field(s) of :class:`RunParams` it sets, and its help
  text, unit and type come from that field;
* **nested mappings** (:func:`params_from_dict`, :func:`load_config`): a TOML file whose
  tables mirror the dataclasses (``[scan.scanner]``), written by :func:`to_toml`;
* **JSON schemas** (:func:`json_schema`) for other programs (the REST service).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

from ..errors import InputFormatError, InvalidParameterError
from ._fields import ParamInfo, describe, field_info, walk
from .run import DEFAULT_RUN_PRESET, RunParams, ScanParams, run_preset
from .scanner import INSTRUMENTS, model_fields, resolution_fields

__all__ = [
    "SETTINGS",
    "Setting",
    "apply_settings",
    "json_schema",
    "load_config",
    "params_from_dict",
    "read_toml",
    "to_toml",
    "scan_params",
]


@dataclass(frozen=True)
class Setting:
    """A flat setting: a name and the :class:`RunParams` field(s) it sets.

    Attributes
    ----------
    name : str
        The manifest column; the flag is ``--`` + the name with dashes.
    paths : tuple of tuple of str
        The nested fields it sets, from :class:`RunParams` down; all get the same value.
    help : str, optional
        Help text when it sets several fields (else the field's own).
    """

    name: str
    paths: tuple[tuple[str, ...], ...]
    help: str | None = None

    @property
    def info(self) -> ParamInfo:
        """The parameter model's description of the (first) field it sets."""
        return info_at(RunParams, self.paths[0])

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    def convert(self, value: Any) -> Any:
        """The value for the field(s), from text (a flag, a manifest cell) or a number
        (:meth:`ParamInfo.read`: optional fields read ``0`` and ``none`` as ``None``)."""
        return self.info.read(value)


def info_at(cls: type, path: tuple[str, ...]) -> ParamInfo:
    """The :class:`ParamInfo` of the field at ``path`` below dataclass ``cls``."""
    owner = cls
    for k in path[:-1]:
        owner = type(field_info(owner, k).default)
    return field_info(owner, path[-1], path=path[:-1])


def _setting(path: tuple[str, ...]) -> Setting:
    info = info_at(RunParams, path)
    return Setting(info.cli_flag[2:].replace("-", "_"), (path,))


#: The flat settings by name: ``treesim run``/``batch`` flags and manifest columns.
SETTINGS: dict[str, Setting] = {
    s.name: s
    for s in (
        _setting(("reconstruct", "method")),
        _setting(("reconstruct", "facets")),
        _setting(("reconstruct", "prepare", "voxel_size_m")),
        _setting(("reconstruct", "poisson_depth")),
        _setting(("scan", "n_stations")),
        _setting(("scan", "distance_m")),
        _setting(("scan", "height_m")),
        _setting(("scan", "lod")),
        _setting(("compare", "tolerance_m")),
        Setting(
            "resolution_deg",
            (
                ("scan", "scanner", "horizontal_resolution_deg"),
                ("scan", "scanner", "vertical_resolution_deg"),
            ),
            help="horizontal and vertical angular step of the scanner",
        ),
    )
}


def apply_settings(params: RunParams, settings: Mapping[str, Any], *, where: str = "") -> RunParams:
    """Apply flat settings (see :data:`SETTINGS`) to ``params``.

    Parameters
    ----------
    params : RunParams
    settings : mapping of str -> value
        Values may be text (manifest cells); empty text and ``None`` are skipped.
    where : str
        Prefix for error messages (e.g. ``"manifest.csv row 3: "``).
    """
    nested: dict[str, Any] = {}
    for key, value in settings.items():
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        if key not in SETTINGS:
            raise InvalidParameterError(
                f"{where}unknown setting {key!r}; known: {', '.join(SETTINGS)}"
            )
        setting = SETTINGS[key]
        try:
            v = setting.convert(value)
        except (TypeError, ValueError):
            raise InvalidParameterError(f"{where}{key}: cannot read {value!r}") from None
        for path in setting.paths:
            set_path(nested, path, v)
    return merge(params, nested, where)


def set_path(nested: dict[str, Any], path: tuple[str, ...], value: Any) -> None:
    """Put ``value`` at ``path`` in a nested mapping, creating the tables on the way."""
    node = nested
    for k in path[:-1]:
        node = node.setdefault(k, {})
    node[path[-1]] = value


def _coerce(value: Any, current: Any, info: ParamInfo, name: str) -> Any:
    if value is None or (isinstance(value, str) and value.lower() in ("none", "auto")):
        if info.optional:
            return None
        if value is None:
            raise InvalidParameterError(f"{name} needs a value")
    if isinstance(current, bool) or info.type == "bool":
        if not isinstance(value, bool):
            raise InvalidParameterError(f"{name} must be true or false, got {value!r}")
        return value
    if isinstance(value, list):
        return tuple(value)
    if isinstance(current, (int, float)) and not isinstance(current, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InvalidParameterError(f"{name} must be a number, got {value!r}")
        if info.integer and isinstance(value, float) and value.is_integer():
            return int(value)  # 3.0 (JSON, TOML) for a whole number
        return value  # 2.5, inf or nan for a whole number: check_bounds refuses and says why
    return value


def merge(obj: Any, mapping: Mapping[str, Any], where: str = "", prefix: str = "") -> Any:
    """A copy of dataclass ``obj`` with the (nested) ``mapping`` applied, validated.

    The one way settings reach a parameter dataclass: TOML files, flat settings and the
    command line's options all go through it, so all are checked the same way."""
    known = {f.name: f for f in fields(obj)}
    changes: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if key not in known:
            section = f"[{prefix[:-1]}]" if prefix else "the top level"
            raise InvalidParameterError(
                f"{where}unknown setting {key!r} in {section}; known: {', '.join(known)}"
            )
        current = getattr(obj, key)
        if is_dataclass(current):
            if not isinstance(value, Mapping):
                raise InvalidParameterError(f"{where}{name} must be a table ([{name}])")
            changes[key] = merge(current, value, where, f"{name}.")
        else:
            try:
                changes[key] = _coerce(value, current, field_info(type(obj), key), name)
            except InvalidParameterError as exc:
                raise _at(exc, name) from None
    if not changes:
        return obj
    try:
        return replace(obj, **changes)
    except InvalidParameterError as exc:
        section = f" in [{prefix[:-1]}]" if prefix else ""
        raise _at(InvalidParameterError(f"{where}{exc}{section}"), prefix[:-1]) from None
    except (TypeError, ValueError) as exc:
        raise _at(
            InvalidParameterError(f"{where}bad value in [{prefix[:-1] or 'top'}]: {exc}"),
            prefix[:-1],
        ) from None


def _at(exc: InvalidParameterError, path: str) -> InvalidParameterError:
    """``exc`` with ``.field``: the dotted path of the setting (or section) it is about,
    unless a deeper level named one already ("" for the top level)."""
    if getattr(exc, "field", None) is None:
        exc.field = path  # type: ignore[attr-defined]
    return exc


def params_from_dict(
    data: Mapping[str, Any], *, base: RunParams | None = None, where: str = ""
) -> RunParams:
    """RunParams from a nested mapping (a parsed TOML file).

    A top-level ``preset`` key picks the base preset (unless ``base`` is given); every
    other key overrides a field of it. Unknown keys are errors.
    """
    data = dict(data)
    name = data.pop("preset", None)
    if base is None:
        base = run_preset(str(name)) if name is not None else run_preset()
    return merge(base, data, where)


def load_config(path: str | Path, *, base: RunParams | None = None) -> RunParams:
    """Read RunParams from a TOML file (see :func:`to_toml` for its shape).

    Parameters
    ----------
    path : str or Path
        The TOML file: tables ``[scan]``, ``[reconstruct]``, ``[compare]``, ``[report]``
        (and their sub-tables) whose keys are the parameters' names.
    base : RunParams, optional
        The parameters the file's keys change (default: the defaults).

    Returns
    -------
    RunParams

    Raises
    ------
    InputFormatError
        If the file is missing or not valid TOML.
    InvalidParameterError
        If a key is unknown or a value is out of range.

    Examples
    --------
    >>> from pathlib import Path
    >>> import treesim as ts
    >>> _ = Path("run.toml").write_text("scan.n_stations = 4")
    >>> ts.load_config("run.toml").scan.n_stations
    4
    """
    p = Path(path)
    return params_from_dict(read_toml(p, "config file"), base=base, where=f"{p.name}: ")


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The TOML file ``path`` as a mapping; ``what`` names it in errors (``"config file"``).

    Raises
    ------
    InputFormatError
        If the file is missing, unreadable or not valid TOML.
    """
    import tomllib

    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"{what} {p} not found; check the path")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{what} {p} could not be read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputFormatError(f"{what} {p} is not valid TOML: {exc}") from None


def to_toml(params: RunParams) -> str:
    """The parameters as a TOML file :func:`load_config` reads back, each line with its
    help text and unit from the parameter model (``None`` is written as ``"none"``)."""
    d = params.to_dict()
    d.pop("preset", None)
    lines = [
        f'preset = "{params.preset}"' if params.preset else f'# preset = "{DEFAULT_RUN_PRESET}"'
    ]
    docs = {info.path: info for info in walk(RunParams)}

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    def comment(path: tuple[str, ...]) -> str:
        info = docs.get(path)
        if info is None:
            return ""
        unit = f" [{info.unit}]" if info.unit else ""
        none = f"; none: {info.none_means}" if info.none_means else ""
        return f"  # {info.help}{unit}{none}"

    def table(path: tuple[str, ...], node: dict[str, Any]) -> None:
        scalars = {k: v for k, v in node.items() if not isinstance(v, dict) or k == "reflectance"}
        subs = {k: v for k, v in node.items() if k not in scalars}
        if path:
            lines.append("")
            lines.append(f"[{'.'.join(path)}]")
        for k, v in scalars.items():
            if v is None:
                text = '"none"'
            elif isinstance(v, dict):
                text = "{ " + ", ".join(f"{kk} = {value(vv)}" for kk, vv in v.items()) + " }"
            else:
                text = value(v)
            lines.append(f"{k} = {text}{comment(path + (k,))}")
        for k, v in subs.items():
            table(path + (k,), v)

    table((), d)
    return "\n".join(lines) + "\n"


_JSON_TYPES = {"int": "integer", "float": "number", "str": "string", "bool": "boolean"}
#: JSON Schema's names of the bounds :func:`~treesim.params.param` declares.
_JSON_BOUNDS = ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum")


def _bounds(info: ParamInfo) -> dict[str, float]:
    """The field's declared range (``param(ge=, gt=, le=, lt=)``) as JSON Schema keywords,
    so that the schema states the range :func:`merge` enforces."""
    return {k: b for k, b in zip(_JSON_BOUNDS, info.bounds, strict=True) if b is not None}


def json_schema(cls: type = RunParams) -> dict[str, Any]:
    """A JSON Schema (draft 2020-12) of a parameter dataclass, from the parameter model.

    Every property carries its help (``description``), unit (``x-unit``), default,
    choices and declared range (``minimum``, ``exclusiveMinimum``, ...); nested
    dataclasses are nested objects; unknown keys are refused, as :func:`merge` refuses
    them. The schema describes; :func:`merge` still decides.
    """
    props: dict[str, Any] = {}
    for info in describe(cls):
        d = info.default
        if is_dataclass(d) and not isinstance(d, type):
            sub = json_schema(type(d))
            sub["description"] = info.help
            props[info.name] = sub
            continue
        t = info.base_type
        if t.startswith("tuple") or t.startswith("list"):
            item = "integer" if "int" in t.split("[", 1)[1] else "number"
            schema: dict[str, Any] = {"type": "array", "items": {"type": item, **_bounds(info)}}
            if "..." not in t:
                n = t.split("[", 1)[1].count(",") + 1
                schema.update(minItems=n, maxItems=n)
        elif t.startswith("dict"):
            # the one table of numbers, reflectance per label, is checked in [0, 1]
            values = {"type": "number", "minimum": 0, "maximum": 1}
            schema = {"type": "object", "additionalProperties": values}
        elif info.choices:
            schema = {"type": "string", "enum": list(info.choices)}
        else:
            schema = {"type": _JSON_TYPES.get(info.base_type, "string"), **_bounds(info)}
        if info.optional:
            schema = {"anyOf": [schema, {"type": "null"}]}
        schema["description"] = info.help + (
            f" (null: {info.none_means})" if info.none_means else ""
        )
        if info.unit:
            schema["x-unit"] = info.unit
        schema["default"] = json.loads(json.dumps(d if not isinstance(d, tuple) else list(d)))
        props[info.name] = schema
    return {
        "title": cls.__name__,
        "description": (cls.__doc__ or "").strip().splitlines()[0],
        "type": "object",
        "properties": props,
        "additionalProperties": False,
    }


def scan_params(
    settings: Mapping[str, Any] | None = None,
    *,
    base: ScanParams | None = None,
    instrument: str | None = None,
    beam: bool = False,
    noise: bool = False,
    resolution_deg: float | None = None,
) -> ScanParams:
    """ScanParams the way ``treesim scan`` builds them: ``base`` (default the model's), its
    scanner replaced by an instrument's figures (with its beam and noise models only when
    asked), both angular steps from ``resolution_deg``, then the nested ``settings``
    (field names of :class:`ScanParams`, ``scanner`` a table) checked by
    :func:`~treesim.params.merge`. Without an instrument, ``beam`` and ``noise`` turn the
    models on with a generic scanner's figures (:data:`~treesim.params.GENERIC_TLS`);
    ``settings`` still override them.

    Raises
    ------
    InvalidParameterError
        Unknown instrument or setting, or a value out of range.
    """
    params = base or ScanParams()
    given = dict(settings or {})
    scanner_given = dict(given.pop("scanner", None) or {})
    if resolution_deg is not None:
        for k, v in resolution_fields(resolution_deg).items():
            scanner_given.setdefault(k, v)
    if instrument:
        if instrument not in INSTRUMENTS:
            raise InvalidParameterError(
                f"unknown instrument {instrument!r}; the instruments are {', '.join(INSTRUMENTS)}"
            )
        params = replace(params, scanner=INSTRUMENTS[instrument].spec(beam=beam, noise=noise))
    elif beam or noise:
        params = replace(
            params, scanner=params.scanner.with_(**model_fields(beam=beam, noise=noise))
        )
    return merge(params, {**given, "scanner": scanner_given} if scanner_given else given)
