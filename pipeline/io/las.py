"""LAS and LAZ point clouds, through laspy (LAZ with the lazrs backend).

Reading gives float64 coordinates (scaled and offset), the standard dimensions
``intensity``, ``return_number``, ``number_of_returns``, ``classification`` and, when the
point format has it, ``gps_time``; any other standard dimension that is not all zero
(``user_data``, ``point_source_id``, ``red``, ...), and every extra dimension under its
own name and dtype.

Writing uses point format 6 (LAS 1.4) with the same scale on every axis (``las_scale_m``,
0.1 mm by default) and offsets at the floor of a point of the cloud, so georeferenced
coordinates keep the scale's precision: the per-axis minimum for a whole cloud
(:func:`write_las`), the caller's ``origin_hint_m`` or else the first chunk's minimum for
a streamed one (:class:`LasCloudWriter`). Fields named like a format-6 standard dimension
go there (cast to its type: ``intensity`` rounded and clipped to 0..65535,
``return_number`` / ``number_of_returns`` clipped to 1..15, ``classification`` to 0..255);
a scan's ``time_s`` (seconds since the station's scan started) goes to ``gps_time`` as
GPS week time (global encoding bit 0 clear; see :mod:`treesim.scan.timing`) unless the
cloud has a ``gps_time`` of its own, and reading a file whose treesim metadata records
that convention gives it back as ``time_s``; every other field becomes an extra
dimension with its own name and dtype (bool as uint8) and a short description.
``Cloud.metadata`` is stored as JSON in a VLR (user id ``treesim``) and ``label_names``
also in the description of the ``label`` dimension (``0=other,1=wood,2=leaf,3=ground``).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np
from numpy.typing import DTypeLike

from ..cloud import Cloud
from ..errors import InputFormatError, InvalidGeometryError, InvalidParameterError
from ._common import (
    FILE_METADATA_KEYS,
    METADATA_TAG,
    field_columns,
    format_label_names,
    parse_label_names,
)
from .writer import CloudWriter

if TYPE_CHECKING:
    import laspy


def _laspy() -> Any:
    """laspy, imported when a LAS/LAZ file is first read or written (it takes a tenth of a
    second and more; every ``treesim`` command imports this module, not all write LAZ)."""
    import laspy

    return laspy


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

#: Fields written to a standard dimension of another name: a scan's pulse times (seconds
#: since the station's scan started) are LAS's ``gps_time`` (as GPS week time).
_ALIASES = {"time_s": "gps_time"}
#: The metadata key a treesim scan records its time convention under: a file with it
#: reads its ``gps_time`` back as ``time_s``.
_TIME_KEY = "time"

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

_LAZ_BACKEND = "Lazrs"  # laspy.LazBackend's name: laspy is imported when a file is read


def _backends() -> tuple[laspy.LazBackend, ...]:
    available = _laspy().LazBackend.detect_available()
    return tuple(available) or (_laspy().LazBackend[_LAZ_BACKEND],)


#: A LAZ file's chunk size that means "variable" (each chunk's point count in the table).
_VARIABLE_CHUNK = 0xFFFFFFFF
#: The largest fixed LAZ chunk size believed where the file holds fewer points: LAStools
#: and lazrs write 50,000; lazrs allocates a chunk's points at once, and a corrupt size
#: (one flipped byte: 4.3e9) aborts the interpreter instead of raising.
_MAX_CHUNK_POINTS = 1 << 24


def _corrupt(path: Path, what: str) -> InputFormatError:
    return InputFormatError(f"{path}: corrupt LAS header ({what}); is the file complete?")


def _check_header(path: Path) -> None:
    """Refuse a LAS/LAZ whose header contradicts the file's size before laspy reads it:
    laspy trusts the header's VLR count and can loop for ever on garbage, allocates what
    the point and EVLR counts say (a MemoryError on a flipped byte), and lazrs aborts the
    whole process on a corrupt chunk size or chunk table."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(375)
            if len(head) < 227 or head[:4] != b"LASF":
                raise InputFormatError(
                    f"{path}: not a LAS/LAZ file (no LASF header); is it complete?"
                )
            header_size, point_offset, n_vlrs = struct.unpack_from("<HII", head, 94)
            if header_size < 227 or point_offset > size or point_offset < header_size:
                raise _corrupt(path, f"point data offset {point_offset} in a {size}-byte file")
            if n_vlrs * 54 > point_offset - header_size:
                raise _corrupt(
                    path, f"{n_vlrs} variable-length records cannot fit before the point data"
                )
            fh.seek(header_size)
            vlrs = fh.read(point_offset - header_size)
            fh.seek(point_offset)
            table_at = fh.read(8)
    except OSError as exc:
        raise InputFormatError(f"{path}: cannot be read ({exc.strerror})") from exc
    record_length = struct.unpack_from("<H", head, 105)[0]
    n_points = struct.unpack_from("<I", head, 107)[0]
    if head[24] == 1 and head[25] >= 4 and header_size >= 375 and len(head) >= 375:
        n_points = struct.unpack_from("<Q", head, 247)[0] or n_points  # 1.4's 64-bit count
        evlr_start, n_evlrs = struct.unpack_from("<QI", head, 235)
        if n_evlrs and not (point_offset <= evlr_start <= size - 60 * n_evlrs):
            raise _corrupt(
                path, f"{n_evlrs:,} extended records from byte {evlr_start:,} of {size:,}"
            )
    if not head[104] & 0xC0:  # uncompressed: every declared point must be there
        held = max(0, size - point_offset) // max(record_length, 1)
        if held < n_points:
            raise InputFormatError(
                f"{path}: truncated: the header declares {n_points:,} points, the file "
                f"holds {held:,} ({size:,} bytes); upload the whole file"
            )
        return
    _check_laz(path, vlrs, n_vlrs, table_at, size, point_offset, record_length, n_points)


