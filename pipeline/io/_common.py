"""Helpers shared by the format modules: field columns, metadata text, safe writes."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

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
        if name.lower() in COORDINATE_NAMES:
            raise InvalidGeometryError(
                f"field {name!r} clashes with the coordinate of the same name; rename the field"
            )
        if arr.dtype.kind not in "biuf":
            raise InvalidGeometryError(
                f"field {name!r} has dtype {arr.dtype}; only numeric and boolean fields can be "
                "written to a point cloud file: convert it or drop it from cloud.fields"
            )
        flat = arr.reshape(n, -1)
        if arr.ndim == 1:
            columns.append((name, arr))
        else:
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


@contextmanager
def atomic_output(path: Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; move it onto ``path`` on success.

    :func:`pipeline.atomic.atomic_path` with OS errors mapped to
    :class:`InputFormatError`: a failed write leaves no partial file behind (and an
    existing file untouched).
    """
    try:
        with atomic_path(path) as tmp:
            yield tmp
    except OSError as exc:
        raise InputFormatError(
            f"could not write {path}: {exc.strerror or exc}; check that the folder exists "
            "and is writable"
        ) from exc


def write_binary(path: Path, write: Callable[[BinaryIO], None]) -> None:
    """Write through ``write(stream)`` to ``path`` atomically (see :func:`atomic_output`)."""
    with atomic_output(path) as tmp, open(tmp, "wb") as stream:
        write(stream)
