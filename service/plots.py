"""Plots for the service: the ``plot`` upload (a zip archive of a plot file and its trees),
and how a job of ``plan`` or ``plot-scan`` gets its plot (:class:`PlotSource`: an archive,
a mesh, a stand the job generates itself, of at most
:data:`treesim.plot.generate.MAX_TREES` trees, or one
procedural tree; :func:`open_plot`).

A plot archive holds ``plot.toml`` at its root or in its one top folder, the trees CSV it
names and every mesh, cylinder table, field cloud or terrain file its trees and terrain
name. It is checked when uploaded and again when a job unpacks it:

* every entry is a plain file or folder under a relative name: no absolute path, no
  drive, no ``..``, no backslash, no link, no name twice;
* at most :data:`MAX_ENTRIES` entries and a stated number of bytes unpacked (the
  upload's limit times :data:`UNPACK_FACTOR`), counted while unpacking;
* ``plot.toml`` reads (:func:`treesim.plot.io.read_plot`), and every path it and its
  trees name is relative, stays inside the archive and is there.

Trees are built only when a job runs: a mesh that does not read fails that job, with
treesim's message.
"""

from __future__ import annotations

import shutil
import stat
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from treesim.errors import (
    EmptyInputError,
    InputFormatError,
    InvalidParameterError,
    ResourceLimitError,
    TreesimError,
)

__all__ = [
    "MAX_ENTRIES",
    "UNPACK_FACTOR",
    "PlotSource",
    "inspect_plot_archive",
    "is_zip",
    "open_plot",
    "unpack_plot",
]

#: Most entries (files and folders) in a plot archive.
MAX_ENTRIES = 10_000
#: A plot archive may unpack to this many times the upload limit.
UNPACK_FACTOR = 4
#: The plot file an archive must hold (:data:`treesim.plot.io.PLOT_FILE`, named here so
#: that the API starts without importing :mod:`treesim.plot`).
PLOT_FILE = "plot.toml"

_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def is_zip(path: str | Path) -> bool:
    """Whether the file starts as a zip archive does (a local header, or an empty
    archive's end record)."""
    with open(path, "rb") as fh:
        return fh.read(4) in _ZIP_MAGIC


def _bad(label: str, why: str) -> InputFormatError:
    return InputFormatError(f"{label}: {why}")


def _entry_parts(name: str, label: str) -> tuple[str, ...]:
    """The folders and name of an archive entry, refused unless it is a plain relative
    name inside the archive."""
    if not name or "\\" in name or "\x00" in name:
        raise _bad(label, f"entry {name!r}: a name with a backslash or NUL is refused")
    p = PurePosixPath(name)
    if p.is_absolute() or (p.parts and ":" in p.parts[0]):
        raise _bad(label, f"entry {name!r}: absolute paths are refused; zip the plot's folder")
    if any(part == ".." for part in p.parts):
        raise _bad(label, f"entry {name!r}: '..' is refused in an archive's names")
    parts = tuple(part for part in p.parts if part != ".")
    if not parts:
        raise _bad(label, f"entry {name!r}: an empty name")
    return parts