def _check_laz(
    path: Path,
    vlrs: bytes,
    n_vlrs: int,
    table_at: bytes,
    size: int,
    point_offset: int,
    record_length: int,
    n_points: int,
) -> None:
    """The LAZ parts lazrs trusts: the laszip record's items and chunk size, and where
    the chunk table is and how many chunks it lists (see :func:`_check_header`)."""
    at, chunk_size = 0, None
    for _ in range(n_vlrs):
        if at + 54 > len(vlrs):
            raise _corrupt(path, "a variable-length record runs into the point data")
        user_id = vlrs[at + 2 : at + 18].rstrip(b"\0")
        record_id, length = struct.unpack_from("<HH", vlrs, at + 18)
        data = vlrs[at + 54 : at + 54 + length]
        if user_id == b"laszip encoded" and record_id == 22204 and len(data) >= 34:
            chunk_size = struct.unpack_from("<I", data, 12)[0]
            n_items = struct.unpack_from("<H", data, 32)[0]
            items = [struct.unpack_from("<HHH", data, 34 + 6 * k) for k in range(n_items)]
            if len(data) != 34 + 6 * n_items or sum(i[1] for i in items) != record_length:
                raise _corrupt(path, "its LAZ items do not make up its point record")
        at += 54 + length
    if chunk_size is None:
        raise _corrupt(path, "compressed, but no laszip record")
    fixed = chunk_size != _VARIABLE_CHUNK
    if fixed and (chunk_size == 0 or chunk_size > max(n_points, _MAX_CHUNK_POINTS)):
        raise _corrupt(path, f"LAZ chunk size {chunk_size:,} for {n_points:,} points")
    (table,) = struct.unpack("<q", table_at) if len(table_at) == 8 else (-2,)
    if table == -1:  # written by a streaming writer: no table, lazrs reads chunk by chunk
        return
    if not point_offset + 8 <= table <= size - 8:
        raise _corrupt(path, f"LAZ chunk table at byte {table:,} of {size:,}")
    with open(path, "rb") as fh:
        fh.seek(table)
        version, n_chunks = struct.unpack("<II", fh.read(8))
    # fixed chunks: all full but the last; variable ones hold at least a point each
    bad = n_chunks != -(-n_points // chunk_size) if fixed else n_chunks > max(n_points, 1)
    if version != 0 or bad:
        raise _corrupt(path, f"LAZ chunk table lists {n_chunks:,} chunks for {n_points:,} points")


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
        las = _laspy().read(path, laz_backend=_backends())
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
    except _laspy().errors.LaspyException as exc:
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
    if _TIME_KEY in metadata and "gps_time" in fields and "time_s" not in fields:
        fields = {("time_s" if k == "gps_time" else k): v for k, v in fields.items()}
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
    for dim in _laspy().PointFormat(POINT_FORMAT).dimensions:
        if dim.name in _SKIP_STANDARD:
            continue
        if dim.kind == _laspy().DimensionKind.BitField:
            dtype, lo, hi = np.dtype(np.uint8), 0.0, float(2**dim.num_bits - 1)
        elif dim.kind == _laspy().DimensionKind.FloatingPoint:
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


def _extra_dtype(dtype: np.dtype) -> np.dtype:
    """The dtype an extra dimension stores a field of ``dtype`` in (bool as uint8, half as
    float32, little-endian)."""
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
    return _laspy().VLR(
        user_id=METADATA_TAG,
        record_id=METADATA_RECORD_ID,
        description="treesim metadata (JSON)",
        record_data=data,
    )


#: Points buffered before they go to laspy in one ``write_points`` call. The parallel LAZ
#: compressor splits each call into LAZ chunks (50 000 points) and compresses those on
#: all cores, so it pays only on big calls; 1 000 000 points is 20 whole chunks. The
#: buffer is one point record of at most this many points: 30 bytes a point in format 6
#: plus the extra dimensions (53 bytes with the scanner's fields: about 53 MB). It grows
#: to that size only as points arrive, so small files keep a small buffer.
BATCH_POINTS = 1_000_000

#: Standard dimensions set to 1 when the cloud has no such field (format 6 wants >= 1).
_DEFAULT_ONE = ("return_number", "number_of_returns")


def _write_backends(threads: int) -> tuple[laspy.LazBackend, ...]:
    """LAZ backends to try, best first: lazrs in parallel unless ``threads`` is 1.

    lazrs compresses in parallel on rayon's global thread pool, which takes its size from
    ``RAYON_NUM_THREADS`` or the number of cores when it is first used; lazrs (0.8)
    exposes no thread count, so ``threads`` > 1 cannot be honoured exactly: 0 and > 1
    both give the parallel backend (all cores), 1 the sequential one.
    """
    parallel, sequential = _laspy().LazBackend.LazrsParallel, _laspy().LazBackend.Lazrs
    preferred = (sequential,) if threads == 1 else (parallel, sequential)
    available = tuple(_laspy().LazBackend.detect_available())
    ordered = [b for b in preferred if b in available]
    ordered += [b for b in available if b not in ordered]
    return tuple(ordered) or preferred


def _check_scale(las_scale_m: float) -> float:
    try:
        scale = float(las_scale_m)
    except (TypeError, ValueError):
        scale = float("nan")
    if not np.isfinite(scale) or scale <= 0:
        raise InvalidParameterError(
            f"las_scale_m must be a positive number of metres, got {las_scale_m!r}"
        )
    return scale


def _check_origin(origin_hint_m: Any) -> np.ndarray:
    try:
        origin = np.asarray(origin_hint_m, dtype=np.float64)
    except (TypeError, ValueError):
        origin = np.full(1, np.nan)
    if origin.shape != (3,) or not np.isfinite(origin).all():
        raise InvalidParameterError(
            f"origin_hint_m must be 3 finite coordinates (a point inside the scene), "
            f"got {origin_hint_m!r}"
        )
    return origin


class LasCloudWriter(CloudWriter):
    """Stream points into a LAS (``.las``) or LAZ (``.laz``) file, point format 6 (LAS 1.4).

    What :func:`write_las` writes, in chunks (see :class:`~treesim.io.writer.CloudWriter`
    for the protocol): the same header, extra dimensions, descriptions, metadata VLR, scale
    and defaults. Chunks are packed into a buffer of at most :data:`BATCH_POINTS` points
    that goes to laspy's streaming writer when full and at close; laspy completes the
    header (point count, bounds, points by return) on close.

    Parameters
    ----------
    path : str or Path
        Destination; compressed when the suffix is ``.laz`` (any case).
    fields : mapping of str -> dtype
        Fields named like a format-6 standard dimension go there (rounded and clipped to
        its type); the others become extra dimensions of their dtype (bool as uint8).
    metadata : mapping, optional
        Stored as JSON in a VLR; ``label_names`` also in the ``label`` description.
    origin_hint_m : (3,) float, optional
        A point inside the scene (e.g. its bounds' minimum): the offsets are its floor.
        Without it they are the floor of the first non-empty chunk's minimum.
    las_scale_m : float, optional
        Coordinate resolution in metres (the LAS scale, same on every axis).
    threads : int, optional
        LAZ only: 1 compresses on one core (lazrs), 0 (default) or more on all cores
        (lazrs in parallel; see :func:`_write_backends` for why not exactly ``threads``).

    Raises
    ------
    InvalidParameterError
        If ``las_scale_m``, ``origin_hint_m`` or ``threads`` is invalid.
    InvalidGeometryError
        If a field cannot be stored (non-numeric, name longer than 32 bytes); from
        ``write``: if coordinates are not finite or do not fit int32 at the scale.
    InputFormatError
        If laspy or the file system fails to write the file.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        fields: Mapping[str, DTypeLike],
        metadata: Mapping[str, Any] | None = None,
        origin_hint_m: Any = None,
        las_scale_m: float = 1e-4,
        threads: int = 0,
    ) -> None:
        super().__init__(path, fields, metadata)
        self._scale = _check_scale(las_scale_m)
        self._offsets: np.ndarray | None = (
            None if origin_hint_m is None else np.floor(_check_origin(origin_hint_m))
        )
        threads = int(threads)
        if threads < 0:
            raise InvalidParameterError(f"threads must be >= 0 (0: all cores), got {threads}")
        self._compress = self.path.suffix.lower() == ".laz"
        self._backends = _write_backends(threads) if self._compress else None
        self._standard = _standard_targets()
        #: field -> the standard dimension it fills (its own name, or an alias's)
        self._targets = {
            name: target
            for name in self._fields
            for target in (_ALIASES.get(name, name),)
            if target in self._standard and (target == name or target not in self._fields)
        }
        extras: list[laspy.ExtraBytesParams] = []
        for name, dtype in self._fields.items():
            if name in self._targets:
                continue
            if not name.isascii() or len(name.encode()) > _NAME_MAX:
                raise InvalidGeometryError(
                    f"field name {name!r} cannot be a LAS extra dimension (ASCII, at most "
                    f"{_NAME_MAX} characters); rename the field"
                )
            extras.append(
                _laspy().ExtraBytesParams(
                    name=name,
                    type=_extra_dtype(dtype),
                    description=_description(name, self._metadata),
                )
            )
        try:
            header = _laspy().LasHeader(point_format=POINT_FORMAT, version=LAS_VERSION)
            # gps_time is GPS week time (bit 0 clear): a scan's seconds since its start
            header.global_encoding.gps_time_type = _laspy().header.GpsTimeType.WEEK_TIME
            if extras:
                header.add_extra_dims(extras)
            header.scales = np.array([self._scale] * 3)
            vlr = _metadata_vlr(self._metadata)
            if vlr is not None:
                header.vlrs.append(vlr)
        except _laspy().errors.LaspyException as exc:
            raise InputFormatError(f"could not write {self.path} as LAS/LAZ: {exc}") from exc
        self._header = header
        self._defaults = [name for name in _DEFAULT_ONE if name not in self._fields]
        self._batch = int(BATCH_POINTS)
        self._buffer: laspy.PackedPointRecord | None = None
        self._fill = 0
        self._stream: BinaryIO | None = None
        self._laspy: laspy.LasWriter | None = None
        self._start()

    @property
    def offsets(self) -> np.ndarray | None:
        """(3,) float64: the LAS offsets, once known (from the hint or the first chunk)."""
        return None if self._offsets is None else self._offsets.copy()

    @property
    def laz_backend(self) -> laspy.LazBackend | None:
        """The LAZ backend compressing the points (None for LAS or before the first
        batch is handed to laspy)."""
        if self._laspy is None or not self._compress:
            return None
        writer = self._laspy.point_writer
        if type(writer).__name__ == "LazrsPointWriter":
            parallel = getattr(writer, "parallel", False)
            return _laspy().LazBackend.LazrsParallel if parallel else _laspy().LazBackend.Lazrs
        return _laspy().LazBackend.Laszip

    def _open(self, tmp: Path) -> None:
        self._stream = open(tmp, "wb")

    def _write(self, points: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        finite = np.isfinite(points).all(axis=1)
        if not finite.all():
            first = self.points_written + int(np.flatnonzero(~finite)[0])
            raise InvalidGeometryError(
                f"{int((~finite).sum())} points have NaN or infinite coordinates (first at row "
                f"{first}); LAS cannot store them: drop those rows before writing"
            )
        if self._offsets is None:
            self._offsets = np.floor(points.min(axis=0))
        start = 0
        while start < len(points):
            stop = start + min(self._batch - self._fill, len(points) - start)
            self._pack(points[start:stop], {k: v[start:stop] for k, v in columns.items()}, start)
            start = stop
            if self._fill == self._batch:
                self._flush()

    def _pack(self, points: np.ndarray, columns: dict[str, np.ndarray], row: int) -> None:
        """Convert part of a chunk (the points from ``row`` on) into the buffer."""
        ints = self._integers(points, self.points_written + row)
        n = len(points)
        self._reserve(self._fill + n)
        assert self._buffer is not None
        slot = self._buffer[self._fill : self._fill + n]
        slot["X"][:] = ints[:, 0]
        slot["Y"][:] = ints[:, 1]
        slot["Z"][:] = ints[:, 2]
        for name in self._defaults:
            slot[name][:] = np.ones(n, dtype=np.uint8)
        for name, values in columns.items():
            target = self._targets.get(name)
            if target is not None:
                slot[target][:] = _to_standard(values, *self._standard[target])
            else:
                slot[name][:] = values.astype(_extra_dtype(values.dtype), copy=False)
        self._fill += n

    def _integers(self, points: np.ndarray, first_row: int) -> np.ndarray:
        """(n, 3) int32 scaled coordinates, or raise if some do not fit int32."""
        assert self._offsets is not None
        counts = np.rint((points - self._offsets) / self._scale)
        info = np.iinfo(np.int32)
        bad = ((counts < info.min) | (counts > info.max)).any(axis=1)
        if bad.any():
            extent = float(np.abs(points - self._offsets).max())
            offsets = ", ".join(f"{v:.15g}" for v in self._offsets)
            raise InvalidGeometryError(
                f"the cloud extends {extent:.6g} m from the LAS offsets ({offsets}) (first "
                f"at row {first_row + int(np.flatnonzero(bad)[0])}), which does not fit LAS's "
                f"32-bit integers at las_scale_m={self._scale:g} (at most "
                f"{info.max * self._scale:.6g} m); use a coarser las_scale_m"
            )
        return counts.astype(np.int32)

    def _reserve(self, size: int) -> None:
        """Make the buffer hold at least ``size`` points (at most :data:`BATCH_POINTS`)."""
        have = 0 if self._buffer is None else len(self._buffer)
        if size <= have:
            return
        # the whole batch at once: zeros are calloc'd, pages only touched when filled
        grown = _laspy().PackedPointRecord.zeros(self._batch, self._header.point_format)
        if self._buffer is not None and self._fill:
            grown.array[: self._fill] = self._buffer.array[: self._fill]
        self._buffer = grown

    def _laspy_writer(self) -> laspy.LasWriter:
        """laspy's writer, created once the offsets are known (or at close)."""
        if self._laspy is None:
            assert self._stream is not None
            self._header.offsets = self._offsets if self._offsets is not None else np.zeros(3)
            self._laspy = _laspy().open(
                self._stream,
                mode="w",
                header=self._header,
                do_compress=self._compress,
                laz_backend=self._backends,
                closefd=False,
            )
        return self._laspy

    def _flush(self) -> None:
        if self._fill:
            assert self._buffer is not None
            self._laspy_writer().write_points(self._buffer[: self._fill])
            self._fill = 0

    def _finish(self) -> None:
        self._flush()
        self._laspy_writer().close()
        self._buffer = None
        assert self._stream is not None
        self._stream.close()

    def _discard(self) -> None:
        # Drop laspy's writer before closing the file: its compressor may hold the stream.
        self._laspy = None
        self._buffer = None
        if self._stream is not None:
            self._stream.close()

    def _translate(self, exc: BaseException) -> BaseException:
        if isinstance(exc, _laspy().errors.LaspyException) or type(exc).__name__ == "LazrsError":
            return InputFormatError(f"could not write {self.path} as LAS/LAZ: {exc}")
        return super()._translate(exc)


def write_las(path: str | Path, cloud: Cloud, *, las_scale_m: float = 1e-4) -> Path:
    """Write a LAS (``.las``) or LAZ (``.laz``) file, point format 6 (LAS 1.4).

    One chunk through :class:`LasCloudWriter`; the offsets are the floor of the per-axis
    minimum, so georeferenced coordinates keep the scale's precision.

    Parameters
    ----------
    path : str or Path
        Destination; compressed when the suffix is ``.laz`` (any case).
    cloud : Cloud
        The points, fields and metadata to write (may be empty).
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
    columns = dict(field_columns(cloud))
    writer = LasCloudWriter(
        path,
        fields={name: values.dtype for name, values in columns.items()},
        metadata=cloud.metadata,
        las_scale_m=las_scale_m,
    )
    with writer:
        writer.write(cloud.points, columns)
    return writer.path
