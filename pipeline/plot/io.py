"""Plot files: ``plot.toml`` (the plot, its terrain, its trees or a trees CSV) and the
trees CSV.

``plot.toml``::

    radius_m = 15.0              # the plot's radius (m)
    centre_xy = [0.0, 0.0]       # its centre (m)
    facets = 16                  # vertices per ring of procedural and QSM trees' tubes
    terrain_cell_m = 1.0         # the terrain mesh's cells (m)
    trees = "trees.csv"          # the trees: a CSV beside it, or [[trees]] tables below

    [terrain]                    # flat (default), slope, dtm or cloud
    kind = "slope"
    z0_m = 0.0
    slope_deg = 10.0
    aspect_deg = 90.0            # downhill towards, compass degrees
    # path = "dtm.asc"           # dtm (ESRI ASCII grid) or cloud (a ground cloud)

    [stand]                      # free-form: how the stand was made (kept, not read)

    [[trees]]                    # one table per tree, the CSV's columns as keys
    tree_id = 1
    x_m = 3.2
    ...

The trees CSV has a header; its columns are :data:`TREE_COLUMNS` (``tree_id``, ``x_m``
and ``y_m`` are required, the rest optional; an empty cell is the default; other columns
are ignored). Paths in either file are relative to the file's folder. Floats are written
as the shortest decimal that reads back to the same float64, so a plot written and read
back is the same plot.
"""

from __future__ import annotations

import csv
import io as _io
import math
import tomllib
from pathlib import Path
from typing import Any

from ..atomic import write_text
from ..errors import InputFormatError, InvalidParameterError, TreesimError
from .core import TERRAIN_KINDS, Plot, PlotTree, Terrain

__all__ = [
    "PLOT_FILE",
    "TREE_COLUMNS",
    "read_plot",
    "read_trees_csv",
    "write_plot",
    "write_trees_csv",
]

#: The plot file's usual name (a folder given for a plot means this file in it).
PLOT_FILE = "plot.toml"
#: The trees CSV's columns, in the order written.
TREE_COLUMNS = (
    "tree_id",
    "x_m",
    "y_m",
    "z_m",
    "rotation_deg",
    "source",
    "species",
    "seed",
    "path",
    "scale",
    "leaves",
    "dbh_m",
    "height_m",
    "field_cloud",
)
#: Columns holding paths (relative to the file's folder).
_PATHS = ("path", "field_cloud")
_PLOT_KEYS = {"radius_m", "centre_xy", "facets", "terrain_cell_m", "trees", "terrain", "stand"}
_TERRAIN_KEYS = {"kind", "z0_m", "slope_deg", "aspect_deg", "path"}
_INT = {"tree_id", "seed"}
_FLOAT = {"x_m", "y_m", "z_m", "rotation_deg", "scale", "dbh_m", "height_m"}


def _tree_from_row(row: dict[str, Any], where: str) -> PlotTree:
    """A PlotTree from a CSV row or a TOML table (strings or typed values)."""
    kw: dict[str, Any] = {}
    for key in ("tree_id", "x_m", "y_m"):
        if row.get(key) in (None, ""):
            raise InputFormatError(f"{where}: {key} is missing; every tree needs tree_id, x_m, y_m")
    for key, raw in row.items():
        if key not in TREE_COLUMNS or raw is None or raw == "":
            continue
        try:
            if key in _INT:
                if isinstance(raw, bool) or (isinstance(raw, float) and not raw.is_integer()):
                    raise ValueError
                val: Any = int(raw) if not isinstance(raw, str) else int(raw.strip())
            elif key in _FLOAT:
                if isinstance(raw, bool):
                    raise ValueError
                val = float(raw)
            elif key == "leaves":
                if isinstance(raw, bool):
                    val = raw
                elif str(raw).strip().lower() in ("true", "1", "yes"):
                    val = True
                elif str(raw).strip().lower() in ("false", "0", "no"):
                    val = False
                else:
                    raise ValueError
            else:
                val = str(raw).strip()
        except (TypeError, ValueError):
            kind = "an integer" if key in _INT else "a number" if key in _FLOAT else "true/false"
            raise InputFormatError(f"{where}: {key} must be {kind}, got {raw!r}") from None
        kw[key] = val
    try:
        return PlotTree(**kw)
    except InvalidParameterError as exc:
        raise InputFormatError(f"{where}: {exc}") from exc