def unpack_plot(
    archive: str | Path,
    dest: str | Path,
    *,
    max_bytes: int | None = None,
    label: str | None = None,
) -> Path:
    """Unpack a plot archive into the (new or empty) folder ``dest``, safely (see the
    module notes), and return the path of its ``plot.toml``.

    Raises
    ------
    InputFormatError
        Not a zip archive, a refused entry, no ``plot.toml`` or more than one.
    ResourceLimitError
        More than :data:`MAX_ENTRIES` entries or ``max_bytes`` unpacked.
    """
    label = label or Path(archive).name
    out = Path(dest)
    out.mkdir(parents=True, exist_ok=True)
    root = out.resolve()
    try:
        zf = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError) as exc:
        raise _bad(label, f"not a readable zip archive ({exc})") from None
    with zf:
        infos = zf.infolist()
        if len(infos) > MAX_ENTRIES:
            raise ResourceLimitError(
                f"{label}: {len(infos):,} entries; a plot archive may hold {MAX_ENTRIES:,}"
            )
        declared = sum(i.file_size for i in infos)
        if max_bytes is not None and declared > max_bytes:
            raise ResourceLimitError(
                f"{label}: unpacks to {declared:,} bytes; the limit is {max_bytes:,} "
                f"({UNPACK_FACTOR} x TREESIM_MAX_UPLOAD_BYTES)"
            )
        seen: set[tuple[str, ...]] = set()
        total = 0
        for info in infos:
            parts = _entry_parts(info.filename, label)
            mode = info.external_attr >> 16
            if stat.S_ISLNK(mode):
                raise _bad(label, f"entry {info.filename!r}: links are refused")
            if info.flag_bits & 0x1:
                raise _bad(label, f"entry {info.filename!r}: encrypted entries are refused")
            key = tuple(p.casefold() for p in parts)
            if key in seen:
                raise _bad(label, f"entry {info.filename!r} appears twice")
            seen.add(key)
            target = root.joinpath(*parts)
            if info.is_dir():
                try:
                    target.mkdir(parents=True, exist_ok=True)
                except OSError:
                    raise _bad(label, f"entry {info.filename!r} clashes with a file") from None
                continue
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                with zf.open(info) as src, open(target, "xb") as dst:
                    while chunk := src.read(1 << 20):
                        total += len(chunk)
                        if max_bytes is not None and total > max_bytes:
                            raise ResourceLimitError(
                                f"{label}: unpacks to more than {max_bytes:,} bytes "
                                f"({UNPACK_FACTOR} x TREESIM_MAX_UPLOAD_BYTES)"
                            )
                        dst.write(chunk)
            except FileExistsError:
                raise _bad(label, f"entry {info.filename!r} clashes with another") from None
            except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError) as exc:
                raise _bad(label, f"entry {info.filename!r} cannot be unpacked ({exc})") from None
            except (EOFError, OSError, ValueError) as exc:  # zlib errors are ValueError kin
                raise _bad(label, f"entry {info.filename!r} is corrupt ({exc})") from None
    found = [root / PLOT_FILE] if (root / PLOT_FILE).is_file() else []
    if not found:
        tops = [p for p in root.iterdir() if p.is_dir() and not p.name.startswith("__MACOSX")]
        found = [p / PLOT_FILE for p in tops if (p / PLOT_FILE).is_file()]
    if not found:
        raise _bad(
            label,
            f"no {PLOT_FILE} at the archive's root or in its top folder; zip the folder "
            "that treesim plot generate wrote (plot.toml, trees.csv and the trees' files)",
        )
    if len(found) > 1:
        names = ", ".join(sorted(p.relative_to(root).as_posix() for p in found))
        raise _bad(label, f"more than one plot file ({names}); upload one plot per archive")
    return found[0]


def _inside(root: Path, base: Path, rel: str, what: str, label: str) -> None:
    p = Path(rel)
    if p.is_absolute():
        raise _bad(label, f"{what} {rel!r} is an absolute path; name files inside the archive")
    q = (base / p).resolve()
    if not q.is_relative_to(root):
        raise _bad(label, f"{what} {rel!r} points outside the archive")
    if not q.is_file():
        raise _bad(label, f"{what} {rel!r} is not in the archive")


def read_unpacked_plot(plot_file: Path, root: Path, label: str) -> Any:
    """The plot of an unpacked archive, once every path it names is checked to be a file
    inside ``root``; errors name the archive, never the folder it was unpacked into."""
    import tomllib

    from treesim.plot.io import read_plot

    root = root.resolve()
    shown = plot_file.relative_to(root).as_posix()
    base = plot_file.parent.resolve()

    def clean(exc: TreesimError) -> str:
        text = str(exc).replace(str(base) + "/", "").replace(str(root) + "/", "")
        return text.replace(str(base), ".").replace(str(root), ".")

    try:
        try:
            doc = tomllib.loads(plot_file.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, tomllib.TOMLDecodeError):
            doc = {}  # read_plot says what is wrong with it
        if isinstance(doc.get("trees"), str):
            _inside(root, base, doc["trees"], f"{shown}: trees", label)
        ter = doc.get("terrain")
        if isinstance(ter, dict) and isinstance(ter.get("path"), str):
            _inside(root, base, ter["path"], f"{shown}: terrain path", label)
        plot = read_plot(plot_file)
        for t in plot.trees:
            if t.path:
                _inside(root, base, str(t.path), f"{shown}: tree {t.tree_id}'s path", label)
            if t.field_cloud:
                _inside(
                    root,
                    base,
                    str(t.field_cloud),
                    f"{shown}: tree {t.tree_id}'s field_cloud",
                    label,
                )
    except InputFormatError as exc:
        msg = clean(exc)
        raise InputFormatError(msg if msg.startswith(label) else f"{label}: {msg}") from None
    except TreesimError as exc:
        raise type(exc)(f"{label}: {clean(exc)}") from None
    return plot


