"""Delimited text point clouds: ``.xyz``, ``.txt``, ``.csv``, ``.asc``, ``.pts``.

Layout read
-----------
* Values separated by whitespace, or by commas (or semicolons) when the first data line
  contains one.
* Blank lines and ``#`` comments are ignored.
* An optional header line of column names (recognised because it is not numeric); names
  are lower-cased and stripped of quotes and a leading ``//`` (CloudCompare). The header
  must name ``x``, ``y`` and ``z``; the other columns become fields.
* Without a header the first three columns are x, y, z and column ``i`` (0-based) of the
  rest becomes the field ``col{i}`` (``col3``, ``col4``, ...).
* A leading line holding a single integer (the point count of Leica ``.pts``) is skipped.

All values are read as float64. ``nan`` values are kept (``Cloud.validate`` reports the
rows); a line that is not numeric, or has the wrong number of values, is an error that
names the line.

Layout written
--------------
A header line ``x y z field...`` then one line per point; commas for ``.csv``, spaces
otherwise. Coordinates are written with 9 decimals (1 nm: float64 coordinates of
georeferenced data round-trip to better than 1e-9 m), float64 fields with 15 significant
digits, float32 fields with 9 (exact), integer and boolean fields as integers.
Metadata is not written: use PLY or LAS/LAZ to keep it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import DTypeLike

from ..cloud import Cloud
from ..errors import InputFormatError, InvalidGeometryError
from ._common import field_columns
from .writer import CloudWriter

#: Suffixes handled by this module.
SUFFIXES: tuple[str, ...] = (".xyz", ".txt", ".csv", ".asc", ".pts")

#: How many leading lines are searched for the header / first data line.
_MAX_PREAMBLE_LINES = 10_000

#: Rows formatted per chunk when writing.
_WRITE_CHUNK = 100_000


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _strip_comment(line: str) -> str:
    return line.split("#", 1)[0].strip()


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return [t.strip() for t in line.split(delimiter)]


def _detect_delimiter(line: str) -> str | None:
    for delimiter in (",", ";"):
        if delimiter in line:
            return delimiter
    return None


def _clean_name(token: str) -> str:
    name = token.strip().strip("\"'").lstrip("/").strip().lower()
    return name


def _preamble(path: Path) -> tuple[int, str | None, list[str] | None, int | None, str | None]:
    """Scan the leading lines.

    Returns
    -------
    tuple
        ``(skip, delimiter, header, first_data_line_no, first_data_line)``: the number of
        lines before the data (header and count line included), the delimiter (None for
        whitespace), the header tokens or None, and the 1-based number and text of the
        first data line (None if the file has no data).
    """
    header_line: str | None = None
    skip = 0
    seen_content = False
    with open(path, encoding="utf-8-sig") as stream:
        for line_no, raw in enumerate(stream, start=1):
            if line_no > _MAX_PREAMBLE_LINES:
                break
            line = _strip_comment(raw)
            if not line:
                continue
            tokens = line.replace(",", " ").replace(";", " ").split()
            if all(_is_number(t) for t in tokens):
                if not seen_content and len(tokens) == 1 and tokens[0].isdigit():
                    seen_content = True  # point count of a .pts file
                    skip = line_no
                    continue
                delimiter = _detect_delimiter(line)
                header = _split(header_line, delimiter) if header_line is not None else None
                return skip, delimiter, header, line_no, line
            if header_line is not None:
                raise InputFormatError(
                    f"{path}: line {line_no} is not numeric ({line[:80]!r}) and a header "
                    "line was already read; remove the extra line"
                )
            header_line = line
            seen_content = True
            skip = line_no
    if header_line is None:
        return skip, None, None, None, None
    delimiter = _detect_delimiter(header_line)
    return skip, delimiter, _split(header_line, delimiter), None, None


def _column_names(
    path: Path, ncols: int, header: list[str] | None, columns: Sequence[str | None] | None
) -> list[str | None]:
    if columns is not None:
        names = [None if c is None else str(c).strip().lower() for c in columns]
        source = "columns="
    elif header is not None:
        names = [_clean_name(t) for t in header]
        source = "the header line"
    else:
        return ["x", "y", "z"] + [f"col{i}" for i in range(3, ncols)]
    if len(names) != ncols:
        raise InputFormatError(
            f"{path}: {source} names {len(names)} columns but the data has {ncols}; "
            "give one name per column (None to skip a column)"
        )
    given = [n for n in names if n]
    duplicates = sorted({n for n in given if given.count(n) > 1})
    if duplicates:
        raise InputFormatError(f"{path}: {source} repeats the column names {duplicates}")
    missing = [c for c in ("x", "y", "z") if c not in given]
    if missing:
        raise InputFormatError(
            f"{path}: {source} does not name the coordinate columns {missing} "
            f"(names: {names}); pass columns=['x', 'y', 'z', ...] to name the columns"
        )
    return names


def _locate_bad_line(path: Path, skip: int, delimiter: str | None, ncols: int) -> str:
    """Describe the first data line that is not ``ncols`` numbers."""
    with open(path, encoding="utf-8-sig", errors="replace") as stream:
        for line_no, raw in enumerate(stream, start=1):
            if line_no <= skip:
                continue
            line = _strip_comment(raw)
            if not line:
                continue
            tokens = _split(line, delimiter)
            if len(tokens) != ncols:
                return (
                    f"line {line_no} has {len(tokens)} values where the first data line has "
                    f"{ncols} ({line[:80]!r})"
                )
            bad = next((t for t in tokens if not _is_number(t)), None)
            if bad is not None:
                return f"line {line_no} is not numeric: {bad!r} in {line[:80]!r}"
    return "a line could not be parsed"


def read_text(path: str | Path, *, columns: Sequence[str | None] | None = None) -> Cloud:
    """Read a delimited text point cloud.

    Parameters
    ----------
    path : str or Path
        The file (``.xyz``, ``.txt``, ``.csv``, ``.asc``, ``.pts``).
    columns : sequence of str or None, optional
        One name per column, overriding the header (or the default ``x y z col3 ...``).
        Must name ``x``, ``y`` and ``z``; ``None`` skips a column. Names are lower-cased.

    Returns
    -------
    Cloud
        ``points`` (n, 3) float64; each other named column is a (n,) float64 field.
        ``metadata["source_path"]`` is the path read.

    Raises
    ------
    InputFormatError
        If the file cannot be decoded, a line is not numeric or has the wrong number of
        values (the message names the line), or the columns are misnamed.
    """
    path = Path(path)
    try:
        skip, delimiter, header, first_no, first_line = _preamble(path)
    except UnicodeDecodeError as exc:
        raise InputFormatError(
            f"{path} is not a UTF-8 text file ({exc.reason} at byte {exc.start}); "
            "is the suffix right?"
        ) from exc
    metadata = {"source_path": str(path)}

    if first_line is None:  # header only, or nothing at all
        ncols = len(header) if header is not None else (len(columns) if columns else 3)
        names = _column_names(path, ncols, header, columns)
        fields = {n: np.empty(0) for n in names if n and n not in ("x", "y", "z")}
        return Cloud(np.empty((0, 3)), fields, metadata)

    ncols = len(_split(first_line, delimiter))
    if ncols < 3:
        raise InputFormatError(
            f"{path}: line {first_no} has {ncols} value(s); a point needs at least x y z"
        )
    names = _column_names(path, ncols, header, columns)
    try:
        data = np.loadtxt(
            path,
            dtype=np.float64,
            delimiter=delimiter,
            comments="#",
            skiprows=skip,
            ndmin=2,
            encoding="utf-8-sig",
        )
    except (ValueError, UnicodeDecodeError) as exc:
        where = _locate_bad_line(path, skip, delimiter, ncols)
        raise InputFormatError(
            f"{path}: {where}; fix or remove that line (every data line must hold {ncols} numbers)"
        ) from exc
    if data.shape[1] != ncols:  # cannot happen with loadtxt, kept as a guard
        raise InputFormatError(f"{path}: expected {ncols} columns, read {data.shape[1]}")

    index = {n: i for i, n in enumerate(names) if n}
    points = data[:, [index["x"], index["y"], index["z"]]]
    fields = {
        n: np.ascontiguousarray(data[:, i])
        for i, n in enumerate(names)
        if n and n not in ("x", "y", "z")
    }
    return Cloud(points, fields, metadata)


def _format_for(dtype: np.dtype) -> str:
    """The printf format of a column of ``dtype``."""
    if dtype.kind in "biu":
        return "%d"
    if dtype.itemsize <= 4:
        return "%.9g"
    return "%.15g"


class TextCloudWriter(CloudWriter):
    """Stream points into a delimited text file, one line per point.

    What :func:`write_text` writes, in chunks (see :class:`~treesim.io.writer.CloudWriter`
    for the protocol): the header line ``x y z field...`` when opened, then each chunk's
    rows as they come, formatted :data:`_WRITE_CHUNK` rows at a time.

    Parameters
    ----------
    path : str or Path
        Destination; ``.csv`` is written comma-separated, other suffixes space-separated.
    fields : mapping of str -> dtype
        One column each, formatted by dtype (see the module docstring).
    metadata : mapping, optional
        Ignored: text files do not store metadata.

    Raises
    ------
    InvalidGeometryError
        If a field name contains the delimiter or whitespace, or a field is not numeric.
    InputFormatError
        If the file cannot be written.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        fields: Mapping[str, DTypeLike],
        metadata: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__(path, fields, metadata)
        for name in self._fields:
            if not name or any(c.isspace() or c in ",;#" for c in name):
                raise InvalidGeometryError(
                    f"field name {name!r} cannot be written to a text header (it contains "
                    "whitespace, ',', ';' or '#'); rename the field"
                )
        self._delimiter = "," if self.path.suffix.lower() == ".csv" else " "
        self._row = self._delimiter.join(
            ["%.9f"] * 3 + [_format_for(dtype) for dtype in self._fields.values()]
        )
        self._stream: TextIO | None = None
        self._start()

    def _open(self, tmp: Path) -> None:
        self._stream = open(tmp, "w", encoding="utf-8", newline="\n")
        self._stream.write(self._delimiter.join(["x", "y", "z", *self._fields]) + "\n")

    def _write(self, points: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        values = [points[:, 0], points[:, 1], points[:, 2]]
        values += [v.astype(np.int64) if v.dtype.kind == "b" else v for v in columns.values()]
        assert self._stream is not None
        for start in range(0, len(points), _WRITE_CHUNK):
            chunk = [v[start : start + _WRITE_CHUNK].tolist() for v in values]
            self._stream.write("\n".join(self._row % row for row in zip(*chunk, strict=True)))
            self._stream.write("\n")

    def _finish(self) -> None:
        assert self._stream is not None
        self._stream.close()

    def _discard(self) -> None:
        if self._stream is not None:
            self._stream.close()


def write_text(path: str | Path, cloud: Cloud) -> Path:
    """Write a delimited text point cloud with a header line.

    One chunk through :class:`TextCloudWriter`.

    Parameters
    ----------
    path : str or Path
        Destination; ``.csv`` is written comma-separated, other suffixes space-separated.
    cloud : Cloud
        The points and fields to write (metadata is not written); may be empty (the file
        then holds the header line only).

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    InvalidGeometryError
        If a field name contains the delimiter or whitespace, or a field is not numeric.
    InputFormatError
        If the file cannot be written.
    """
    columns = dict(field_columns(cloud))
    writer = TextCloudWriter(path, fields={name: values.dtype for name, values in columns.items()})
    with writer:
        writer.write(cloud.points, columns)
    return writer.path
