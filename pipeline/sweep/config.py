"""A sweep's configuration: the TOML file read, every name and value checked, the grid
expanded into designs.

The file (see :mod:`treesim.sweep` for a full example)::

    description = "..."          # optional
    preset = "standard"          # the run preset every design starts from
    repeat = 1                   # timings per point (--repeat overrides)
    tolerance_m = 0.01           # τ of every coverage figure, or
    # tolerance_factor = 3.0     # τ = factor × the coarsest reference cloud's point spacing

    [base]                       # settings of every design (names as in [grid])
    [reference]                  # how procedural trees' field clouds are scanned (ScanParams)
    [[tree]]                     # species = "sapling" | cloud = "path" | bundled = "coffee_tree"
    [grid]                       # name = [values ...]: the cartesian product
    [[point]]                    # one design each: names = values, optional preset and label

Parameters are named as the flat settings of ``treesim run``/``batch``
(:data:`treesim.params.SETTINGS`: ``resolution_deg``, ``stations``, ``facets``,
``voxel_m``, ...) or as dotted paths of the parameter model
(``scan.scanner.beam_divergence_mrad``, ``reconstruct.qsm.slice_m``; TOML's dotted keys
and quoted keys both work). Each value goes through :func:`treesim.params.merge`, the
check every TOML file and flag gets.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from ..errors import InputFormatError, InvalidParameterError
from ..jsonio import json_ready
from ..params import (
    SETTINGS,
    RunParams,
    ScanParams,
    info_at,
    merge,
    params_hash,
    resolution_fields,
    run_preset,
    set_path,
    walk,
)
from ..params.models import ModelParams

__all__ = [
    "Design",
    "SweepConfig",
    "TreeSpec",
    "known_names",
    "load_sweep",
    "parse_sweep",
    "paths_of",
    "value_at",
]

#: Top-level keys of a sweep file.
TOP_KEYS = (
    "description",
    "preset",
    "repeat",
    "tolerance_m",
    "tolerance_factor",
    "base",
    "reference",
    "tree",
    "grid",
    "point",
)
#: Keys of a ``[[tree]]`` table: one source, an id, and the procedural model's settings.
TREE_SOURCES = ("species", "cloud", "bundled")
TREE_MODEL_KEYS = ("seed", "leaves", "facets")
#: Fields a sweep sets itself and that no design may set.
RESERVED = {
    ("threads",): "the executor sets threads (--threads, --workers)",
    ("preset",): 'name a design\'s starting preset with preset = "..." in its [[point]]',
    ("reconstruct", "prepare", "threads"): "the executor sets threads (--threads, --workers)",
    ("compare", "nthreads"): "the executor sets threads (--threads, --workers)",
    ("compare", "tolerance_m"): "τ is the sweep's own: set tolerance_m or tolerance_factor "
    "at the top of the file",
}


# -- names ----------------------------------------------------------------------------------
def _leaf_paths() -> dict[str, tuple[str, ...]]:
    return {".".join(i.path): i.path for i in walk(RunParams)}


def known_names() -> list[str]:
    """Every name a sweep accepts: the flat settings, then every dotted leaf path."""
    flat = [n for n, s in SETTINGS.items() if not any(p in RESERVED for p in s.paths)]
    return [*flat, *(n for n, p in _leaf_paths().items() if p not in RESERVED)]


def paths_of(name: str, *, where: str = "") -> tuple[tuple[str, ...], ...]:
    """The fields of :class:`RunParams` that parameter ``name`` sets.

    Raises
    ------
    InvalidParameterError
        For an unknown name (one line listing the known ones) or a field the sweep sets
        itself (threads, τ).
    """
    leaves = _leaf_paths()
    paths = SETTINGS[name].paths if name in SETTINGS else (leaves[name],) if name in leaves else ()
    for path in paths:
        if path in RESERVED:
            raise InvalidParameterError(f"{where}{name} cannot be swept: {RESERVED[path]}")
    if paths:
        return paths
    import difflib

    close = difflib.get_close_matches(name, known_names(), n=3, cutoff=0.6)
    hint = f" (did you mean {' or '.join(close)}?)" if close else ""
    raise InvalidParameterError(
        f"{where}unknown parameter {name!r}{hint}; known: {', '.join(known_names())}"
    )


def value_at(params: RunParams, path: tuple[str, ...]) -> Any:
    """The value of the field at ``path`` of ``params``."""
    node: Any = params
    for k in path:
        node = getattr(node, k)
    return node


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"scan": {"scanner": {"seed": [1]}}}`` → ``{"scan.scanner.seed": [1]}``; a table
    stops at a flat setting or a leaf field (so dict-valued fields stay whole)."""
    leaves = _leaf_paths()
    out: dict[str, Any] = {}
    for k, v in table.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping) and name not in SETTINGS and name not in leaves:
            out.update(_flatten(v, f"{name}."))
        else:
            out[name] = v
    return out