def inspect_plot_archive(
    path: str | Path,
    filename: str | None = None,
    *,
    max_bytes: int | None = None,
    work_dir: str | Path | None = None,
) -> dict[str, Any]:
    """Check an uploaded plot archive (unpacked into a temporary folder inside
    ``work_dir``, by default the archive's own folder, never the system's temp folder;
    streamed, never more than ``max_bytes`` on disk; then removed): the facts an upload
    records (``format`` zip, ``kind`` plot, ``n_trees``, ``bounds``: the plot's square
    around its centre, at its terrain's height there)."""
    label = filename or Path(path).name
    if Path(path).stat().st_size == 0:
        raise EmptyInputError(f"{label}: the body is empty; send the file's bytes")
    where = Path(work_dir) if work_dir is not None else Path(path).resolve().parent
    with tempfile.TemporaryDirectory(prefix="treesim-plot-", dir=where) as tmp:
        plot_file = unpack_plot(path, tmp, max_bytes=max_bytes, label=label)
        plot = read_unpacked_plot(plot_file, Path(tmp), label)
        cx, cy = plot.centre_xy
        r = plot.radius_m
        z = float(plot.terrain.z0_m)
        return {
            "format": "zip",
            "kind": "plot",
            "suffix": ".zip",
            "n_trees": len(plot.trees),
            "bounds": [[cx - r, cy - r, z], [cx + r, cy + r, z]],
            "fields": [],
        }


# -- where a job's plot comes from ---------------------------------------------------------------
@dataclass(frozen=True)
class PlotSource:
    """One of: a plot archive (input ``plot``), a tree mesh (input ``mesh``), a generated
    stand (``stand``, a :class:`treesim.plot.generate.StandParams` of at most
    :data:`treesim.plot.generate.MAX_TREES` trees), one procedural tree (``tree``;
    ``radius_m`` the candidate area)."""

    stand: Any = None  # StandParams
    tree: Any = None  # ModelParams
    radius_m: float | None = None

    def __post_init__(self) -> None:
        st = self.stand
        if st is None:
            return
        # refused when the job is submitted, not when it runs (imported here: the stand's
        # StandParams already loaded the module; the API's start-up does not)
        from treesim.plot.generate import MAX_TREES

        if st.expected_trees > MAX_TREES:
            exc = InvalidParameterError(
                f"stems_per_ha {st.stems_per_ha:g} on a {st.radius_m:g} m plot is "
                f"{st.expected_trees:,.0f} trees; a generated stand has at most {MAX_TREES:,}"
            )
            exc.field = "stand"  # type: ignore[attr-defined]
            raise exc

    def given(self, inputs: set[str] | frozenset[str]) -> list[str]:
        out = [f"inputs.{n}" for n in ("plot", "mesh") if n in inputs]
        if self.stand is not None:
            out.append("parameters.stand")
        if self.tree is not None:
            out.append("parameters.tree")
        return out

    def check(self, inputs: set[str] | frozenset[str]) -> None:
        """Exactly one source, and ``radius_m`` for one tree only (raises
        :class:`InvalidParameterError` with ``field``)."""
        given = self.given(inputs)
        if len(given) != 1:
            exc = InvalidParameterError(
                "give one of: inputs.plot (a plot archive), inputs.mesh (one tree), "
                "parameters.stand (a stand to generate) or parameters.tree (one procedural "
                "tree)" + (f"; got {', '.join(given)}" if given else "")
            )
            exc.field = given[1] if len(given) > 1 else "inputs.plot"  # type: ignore[attr-defined]
            raise exc
        if self.radius_m is not None and given[0] in ("inputs.plot", "parameters.stand"):
            exc = InvalidParameterError(
                "radius_m is for one tree (inputs.mesh or parameters.tree); a plot has its "
                "own radius (parameters.stand.radius_m for a generated stand)"
            )
            exc.field = "parameters.radius_m"  # type: ignore[attr-defined]
            raise exc


@contextmanager
def open_plot(
    source: PlotSource, inputs: Mapping[str, Path], out: Path
) -> Iterator[tuple[Any, bool, dict[str, Any]]]:
    """``(plot, single_tree, what)`` for a job: ``what`` says where the plot came from
    (for the job's JSON). A plot archive is unpacked into a hidden folder of the job's
    output folder, removed when the block ends (a killed job's attempt folder goes
    whole); a generated stand's files are written to ``stand/`` among the results."""
    from treesim.plan.sources import mesh_tree_plot, model_tree_plot

    source.check(set(inputs))
    if "plot" in inputs:
        work = out / ".plot"
        try:
            plot_file = unpack_plot(inputs["plot"], work, label="the plot archive")
            plot = read_unpacked_plot(plot_file, work, "the plot archive")
            yield plot, False, {"plot": inputs["plot"].name}
        finally:
            shutil.rmtree(work, ignore_errors=True)
        return
    if "mesh" in inputs:
        yield mesh_tree_plot(inputs["mesh"], radius_m=source.radius_m), True, {"mesh": "input"}
        return
    if source.stand is not None:
        from treesim.plot.io import write_plot

        plot, stand = source.stand.generate()
        (out / "stand").mkdir(parents=True, exist_ok=True)
        write_plot(out / "stand" / PLOT_FILE, plot, stand=stand)
        yield plot, False, {"stand": {**asdict(source.stand), "trees": len(plot.trees)}}
        return
    plot, what = model_tree_plot(source.tree, radius_m=source.radius_m)
    yield plot, True, what
