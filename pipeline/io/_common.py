"""Helpers shared by the format modules: field columns, metadata text, safe writes."""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..cloud import Cloud
from ..errors import InputFormatError, InvalidGeometryError

#: Prefix of the comment lines (PLY) and of the VLR (LAS) that carry ``Cloud.metadata``.
METADATA_TAG = "treesim"

#: Metadata keys that readers set to describe the file read; writers do not store them.
FILE_METADATA_KEYS = frozenset(
    {"source_path", "las_point_format", "las_version", "las_scales", "las_offsets"}
)

#: Names that cannot be used for fields: they are the coordinates.
COORDINATE_NAMES = frozenset({"x", "y", "z"})


def check_field(name: str, dtype: np.dtype) -> None:
    """Raise unless a field of this name and dtype can be written to a point cloud file.

    Parameters
    ----------
    name : str
        The field's name.
    dtype : numpy.dtype
        The dtype of its values.

    Raises
    ------
    InvalidGeometryError
        If the field is named like a coordinate or is not numeric/boolean.
    """
    if name.lower() in COORDINATE_NAMES:
        raise InvalidGeometryError(
            f"field {name!r} clashes with the coordinate of the same name; rename the field"
        )
    if dtype.kind not in "biuf":
        raise InvalidGeometryError(
            f"field {name!r} has dtype {dtype}; only numeric and boolean fields can be "
            "written to a point cloud file: convert it or drop it from cloud.fields"
        )


def field_columns(cloud: Cloud) -> list[tuple[str, np.ndarray]]:
    """The cloud's fields as 1-D columns, in insertion order.

    A field of shape ``(n, k)`` becomes ``k`` columns named ``name_0`` ... ``name_{k-1}``
    (file formats store scalars per point).

    Parameters
    ----------
    cloud : Cloud
        The cloud whose fields are listed.

    Returns
    -------
    list of (str, (n,) array)
        Column names and values.

    Raises
    ------
    InvalidGeometryError
        If a field is named like a coordinate or is not numeric/boolean.
    """
    n = len(cloud)
    columns: list[tuple[str, np.ndarray]] = []
    for name, values in cloud.fields.items():
        arr = np.asarray(values)
        check_field(name, arr.dtype)
        if arr.ndim == 1:
            columns.append((name, arr))
        else:  # not reshape(n, -1): that fails for n = 0
            flat = arr.reshape(n, int(np.prod(arr.shape[1:])))
            columns.extend((f"{name}_{i}", flat[:, i]) for i in range(flat.shape[1]))
    return columns


def _label_names_from(value: Any) -> dict[int, str] | None:
    """``{code: name}`` from a mapping either way round, or None if it is not one."""
    if not isinstance(value, Mapping) or not value:
        return None
    try:
        return {int(k): str(v) for k, v in value.items()}
    except (TypeError, ValueError):
        pass
    try:  # name -> code, e.g. LABEL_CODES
        return {int(v): str(k) for k, v in value.items()}
    except (TypeError, ValueError):
        return None


def format_label_names(value: Any) -> str | None:
    """``"0=other,1=wood,..."`` for a label-name mapping, or None if it cannot be written so.

    Names containing ``,`` ``=`` line breaks or non-ASCII characters are not written in this
    compact form (callers fall back to JSON).
    """
    names = _label_names_from(value)
    if names is None:
        return None
    parts = []
    for code in sorted(names):
        name = names[code]
        if not name.isascii() or any(c in name for c in ",=\r\n"):
            return None
        parts.append(f"{code}={name}")
    return ",".join(parts)


def parse_label_names(text: str) -> dict[int, str] | None:
    """Inverse of :func:`format_label_names`; None if ``text`` is not of that form."""
    names: dict[int, str] = {}
    for part in text.strip().split(","):
        code, sep, name = part.partition("=")
        if not sep:
            return None
        try:
            names[int(code)] = name
        except ValueError:
            return None
    return names or None


def encode_metadata(metadata: Mapping[str, Any]) -> list[str]:
    """One ``"treesim KEY VALUE"`` line per metadata entry that can be written.

    ``label_names`` is written as ``0=other,1=wood,...``; every other value as JSON.
    Values that are not JSON-serialisable, keys with whitespace and the keys in
    :data:`FILE_METADATA_KEYS` are skipped.
    """
    lines = []
    for key, value in metadata.items():
        key = str(key)
        if not key or any(c.isspace() for c in key) or key in FILE_METADATA_KEYS:
            continue
        text = format_label_names(value) if key == "label_names" else None
        if text is None:
            try:
                text = json.dumps(value, allow_nan=True)
            except (TypeError, ValueError):
                continue
            if key == "label_names":  # JSON object keys are strings: keep the codes
                names = _label_names_from(value)
                text = json.dumps({str(k): v for k, v in names.items()}) if names else text
        lines.append(f"{METADATA_TAG} {key} {text}")
    return lines


def decode_metadata(lines: list[str]) -> dict[str, Any]:
    """Parse the lines written by :func:`encode_metadata`; other lines are ignored."""
    metadata: dict[str, Any] = {}
    for line in lines:
        parts = line.strip().split(maxsplit=2)
        if len(parts) < 3 or parts[0] != METADATA_TAG:
            continue
        key, text = parts[1], parts[2]
        value: Any
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        if key == "label_names":
            if isinstance(value, str):
                value = parse_label_names(value) or value
            elif isinstance(value, dict):
                value = _label_names_from(value) or value
        metadata[key] = value
    return metadata


def write_error(path: Path, exc: OSError) -> InputFormatError:
    """The :class:`InputFormatError` that reports an OS error while writing ``path``."""
    return InputFormatError(
        f"could not write {path}: {exc.strerror or exc}; check that the folder exists "
        "and is writable"
    )


class _Discarded(Exception):
    """Thrown into :func:`~treesim.atomic.atomic_path` to make it drop the temporary file."""


class AtomicFile:
    """:func:`treesim.atomic.atomic_path` held open across calls: commit or discard later.

    For writers whose output outlives one ``with`` block (streaming writers): the
    temporary path is chosen now; :meth:`commit` moves it onto the destination and
    :meth:`discard` removes it, both exactly as :func:`~treesim.atomic.atomic_path` does at
    the end of its ``with`` block. OS errors become :class:`InputFormatError`: a failed
    write leaves no partial file behind (and an existing file untouched).

    Parameters
    ----------
    path : Path
        The destination file; its folder must exist.

    Attributes
    ----------
    tmp : Path
        Where to write the content (``.<name>.<random>.tmp`` beside ``path``).

    Raises
    ------
    InputFormatError
        If the temporary file cannot be created.
    """

    def __init__(self, path: Path) -> None:
        self._path = path
        self._stack = ExitStack()
        with self._mapped_errors():
            self.tmp: Path = self._stack.enter_context(atomic_path(path))

    def commit(self) -> None:
        """Move the temporary file onto the destination."""
        with self._mapped_errors():
            self._stack.close()

    def discard(self) -> None:
        """Remove the temporary file; the destination is left as it was."""
        with self._mapped_errors():
            self._stack.__exit__(_Discarded, _Discarded(), None)

    @contextmanager
    def _mapped_errors(self) -> Iterator[None]:
        try:
            yield
        except OSError as exc:
            raise write_error(self._path, exc) from exc