def _nested(values: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Named values as the nested mapping :func:`~treesim.params.merge` takes."""
    nested: dict[str, Any] = {}
    for name, v in values.items():
        for path in paths_of(name, where=where):
            set_path(nested, path, v)
    return nested


def _placed(fn: Any, *args: Any, where: str, **kw: Any) -> Any:
    """``fn(*args, **kw)``, its :class:`InvalidParameterError` prefixed with ``where`` when
    the message does not name the place already (merge's type errors, unknown presets)."""
    try:
        return fn(*args, **kw)
    except InvalidParameterError as exc:
        if where and not str(exc).startswith(where):
            raise InvalidParameterError(f"{where}{exc}") from None
        raise


def _merge(obj: Any, nested: Mapping[str, Any], where: str) -> Any:
    return _placed(merge, obj, nested, where, where=where)


def _preset(name: str, where: str) -> RunParams:
    return _placed(run_preset, name, where=where)


# -- trees ------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class TreeSpec:
    """One tree of a sweep.

    Attributes
    ----------
    id : str
        Its name in outputs (``points/<id>-<design>``).
    kind : {"procedural", "cloud"}
        A procedural species (exact truth; its field cloud is scanned by the sweep's
        reference design) or a field cloud file.
    source : str
        How the file named it, in words.
    model : ModelParams, optional
        Species, seed, leaves and facets of a procedural tree.
    path : Path, optional
        A field cloud's file (absolute).
    """

    id: str
    kind: str
    source: str
    model: ModelParams | None = None
    path: Path | None = None


def bundled_cloud(name: str) -> Path:
    """The cloud of a tree bundled with treesim (``pipeline/data/<name>/cloud.txt``)."""
    data = resources.files("treesim") / "data"
    names = sorted(p.name for p in data.iterdir() if p.is_dir() and (p / "cloud.txt").is_file())
    if name not in names:
        raise InvalidParameterError(
            f"no bundled tree {name!r}; the bundled trees are {', '.join(names) or 'none'}"
        )
    return Path(str(data / name / "cloud.txt"))


def _tree(raw: Any, i: int, base_dir: Path, where: str) -> TreeSpec:
    w = f"{where}[[tree]] {i + 1}: "
    if not isinstance(raw, Mapping):
        raise InvalidParameterError(
            f"{w}must be a table (species = ..., cloud = ... or bundled = ...)"
        )
    known = ("id", *TREE_SOURCES, *TREE_MODEL_KEYS)
    unknown = [k for k in raw if k not in known]
    if unknown:
        raise InvalidParameterError(
            f"{w}unknown key(s) {', '.join(unknown)}; known: {', '.join(known)}"
        )
    given = [k for k in TREE_SOURCES if k in raw]
    if len(given) != 1:
        raise InvalidParameterError(
            f"{w}give exactly one of species, cloud or bundled (got {', '.join(given) or 'none'})"
        )
    src = given[0]
    tid = raw.get("id")
    if tid is not None and (not isinstance(tid, str) or not tid.strip()):
        raise InvalidParameterError(f"{w}id must be a non-empty string")
    if src == "species":
        from ..models import SPECIES

        species = raw["species"]
        if species not in SPECIES:
            raise InvalidParameterError(
                f"{w}unknown species {species!r}; the species are {', '.join(SPECIES)}"
            )
        model = _merge(
            ModelParams(),
            {k: raw[k] for k in ("species", *TREE_MODEL_KEYS) if k in raw},
            w,
        )
        return TreeSpec(
            id=tid or species,
            kind="procedural",
            source=f"species {species}, seed {model.seed}, {model.facets} facets"
            + ("" if model.leaves is None else (", leaves" if model.leaves else ", leaf-off")),
            model=model,
        )
    extra = [k for k in TREE_MODEL_KEYS if k in raw]
    if extra:
        raise InvalidParameterError(
            f"{w}{', '.join(extra)} apply to procedural trees (species = ...)"
        )
    if src == "bundled":
        path = bundled_cloud(str(raw["bundled"]))
        return TreeSpec(
            id=tid or str(raw["bundled"]),
            kind="cloud",
            source=f"bundled {raw['bundled']}",
            path=path,
        )
    p = Path(str(raw["cloud"]))
    path = p if p.is_absolute() else base_dir / p
    if not path.is_file():
        raise InputFormatError(f"{w}cloud {path} not found; paths are relative to the config file")
    return TreeSpec(
        id=tid or path.stem, kind="cloud", source=f"cloud {raw['cloud']}", path=path.resolve()
    )


# -- designs ----------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Design:
    """One combination of settings, run on every tree.

    Attributes
    ----------
    index : int
        Its place in the file's order (grid first, then the listed points).
    labels : tuple of str
        Names given to it (a ``[[point]]``'s label or preset).
    given : dict
        The values the file set for it (grid and point names), before defaults.
    params : RunParams
        Its effective settings, τ not yet applied.
    key : str
        SHA-256 of what decides its result and its timing: :func:`params_hash` plus any
        swept speed-only field (``scan.chunk_rays`` ...). Point folders are named by it.
    """

    index: int
    labels: tuple[str, ...]
    given: dict[str, Any]
    params: RunParams
    key: str


def design_key(params: RunParams, exec_paths: tuple[tuple[str, ...], ...]) -> str:
    """What names a design: the settings hash and the swept speed-only fields."""
    extra = {".".join(p): json_ready(value_at(params, p)) for p in exec_paths}
    text = json.dumps([params_hash(params), extra], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True, kw_only=True)
class SweepConfig:
    """A sweep, checked and expanded.

    Attributes
    ----------
    path : Path or None
        The file it was read from.
    name : str
        The file's stem (or ``"sweep"``).
    description : str
    preset : str
        The run preset designs start from.
    base : dict
        ``[base]``: named values every design gets.
    parameters : tuple of str
        The names swept (grid keys, then names only points set), in the file's order.
    designs : tuple of Design
        Deduplicated: designs with the same key are one, with their labels merged.
    trees : tuple of TreeSpec
    reference : ScanParams
        The field design that scans procedural trees.
    tolerance_m, tolerance_factor : float or None
        τ as given, or the factor of the derived τ (exactly one is set).
    repeat : int
    raw : dict
        The file's content (for the record).
    """

    path: Path | None
    name: str
    description: str
    preset: str
    base: dict[str, Any]
    parameters: tuple[str, ...]
    designs: tuple[Design, ...]
    trees: tuple[TreeSpec, ...]
    reference: ScanParams
    tolerance_m: float | None
    tolerance_factor: float | None
    repeat: int
    raw: dict[str, Any] = field(default_factory=dict)

    def parameter_info(self) -> list[dict[str, Any]]:
        """Each swept name with the fields it sets, its unit and help."""
        out = []
        for name in self.parameters:
            paths = paths_of(name)
            info = info_at(RunParams, paths[0])
            help_text = (
                SETTINGS[name].help if name in SETTINGS and SETTINGS[name].help else info.help
            )
            out.append(
                {
                    "name": name,
                    "paths": [".".join(p) for p in paths],
                    "unit": info.unit,
                    "help": help_text,
                }
            )
        return out

    def values_of(self, design: Design) -> dict[str, Any]:
        """The design's effective value of every swept parameter."""
        return {n: json_ready(value_at(design.params, paths_of(n)[0])) for n in self.parameters}


def _number(v: Any, name: str, where: str, *, integer: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InvalidParameterError(f"{where}{name} must be a number, got {v!r}")
    if integer and v != int(v):
        raise InvalidParameterError(f"{where}{name} must be an integer, got {v!r}")
    return v


def _reference(raw: Any, where: str) -> ScanParams:
    """``[reference]``: ScanParams fields (``[reference.scanner]`` a table), plus
    ``resolution_deg`` for both angular steps."""
    w = f"{where}[reference] "
    if raw is None:
        raw = {}
    if not isinstance(raw, Mapping):
        raise InvalidParameterError(f"{w}must be a table")
    raw = dict(raw)
    res = raw.pop("resolution_deg", None)
    scanner = dict(raw.pop("scanner", None) or {})
    if res is not None:
        _number(res, "resolution_deg", w)
        for k, v in resolution_fields(res).items():
            scanner.setdefault(k, v)
    if scanner:
        raw["scanner"] = scanner
    return _merge(ScanParams(), raw, w)


def parse_sweep(
    data: Mapping[str, Any], *, base_dir: str | Path = ".", name: str = "sweep", where: str = ""
) -> SweepConfig:
    """A :class:`SweepConfig` from a parsed TOML mapping.

    Parameters
    ----------
    data : mapping
        The file's content.
    base_dir : str or Path
        What ``cloud`` paths are relative to (the file's folder).
    name : str
        The sweep's name (the file's stem).
    where : str
        Prefix of error messages (the file's name).

    Raises
    ------
    InvalidParameterError
        For any unknown key or name, a value out of range, an empty grid, duplicate tree
        ids: one line naming the place.
    InputFormatError
        For a cloud file that does not exist.
    """
    data = dict(data)
    unknown = [k for k in data if k not in TOP_KEYS]
    if unknown:
        raise InvalidParameterError(
            f"{where}unknown key(s) {', '.join(unknown)} at the top level; "
            f"known: {', '.join(TOP_KEYS)}"
        )
    description, preset, start, repeat = _header(data, where)
    tol, factor = _tolerance(data, where)
    base, base_nested = _base(data, where)
    trees = _trees(data, Path(base_dir), where)
    reference = _reference(data.get("reference"), where)
    grid, points_raw = _grid(data, where)
    parameters, specs, labels_of = _specs(grid, points_raw, where)
    # every single value first, so that an error names the value, then every design
    for k, vals in grid.items():
        for v in vals:
            _merge(start, _nested({**base, k: v}, ""), f"{where}[grid] {k}={v!r}: ")
    designs = _designs(start, preset, base_nested, parameters, specs, labels_of, where)
    return SweepConfig(
        path=None,
        name=name,
        description=description,
        preset=preset,
        base={k: json_ready(v) for k, v in base.items()},
        parameters=tuple(parameters),
        designs=tuple(designs),
        trees=tuple(trees),
        reference=reference,
        tolerance_m=float(tol) if tol is not None else None,
        tolerance_factor=float(factor) if factor is not None else None,
        repeat=int(repeat),
        raw=dict(data),
    )


def _header(data: Mapping[str, Any], where: str) -> tuple[str, str, RunParams, int]:
    """``description``, ``preset`` (its name and its parameters) and ``repeat``, checked."""
    description = data.get("description", "")
    if not isinstance(description, str):
        raise InvalidParameterError(f"{where}description must be text")
    preset = data.get("preset", "standard")
    if not isinstance(preset, str):
        raise InvalidParameterError(f"{where}preset must be a run preset's name")
    start = _preset(preset, where)
    repeat = data.get("repeat", 1)
    _number(repeat, "repeat", where, integer=True)
    if repeat < 1:
        raise InvalidParameterError(f"{where}repeat must be >= 1, got {repeat}")
    return description, preset, start, repeat


def _tolerance(data: Mapping[str, Any], where: str) -> tuple[Any, Any]:
    """``tolerance_m`` or ``tolerance_factor`` (at most one; neither: the default factor),
    as given."""
    tol = data.get("tolerance_m")
    factor = data.get("tolerance_factor")
    if tol is not None and factor is not None:
        raise InvalidParameterError(
            f"{where}give tolerance_m (τ itself) or tolerance_factor (τ from the reference), "
            "not both"
        )
    if tol is not None and _number(tol, "tolerance_m", where) <= 0:
        raise InvalidParameterError(f"{where}tolerance_m must be > 0, got {tol}")
    if factor is not None and _number(factor, "tolerance_factor", where) <= 0:
        raise InvalidParameterError(f"{where}tolerance_factor must be > 0, got {factor}")
    if tol is None and factor is None:
        from ..compare import TOLERANCE_FACTOR

        factor = TOLERANCE_FACTOR
    return tol, factor


def _base(data: Mapping[str, Any], where: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """``[base]``: its values by flat name, and nested as the parameter model's paths."""
    base_raw = data.get("base", {}) or {}
    if not isinstance(base_raw, Mapping):
        raise InvalidParameterError(f"{where}[base] must be a table")
    base = _flatten(base_raw)
    return base, _nested(base, f"{where}[base] ")


def _trees(data: Mapping[str, Any], base_dir: Path, where: str) -> list[TreeSpec]:
    """The ``[[tree]]`` tables: at least one, ids unique and usable as folder names."""
    trees_raw = data.get("tree")
    if not trees_raw:
        raise InvalidParameterError(
            f'{where}no trees: add [[tree]] tables (species = "sapling", cloud = "path" or '
            'bundled = "coffee_tree")'
        )
    if not isinstance(trees_raw, list):
        raise InvalidParameterError(f"{where}trees are [[tree]] tables (an array of tables)")
    trees = [_tree(t, i, base_dir, where) for i, t in enumerate(trees_raw)]
    ids = [t.id for t in trees]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise InvalidParameterError(
            f'{where}two trees are named {dup[0]!r}; give one an id = "..."'
        )
    bad_ids = [i for i in ids if not all(c.isalnum() or c in "._-" for c in i)]
    if bad_ids:
        raise InvalidParameterError(
            f"{where}tree id {bad_ids[0]!r}: use letters, digits, '.', '_' and '-' only"
        )
    return trees


def _grid(data: Mapping[str, Any], where: str) -> tuple[dict[str, Any], list[Any]]:
    """``[grid]`` by flat name (each a non-empty list of values of a known name) and the
    raw ``[[point]]`` tables; one of them must be there."""
    grid_raw = data.get("grid", {}) or {}
    if not isinstance(grid_raw, Mapping):
        raise InvalidParameterError(f"{where}[grid] must be a table of name = [values]")
    grid = _flatten(grid_raw)
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise InvalidParameterError(
                f"{where}[grid] {k} must be a non-empty list of values "
                "(a fixed value goes in [base])"
            )
        paths_of(k, where=f"{where}[grid] ")
    points_raw = data.get("point", []) or []
    if not isinstance(points_raw, list):
        raise InvalidParameterError(f"{where}points are [[point]] tables (an array of tables)")
    if not grid and not points_raw:
        raise InvalidParameterError(
            f"{where}nothing to sweep: add a [grid] table or [[point]] tables"
        )
    return grid, points_raw


#: One design as the file gives it: where (for messages), its values, its [[point]] preset.
_Spec = tuple[str, dict[str, Any], str | None]


def _specs(
    grid: dict[str, Any], points_raw: list[Any], where: str
) -> tuple[list[str], list[_Spec], dict[int, str]]:
    """The grid's cartesian product, then the ``[[point]]`` tables, as specs; the names
    swept (grid keys, then names only points set) and each labelled spec's label."""
    parameters: list[str] = list(grid)
    specs: list[_Spec] = []
    for combo in itertools.product(*grid.values()):
        specs.append(
            (
                "[grid] "
                + ", ".join(f"{k}={v!r}" for k, v in zip(grid, combo, strict=True))
                + ": ",
                dict(zip(grid, combo, strict=True)),
                None,
            )
        )
    labels_of: dict[int, str] = {}
    for i, raw in enumerate(points_raw):
        w = f"[[point]] {i + 1}: "
        if not isinstance(raw, Mapping):
            raise InvalidParameterError(f"{where}{w}must be a table of name = value")
        raw = dict(raw)
        label = raw.pop("label", None)
        p_preset = raw.pop("preset", None)
        if label is not None and not isinstance(label, str):
            raise InvalidParameterError(f"{where}{w}label must be text")
        if p_preset is not None:
            if not isinstance(p_preset, str):
                raise InvalidParameterError(f"{where}{w}preset must be a run preset's name")
            _preset(p_preset, f"{where}{w}")
        values = _flatten(raw)
        for k in values:
            paths_of(k, where=f"{where}{w}")
            if k not in parameters:
                parameters.append(k)
        if label or p_preset:
            labels_of[len(specs)] = label or p_preset
        specs.append((w, values, p_preset))
    return parameters, specs, labels_of


def _designs(
    start: RunParams,
    preset: str,
    base_nested: dict[str, Any],
    parameters: list[str],
    specs: list[_Spec],
    labels_of: dict[int, str],
    where: str,
) -> list[Design]:
    """Every spec's effective settings as a :class:`Design`; specs with the same key are
    one design, their labels merged."""
    exec_paths = tuple(
        p for n in parameters for p in paths_of(n) if info_at(RunParams, p).execution_only
    )
    designs: list[Design] = []
    by_key: dict[str, int] = {}
    for i, (w, values, p_preset) in enumerate(specs):
        first = run_preset(p_preset) if p_preset else start
        params = _merge(first, base_nested, f"{where}[base] ")
        params = _merge(params, _nested(values, f"{where}{w}"), f"{where}{w}")
        params = replace(params, preset=p_preset or preset)
        key = design_key(params, exec_paths)
        label = labels_of.get(i)
        if key in by_key:
            j = by_key[key]
            d = designs[j]
            if label and label not in d.labels:
                designs[j] = replace(d, labels=(*d.labels, label))
            continue
        by_key[key] = len(designs)
        designs.append(
            Design(
                index=len(designs),
                labels=(label,) if label else (),
                given={k: json_ready(v) for k, v in values.items()},
                params=params,
                key=key,
            )
        )
    return designs


def load_sweep(path: str | Path) -> SweepConfig:
    """Read and check a sweep file (TOML).

    Raises
    ------
    InputFormatError
        If the file is missing, unreadable or not TOML.
    InvalidParameterError
        For any unknown name or bad value (see :func:`parse_sweep`).
    """
    import tomllib

    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"sweep file {p} not found; check the path")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"sweep file {p} could not be read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputFormatError(f"sweep file {p} is not valid TOML: {exc}") from None
    cfg = parse_sweep(data, base_dir=p.resolve().parent, name=p.stem, where=f"{p.name}: ")
    return replace(cfg, path=p.resolve())
