"""PLY point clouds, through plyfile.

Writing gives binary little-endian PLY whose ``vertex`` element has ``double x, y, z``
(never float32: at y = 5 500 000 m float32 moves points by up to 0.5 m) and one property
per field with the field's own type (bool as uint8; 64-bit integers, which PLY lacks, as
32-bit when the values fit). ``Cloud.metadata`` is written as comments
``treesim KEY VALUE`` (``label_names`` as ``0=other,1=wood,...``, other values as JSON).

Reading takes the ``vertex`` element of any PLY (ASCII or binary, float or double, with or
without faces): x, y, z as float64 and every other scalar vertex property as a field in
its stored type; list properties are skipped.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import plyfile
from numpy.typing import DTypeLike

from ..cloud import Cloud
from ..errors import InputFormatError, InvalidGeometryError
from ._common import decode_metadata, encode_metadata, field_columns
from .writer import CloudWriter

#: Suffixes handled by this module.
SUFFIXES: tuple[str, ...] = (".ply",)


def ply_has_faces(path: str | Path) -> bool:
    """Whether a PLY file declares a non-empty ``face`` element, i.e. holds a mesh.

    Reads the header only (at most 10 000 lines).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
        False also when the file cannot be read or its header parsed.
    """
    try:
        with open(path, "rb") as fh:
            for _ in range(10_000):
                line = fh.readline()
                if not line:
                    break
                words = line.decode("ascii", "replace").split()
                if words[:2] == ["element", "face"] and len(words) >= 3:
                    return int(words[2]) > 0
                if words[:1] == ["end_header"]:
                    break
    except (OSError, ValueError):
        return False
    return False


#: numpy dtypes PLY can store (keyed by kind and size) and their PLY names (plyfile's).
_PLY_TYPES: dict[tuple[str, int], tuple[str, str]] = {
    ("i", 1): ("<i1", "char"),
    ("u", 1): ("<u1", "uchar"),
    ("i", 2): ("<i2", "short"),
    ("u", 2): ("<u2", "ushort"),
    ("i", 4): ("<i4", "int"),
    ("u", 4): ("<u4", "uint"),
    ("f", 4): ("<f4", "float"),
    ("f", 8): ("<f8", "double"),
}

#: Digits reserved for the vertex count in the header (any 64-bit count fits).
_COUNT_WIDTH = 20

#: The comment that pads the header to the same length whatever the vertex count.
_PADDING = "(room for the vertex count)"


def _stored_dtype(name: str, dtype: np.dtype) -> np.dtype:
    """The little-endian type a field declared as ``dtype`` is stored in.

    Booleans as uint8, float16 as float32; 64-bit integers, which PLY lacks, as int32 or
    uint32 (each chunk is checked to fit).
    """
    if dtype.kind == "b":
        return np.dtype("<u1")
    if dtype.kind == "f" and dtype.itemsize < 4:
        return np.dtype("<f4")
    if dtype.kind in "iu" and dtype.itemsize == 8:
        return np.dtype("<i4" if dtype.kind == "i" else "<u4")
    try:
        return np.dtype(_PLY_TYPES[(dtype.kind, dtype.itemsize)][0])
    except KeyError:
        raise InvalidGeometryError(
            f"field {name!r} has dtype {dtype}, which PLY cannot store; convert it to float64"
        ) from None


def _whole_field_dtype(name: str, values: np.ndarray) -> np.dtype:
    """The dtype to declare for a whole field: 64-bit integers as the narrowest PLY type
    that holds every value exactly (int32, uint32, else float64 up to 2**53)."""
    dtype = values.dtype
    if dtype.kind not in "iu" or dtype.itemsize != 8:
        return dtype
    for target in (np.dtype(np.int32), np.dtype(np.uint32)):
        info = np.iinfo(target)
        if len(values) == 0 or (values.min() >= info.min and values.max() <= info.max):
            return target
    if np.abs(values).max() <= 2**53:
        return np.dtype(np.float64)
    raise InvalidGeometryError(
        f"field {name!r} holds 64-bit integers beyond 2**53, which PLY cannot store exactly; "
        "use LAS/LAZ or reduce the values"
    )


class PlyCloudWriter(CloudWriter):
    """Stream points into a binary little-endian PLY file.

    What :func:`write_ply` writes, in chunks (see :class:`~treesim.io.writer.CloudWriter`
    for the protocol): ``double x, y, z``, one property per field, metadata as comments.
    Each chunk is written as it comes (no buffer beyond the chunk).

    The vertex count is unknown until close, so the header is written first with the
    count 0 and a comment ``(room for the vertex count)...`` after the metadata comments,
    and rewritten in place on close with the real count and the padding shortened by as
    many characters as the count grew: the count is written plainly (no leading zeros or
    trailing spaces, which some readers mis-parse) and the header keeps its length.

    Parameters
    ----------
    path : str or Path
        Destination.
    fields : mapping of str -> dtype
        One property each, of the field's type (bool as uint8, float16 as float32; 64-bit
        integers as int32 or uint32, and a chunk with values beyond those is refused).
    metadata : mapping, optional
        Written as comments ``treesim KEY VALUE`` (non-ASCII entries are dropped).

    Raises
    ------
    InvalidGeometryError
        If a field name is not one ASCII word or its dtype cannot be stored; from
        ``write``: if a 64-bit integer field holds values beyond 32 bits.
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
            if not name.isascii() or not name or any(c.isspace() for c in name):
                raise InvalidGeometryError(
                    f"field name {name!r} cannot be a PLY property (one ASCII word); rename it"
                )
        self._stored = {name: _stored_dtype(name, dt) for name, dt in self._fields.items()}
        self._record = np.dtype(
            [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
            + [(name, dtype) for name, dtype in self._stored.items()]
        )
        self._comments = [c for c in encode_metadata(self._metadata) if c.isascii()]
        self._stream: BinaryIO | None = None
        self._header_size = 0
        self._start()

    def _header(self, count: int) -> bytes:
        """The header for ``count`` vertices; the same length for every count."""
        digits = str(count)
        lines = ["ply", "format binary_little_endian 1.0"]
        lines += [f"comment {c}" for c in self._comments]
        lines.append(f"comment {_PADDING}{'.' * (_COUNT_WIDTH - len(digits))}")
        lines.append(f"element vertex {digits}")
        for name in self._record.names:
            dtype = self._record.fields[name][0]
            lines.append(f"property {_PLY_TYPES[(dtype.kind, dtype.itemsize)][1]} {name}")
        lines.append("end_header")
        return ("\n".join(lines) + "\n").encode("ascii")

    def _open(self, tmp: Path) -> None:
        self._stream = open(tmp, "wb")
        header = self._header(0)
        self._header_size = len(header)
        self._stream.write(header)

    def _write(self, points: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        raw = np.empty(len(points) * self._record.itemsize, dtype=np.uint8)
        vertex = raw.view(self._record)
        vertex["x"], vertex["y"], vertex["z"] = points.T
        for name, values in columns.items():
            stored = self._stored[name]
            if values.dtype.kind in "iu" and values.dtype.itemsize > stored.itemsize:
                info = np.iinfo(stored)
                if values.min() < info.min or values.max() > info.max:
                    raise InvalidGeometryError(
                        f"field {name!r} holds values in [{values.min()}, {values.max()}], "
                        f"beyond the PLY {stored.name} it is stored as (PLY has no 64-bit "
                        "integers); declare it float64 (exact to 2**53) or write LAS/LAZ"
                    )
            vertex[name] = values
        assert self._stream is not None
        self._stream.write(raw)

    def _finish(self) -> None:
        assert self._stream is not None
        header = self._header(self.points_written)
        if len(header) != self._header_size:  # cannot happen: the padding absorbs the count
            raise AssertionError("the PLY header changed length")
        self._stream.seek(0)
        self._stream.write(header)
        self._stream.close()

    def _discard(self) -> None:
        if self._stream is not None:
            self._stream.close()


def write_ply(path: str | Path, cloud: Cloud) -> Path:
    """Write a binary little-endian PLY point cloud.

    One chunk through :class:`PlyCloudWriter`; 64-bit integer fields are declared as the
    narrowest PLY type that holds all their values (int32, uint32, else float64).

    Parameters
    ----------
    path : str or Path
        Destination.
    cloud : Cloud
        The points (written as double), fields and metadata (written as comments); may
        be empty.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    InvalidGeometryError
        If a field cannot be stored (non-numeric, name not a single ASCII word, 64-bit
        integers beyond 2**53).
    InputFormatError
        If the file cannot be written.
    """
    columns = dict(field_columns(cloud))
    writer = PlyCloudWriter(
        path,
        fields={name: _whole_field_dtype(name, values) for name, values in columns.items()},
        metadata=cloud.metadata,
    )
    with writer:
        writer.write(cloud.points, columns)
    return writer.path


def read_ply(path: str | Path) -> Cloud:
    """Read the vertices of a PLY file as a point cloud.

    Parameters
    ----------
    path : str or Path
        The ``.ply`` file (ASCII or binary; faces and other elements are ignored).

    Returns
    -------
    Cloud
        ``points`` (n, 3) float64; each other scalar vertex property as a field in its
        stored type (native byte order); metadata from ``treesim`` comments plus
        ``source_path``.

    Raises
    ------
    InputFormatError
        If the file is not valid PLY or has no vertex element with x, y and z.
    """
    path = Path(path)
    try:
        data = plyfile.PlyData.read(str(path))
    except plyfile.PlyParseError as exc:
        raise InputFormatError(f"{path} is not a valid PLY file: {exc}") from exc
    except (ValueError, EOFError, UnicodeDecodeError, IndexError, KeyError) as exc:
        raise InputFormatError(f"{path} could not be read as PLY: {exc}") from exc
    except OSError as exc:
        raise InputFormatError(f"{path} could not be read: {exc}") from exc
    try:
        vertex = data["vertex"]
    except KeyError:
        names = [e.name for e in data.elements]
        raise InputFormatError(
            f"{path} has no 'vertex' element (elements: {names}); it holds no points"
        ) from None
    props = {p.name: p for p in vertex.properties}
    missing = [c for c in ("x", "y", "z") if c not in props]
    if missing:
        raise InputFormatError(
            f"{path}: the vertex element lacks the properties {missing} "
            f"(has {list(props)}); it cannot be read as a point cloud"
        )
    records = vertex.data
    points = np.column_stack([np.asarray(records[c], dtype=np.float64) for c in "xyz"])
    fields: dict[str, np.ndarray] = {}
    for name, prop in props.items():
        if name in ("x", "y", "z") or isinstance(prop, plyfile.PlyListProperty):
            continue
        values = np.asarray(records[name])
        fields[name] = np.ascontiguousarray(values, dtype=values.dtype.newbyteorder("="))
    metadata = decode_metadata(list(data.comments))
    metadata["source_path"] = str(path)
    return Cloud(points, fields, metadata)