def read_trees_csv(path: str | Path) -> list[PlotTree]:
    """The trees of a trees CSV (see the module notes)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputFormatError(f"{p}: trees CSV not found; check the path") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{p}: cannot read the trees CSV ({exc})") from exc
    reader = csv.DictReader(_io.StringIO(text))
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in ("tree_id", "x_m", "y_m") if c not in header]
    if missing:
        raise InputFormatError(
            f"{p}: the trees CSV lacks the column(s) {', '.join(missing)}; its header must "
            f"name at least tree_id, x_m, y_m (all columns: {', '.join(TREE_COLUMNS)})"
        )
    reader.fieldnames = header
    trees = []
    for i, row in enumerate(reader, start=2):
        if None in row:
            raise InputFormatError(f"{p}, line {i}: more cells than the header has columns")
        trees.append(_tree_from_row(row, f"{p}, line {i}"))
    if not trees:
        raise InputFormatError(f"{p}: the trees CSV has no trees")
    return trees


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _rel(path: str | None, src_dir: Path | None, dst_dir: Path) -> str | None:
    """``path`` (relative to ``src_dir``) made relative to ``dst_dir``; an absolute
    path stays as it is."""
    if not path or Path(path).is_absolute():
        return path
    p = (src_dir or Path.cwd()) / path
    try:
        return Path(_relpath(p.resolve(), dst_dir.resolve())).as_posix()
    except ValueError:  # another drive
        return str(p.resolve())


def _relpath(p: Path, start: Path) -> str:
    import os

    return os.path.relpath(p, start)


def write_trees_csv(
    path: str | Path, trees: list[PlotTree], *, src_dir: Path | None = None
) -> Path:
    """Write trees as a trees CSV (atomically); paths relative to its folder."""
    p = Path(path)
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(TREE_COLUMNS)
    for t in trees:
        row = []
        for c in TREE_COLUMNS:
            v = getattr(t, c)
            if c in _PATHS:
                v = _rel(v, src_dir, p.parent)
            elif c in _FLOAT and v is not None:
                v = float(v)
            row.append(_fmt(v))
        w.writerow(row)
    return write_text(p, buf.getvalue())


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise InvalidParameterError(f"cannot write {v} to a plot file")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise InvalidParameterError(f"cannot write {v!r} to a plot file")


def _toml_table(name: str, d: dict[str, Any], array: bool = False) -> list[str]:
    out = ["", f"[[{name}]]" if array else f"[{name}]"]
    sub = []
    for k, v in d.items():
        if v is None:
            continue
        if isinstance(v, dict):
            sub.append((k, v))
            continue
        out.append(f"{k} = {_toml_value(v)}")
    for k, v in sub:
        out += _toml_table(f"{name}.{k}", v)
    return out


def write_plot(
    path: str | Path,
    plot: Plot,
    *,
    trees_csv: str | None = "trees.csv",
    stand: dict[str, Any] | None = None,
) -> Path:
    """Write ``plot`` as a plot file (atomically), with its trees in ``trees_csv`` beside
    it (None: as ``[[trees]]`` tables in the file). ``stand`` is written as the free-form
    ``[stand]`` table (how the stand was made). Paths are rewritten relative to the new
    file's folder. Returns the plot file's path.

    Parameters
    ----------
    path : str or Path
        The plot file to write (``.toml``); its folder must exist.
    plot : Plot
        The plot.
    trees_csv : str or None
        The trees' CSV file, beside the plot file; None writes them into it.
    stand : dict, optional
        How a generated stand was made (``generate_stand``'s second result).

    Examples
    --------
    >>> from pathlib import Path
    >>> import treesim as ts
    >>> plot = ts.Plot([ts.PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species="aspen")])
    >>> Path("stand").mkdir()
    >>> ts.write_plot("stand/plot.toml", plot).name
    'plot.toml'
    """
    p = Path(path)
    if p.suffix.lower() != ".toml":
        raise InvalidParameterError(f"{p}: a plot file is TOML; name it plot.toml")
    if not p.parent.is_dir():
        raise InvalidParameterError(f"{p.parent}: no such folder; make it first")
    src = None if plot.base_dir is None else Path(plot.base_dir)
    lines = [
        "# treesim plot (see the manual: docs/commands/plot.md)",
        f"radius_m = {_toml_value(float(plot.radius_m))}",
        f"centre_xy = {_toml_value([float(v) for v in plot.centre_xy])}",
        f"facets = {int(plot.facets)}",
        f"terrain_cell_m = {_toml_value(float(plot.terrain_cell_m))}",
    ]
    if trees_csv:
        lines.append(f"trees = {_toml_value(trees_csv)}")
    ter = plot.terrain
    lines += _toml_table(
        "terrain",
        {
            "kind": ter.kind,
            "z0_m": float(ter.z0_m),
            "slope_deg": float(ter.slope_deg),
            "aspect_deg": float(ter.aspect_deg),
            "path": _rel(ter.path, Path(ter.base_dir) if ter.base_dir else src, p.parent),
        },
    )
    if stand:
        lines += _toml_table("stand", stand)
    if not trees_csv:
        for t in plot.trees:
            row = {c: getattr(t, c) for c in TREE_COLUMNS}
            for c in _PATHS:
                row[c] = _rel(row[c], src, p.parent)
            for c in _FLOAT:
                if row[c] is not None:
                    row[c] = float(row[c])
            for c in _INT:
                row[c] = int(row[c])
            lines += _toml_table("trees", row, array=True)
    else:
        write_trees_csv(p.parent / trees_csv, list(plot.trees), src_dir=src)
    return write_text(p, "\n".join(lines) + "\n")


def read_plot(path: str | Path) -> Plot:
    """Read a plot file (or the ``plot.toml`` in a folder).

    Parameters
    ----------
    path : str or Path
        The plot file, or a folder holding ``plot.toml``.

    Returns
    -------
    Plot

    Examples
    --------
    >>> from pathlib import Path
    >>> import treesim as ts
    >>> plot = ts.Plot([ts.PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species="aspen")])
    >>> Path("plot").mkdir()
    >>> _ = ts.write_plot("plot/plot.toml", plot)
    >>> ts.read_plot("plot/plot.toml").tree_ids
    [1]
    """
    p = Path(path)
    if p.is_dir():
        p = p / PLOT_FILE
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise InputFormatError(f"{p}: plot file not found; check the path") from None
    except OSError as exc:
        raise InputFormatError(f"{p}: cannot read the plot file ({exc})") from exc
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputFormatError(f"{p}: not a valid TOML plot file ({exc})") from exc
    unknown = sorted(set(doc) - _PLOT_KEYS)
    if unknown:
        raise InputFormatError(
            f"{p}: unknown key(s) {', '.join(unknown)}; a plot file has "
            f"{', '.join(sorted(_PLOT_KEYS))}"
        )
    base = p.parent
    ter_doc = doc.get("terrain", {})
    if not isinstance(ter_doc, dict):
        raise InputFormatError(f"{p}: [terrain] must be a table")
    bad = sorted(set(ter_doc) - _TERRAIN_KEYS)
    if bad:
        raise InputFormatError(
            f"{p}: unknown [terrain] key(s) {', '.join(bad)}; "
            f"use {', '.join(sorted(_TERRAIN_KEYS))}"
        )
    try:
        terrain = Terrain(**ter_doc, base_dir=str(base))
    except (TypeError, InvalidParameterError) as exc:
        raise InputFormatError(
            f"{p}: [terrain]: {exc} (kinds: {', '.join(TERRAIN_KINDS)})"
        ) from exc
    trees_doc = doc.get("trees")
    if trees_doc is None:
        raise InputFormatError(f'{p}: no trees; add trees = "trees.csv" or [[trees]] tables')
    if isinstance(trees_doc, str):
        trees = read_trees_csv(base / trees_doc)
    elif isinstance(trees_doc, list) and all(isinstance(t, dict) for t in trees_doc):
        trees = []
        for i, t in enumerate(trees_doc, start=1):
            extra = sorted(set(t) - set(TREE_COLUMNS))
            if extra:
                raise InputFormatError(
                    f"{p}: [[trees]] {i}: unknown key(s) {', '.join(extra)}; use "
                    f"{', '.join(TREE_COLUMNS)}"
                )
            trees.append(_tree_from_row(t, f"{p}: [[trees]] {i}"))
        if not trees:
            raise InputFormatError(f"{p}: no trees")
    else:
        raise InputFormatError(
            f'{p}: trees must be a CSV name (trees = "trees.csv") or [[trees]] tables'
        )
    kw: dict[str, Any] = {}
    for key in ("radius_m", "terrain_cell_m"):
        if key in doc:
            v = doc[key]
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise InputFormatError(f"{p}: {key} must be a number, got {v!r}")
            kw[key] = float(v)
    if "facets" in doc:
        if isinstance(doc["facets"], bool) or not isinstance(doc["facets"], int):
            raise InputFormatError(f"{p}: facets must be a whole number, got {doc['facets']!r}")
        kw["facets"] = doc["facets"]
    if "centre_xy" in doc:
        c = doc["centre_xy"]
        if not (
            isinstance(c, list)
            and len(c) == 2
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in c)
        ):
            raise InputFormatError(f"{p}: centre_xy must be [x, y] in metres, got {c!r}")
        kw["centre_xy"] = (float(c[0]), float(c[1]))
    try:
        return Plot(trees, terrain=terrain, base_dir=str(base), **kw)
    except TreesimError as exc:
        raise InputFormatError(f"{p}: {exc}") from exc
