"""LAS and LAZ point clouds, through laspy (LAZ with the lazrs backend).

Reading gives float64 coordinates (scaled and offset), the standard dimensions
``intensity``, ``return_number``, ``number_of_returns``, ``classification`` and, when the
point format has it, ``gps_time``; any other standard dimension that is not all zero
(``user_data``, ``point_source_id``, ``red``, ...), and every extra dimension under its
own name and dtype.

Writing uses point format 6 (LAS 1.4) with the same scale on every axis (``las_scale_m``,
0.1 mm by default) and offsets at the floor of the per-axis minimum, so georeferenced
coordinates keep the scale's precision. Fields named like a format-6 standard dimension
go there (cast to its type: ``intensity`` rounded and clipped to 0..65535,
``return_number`` / ``number_of_returns`` clipped to 1..15, ``classification`` to 0..255);
every other field becomes an extra dimension with its own name and dtype (bool as uint8)
and a short description. ``Cloud.metadata`` is stored as JSON in a VLR (user id
``treesim``) and ``label_names`` also in the description of the ``label`` dimension
(``0=other,1=wood,2=leaf,3=ground``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import laspy
import numpy as np

from ..cloud import Cloud
from ..errors import InputFormatError, InvalidGeometryError, InvalidParameterError
from ._common import (
    FILE_METADATA_KEYS,
    METADATA_TAG,
    field_columns,
    format_label_names,
    parse_label_names,
)
from ._common import write_binary as _write_binary

#: Suffixes handled by this module.
SUFFIXES: tuple[str, ...] = (".las", ".laz")

#: Point format and LAS version written.
POINT_FORMAT = 6
LAS_VERSION = "1.4"

#: Standard dimensions always read (``gps_time`` only if the point format has it).
CORE_DIMENSIONS = ("intensity", "return_number", "number_of_returns", "classification")

#: Record id of the VLR that holds ``Cloud.metadata`` as JSON (user id ``treesim``).
METADATA_RECORD_ID = 1

#: LAS limits on the length of extra-dimension names and descriptions (bytes).
_NAME_MAX = 32
_DESCRIPTION_MAX = 32
_VLR_MAX = 65_535

#: Standard dimensions that are not read or written as fields (coordinates, raw ints).
_SKIP_STANDARD = {"X", "Y", "Z"}

#: Clipping ranges for fields written to standard dimensions (others: the dtype's range).
_STANDARD_RANGES: dict[str, tuple[float, float]] = {
    "return_number": (1, 15),
    "number_of_returns": (1, 15),
}

#: Descriptions of the extra dimensions treesim writes (others get a generic one).
_DESCRIPTIONS: dict[str, str] = {
    "station": "scanner station index",
    "range_m": "range from the scanner (m)",
    "incidence_deg": "incidence angle (degrees)",
    "label": "hit part label",
    "scan_line": "scan line index",
    "scan_column": "scan column index",
    "beam_divergence": "beam divergence",
    "reflectance": "reflectance",
}

_LAZ_BACKEND = laspy.LazBackend.Lazrs


def _backends() -> tuple[laspy.LazBackend, ...]:
    available = laspy.LazBackend.detect_available()
    return tuple(available) or (_LAZ_BACKEND,)


def _check_header(path: Path) -> None:
    """Refuse a LAS/LAZ whose header contradicts the file's size before laspy reads it
    (laspy trusts the header's VLR count and can loop for ever on garbage)."""
    import struct

    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(227)
    except OSError as exc:
        raise InputFormatError(f"{path}: cannot be read ({exc.strerror})") from exc
    if len(head) < 227 or head[:4] != b"LASF":
        raise InputFormatError(f"{path}: not a LAS/LAZ file (no LASF header); is it complete?")
    header_size, point_offset, n_vlrs = struct.unpack_from("<HII", head, 94)
    if header_size < 227 or point_offset > size or point_offset < header_size:
        raise InputFormatError(
            f"{path}: corrupt LAS header (point data offset {point_offset} in a {size}-byte file)"
        )
    if n_vlrs * 54 > point_offset - header_size:
        raise InputFormatError(
            f"{path}: corrupt LAS header ({n_vlrs} variable-length "
            "records cannot fit before the point data)"
        )


def read_las(path: str | Path) -> Cloud:
    """Read a LAS or LAZ file.

    Parameters
    ----------
    path : str or Path
        The ``.las`` or ``.laz`` file.

    Returns
    -------
    Cloud
        ``points`` (n, 3) float64 (scaled and offset); fields as described in the module
        docstring; ``metadata`` from the treesim VLR if any, plus ``source_path``,
        ``las_point_format``, ``las_version``, ``las_scales`` and ``las_offsets``.

    Raises
    ------
    InputFormatError
        If laspy cannot read the file (corrupt, truncated, no LAZ backend).
    """
    path = Path(path)
    _check_header(path)
    try:
        las = laspy.read(path, laz_backend=_backends())
        header = las.header
        scales = np.asarray(header.scales, dtype=np.float64)
        offsets = np.asarray(header.offsets, dtype=np.float64)
        raw = np.column_stack([np.asarray(las.X), np.asarray(las.Y), np.asarray(las.Z)]).astype(
            np.float64
        )
        points = raw * scales + offsets

        fmt = las.point_format
        fields: dict[str, np.ndarray] = {}
        standard = [d for d in fmt.standard_dimension_names if d not in _SKIP_STANDARD]
        for name in standard:
            values = np.array(las[name])
            if name in CORE_DIMENSIONS or name == "gps_time" or np.any(values):
                fields[name] = values
        descriptions: dict[str, str] = {}
        for dim in fmt.extra_dimensions:
            fields[dim.name] = np.array(las[dim.name])
            descriptions[dim.name] = dim.description or ""
        vlrs = list(las.vlrs) + list(getattr(las, "evlrs", None) or [])
        version = str(header.version)
        point_format_id = fmt.id
    except laspy.errors.LaspyException as exc:
        raise InputFormatError(
            f"{path} could not be read as LAS/LAZ ({exc}); check that the file is complete "
            "and really LAS/LAZ"
        ) from exc
    except (OSError, ValueError, EOFError, RuntimeError) as exc:
        raise InputFormatError(f"{path} could not be read as LAS/LAZ: {exc}") from exc

    metadata: dict[str, Any] = {}
    for vlr in vlrs:
        if getattr(vlr, "user_id", "") == METADATA_TAG and vlr.record_id == METADATA_RECORD_ID:
            try:
                stored = json.loads(bytes(vlr.record_data).decode("utf-8"))
            except (ValueError, UnicodeDecodeError):
                continue
            if isinstance(stored, dict):
                metadata.update(stored)
    if "label_names" in metadata and isinstance(metadata["label_names"], dict):
        try:
            metadata["label_names"] = {int(k): v for k, v in metadata["label_names"].items()}
        except ValueError:
            pass
    elif "label" in descriptions:
        names = parse_label_names(descriptions["label"])
        if names:
            metadata["label_names"] = names
    metadata.update(
        source_path=str(path),
        las_point_format=int(point_format_id),
        las_version=version,
        las_scales=scales.tolist(),
        las_offsets=offsets.tolist(),
    )
    return Cloud(points, fields, metadata)


def _standard_targets() -> dict[str, tuple[np.dtype, float, float]]:
    """Format-6 standard dimensions fields may fill: name -> (dtype, lowest, highest)."""
    targets: dict[str, tuple[np.dtype, float, float]] = {}
    for dim in laspy.PointFormat(POINT_FORMAT).dimensions:
        if dim.name in _SKIP_STANDARD:
            continue
        if dim.kind == laspy.DimensionKind.BitField:
            dtype, lo, hi = np.dtype(np.uint8), 0.0, float(2**dim.num_bits - 1)
        elif dim.kind == laspy.DimensionKind.FloatingPoint:
            dtype, lo, hi = np.dtype(dim.dtype), -np.inf, np.inf
        else:
            info = np.iinfo(dim.dtype)
            dtype, lo, hi = np.dtype(dim.dtype), float(info.min), float(info.max)
        lo, hi = _STANDARD_RANGES.get(dim.name, (lo, hi))
        targets[dim.name] = (dtype, lo, hi)
    return targets


def _to_standard(values: np.ndarray, dtype: np.dtype, lo: float, hi: float) -> np.ndarray:
    """Cast a field to the type of a standard dimension, rounding and clipping."""
    values = np.asarray(values)
    if dtype.kind == "f":
        return values.astype(dtype)
    values = values.astype(np.float64)
    values = np.nan_to_num(np.rint(values), nan=lo, posinf=hi, neginf=lo)
    return np.clip(values, lo, hi).astype(dtype)


def _extra_dtype(values: np.ndarray) -> np.dtype:
    """The dtype an extra dimension stores ``values`` in (bool as uint8, half as float32)."""
    dtype = values.dtype
    if dtype.kind == "b":
        return np.dtype(np.uint8)
    if dtype.kind == "f" and dtype.itemsize < 4:
        return np.dtype(np.float32)
    return dtype.newbyteorder("<") if dtype.byteorder == ">" else dtype


def _description(name: str, metadata: dict[str, Any]) -> str:
    if name == "label":
        text = format_label_names(metadata.get("label_names"))
        if text and len(text) <= _DESCRIPTION_MAX:
            return text
    text = _DESCRIPTIONS.get(name, f"treesim field {name}")
    return text.encode("ascii", "replace").decode("ascii")[:_DESCRIPTION_MAX]


def _metadata_vlr(metadata: dict[str, Any]) -> laspy.VLR | None:
    """The metadata as a JSON VLR.

    Entries that are not JSON-serialisable or describe the file read
    (:data:`FILE_METADATA_KEYS`) are dropped; so is all of it if it exceeds a VLR's 64 KiB.
    """
    kept: dict[str, Any] = {}
    for key, value in metadata.items():
        if key in FILE_METADATA_KEYS:
            continue
        if key == "label_names" and isinstance(value, dict):
            value = {str(k): v for k, v in value.items()}
        try:
            json.dumps(value)
        except (TypeError, ValueError):
            continue
        kept[str(key)] = value
    if not kept:
        return None
    data = json.dumps(kept).encode("utf-8")
    if len(data) > _VLR_MAX:
        return None
    return laspy.VLR(
        user_id=METADATA_TAG,
        record_id=METADATA_RECORD_ID,
        description="treesim metadata (JSON)",
        record_data=data,
    )


def _integer_coordinates(points: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (floor of the per-axis minimum) and the (n, 3) int32 scaled coordinates."""
    if len(points) == 0:
        return np.zeros(3), np.empty((0, 3), dtype=np.int32)
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        first = int(np.flatnonzero(~finite)[0])
        raise InvalidGeometryError(
            f"{int((~finite).sum())} points have NaN or infinite coordinates (first at row "
            f"{first}); LAS cannot store them: drop those rows before writing"
        )
    offsets = np.floor(points.min(axis=0))
    counts = np.rint((points - offsets) / scale)
    limit = np.iinfo(np.int32).max
    span = counts.max(axis=0)
    if (span > limit).any():
        extent = points.max(axis=0) - offsets
        raise InvalidGeometryError(
            f"the cloud extends {extent.max():.6g} m from its minimum, which does not fit "
            f"LAS's 32-bit integers at las_scale_m={scale:g} (at most {limit * scale:.6g} m); "
            "use a coarser las_scale_m"
        )
    return offsets, counts.astype(np.int32)


def write_las(path: str | Path, cloud: Cloud, *, las_scale_m: float = 1e-4) -> Path:
    """Write a LAS (``.las``) or LAZ (``.laz``) file, point format 6 (LAS 1.4).

    Parameters
    ----------
    path : str or Path
        Destination; compressed when the suffix is ``.laz`` (any case).
    cloud : Cloud
        The points, fields and metadata to write.
    las_scale_m : float, optional
        Coordinate resolution in metres (the LAS scale, same on every axis).

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    InvalidParameterError
        If ``las_scale_m`` is not a positive finite number.
    InvalidGeometryError
        If coordinates are not finite, the extent does not fit int32 at ``las_scale_m``,
        or a field cannot be stored (non-numeric, name longer than 32 bytes).
    InputFormatError
        If laspy or the file system fails to write the file.
    """
    path = Path(path)
    scale = float(las_scale_m)
    if not np.isfinite(scale) or scale <= 0:
        raise InvalidParameterError(
            f"las_scale_m must be a positive number of metres, got {las_scale_m!r}"
        )
    offsets, ints = _integer_coordinates(cloud.points, scale)
    columns = field_columns(cloud)

    standard = _standard_targets()
    extras: list[laspy.ExtraBytesParams] = []
    for name, values in columns:
        if name in standard:
            continue
        if not name.isascii() or len(name.encode()) > _NAME_MAX:
            raise InvalidGeometryError(
                f"field name {name!r} cannot be a LAS extra dimension (ASCII, at most "
                f"{_NAME_MAX} characters); rename the field"
            )
        extras.append(
            laspy.ExtraBytesParams(
                name=name,
                type=_extra_dtype(values),
                description=_description(name, cloud.metadata),
            )
        )

    try:
        header = laspy.LasHeader(point_format=POINT_FORMAT, version=LAS_VERSION)
        if extras:
            header.add_extra_dims(extras)
        header.scales = np.array([scale, scale, scale])
        header.offsets = offsets
        vlr = _metadata_vlr(cloud.metadata)
        if vlr is not None:
            header.vlrs.append(vlr)
        record = laspy.ScaleAwarePointRecord.zeros(len(cloud), header=header)
        las = laspy.LasData(header, points=record)
        las.X = ints[:, 0]
        las.Y = ints[:, 1]
        las.Z = ints[:, 2]
        names = {name for name, _ in columns}
        if len(cloud):
            for default in ("return_number", "number_of_returns"):
                if default not in names:
                    las[default] = np.ones(len(cloud), dtype=np.uint8)
        for name, values in columns:
            if name in standard:
                las[name] = _to_standard(values, *standard[name])
            else:
                las[name] = values.astype(_extra_dtype(values), copy=False)
        compress = path.suffix.lower() == ".laz"
        _write_binary(
            path,
            lambda stream: las.write(stream, do_compress=compress, laz_backend=_backends()),
        )
    except laspy.errors.LaspyException as exc:
        raise InputFormatError(f"could not write {path} as LAS/LAZ: {exc}") from exc
    return path
