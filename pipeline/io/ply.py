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

from pathlib import Path

import numpy as np
import plyfile

from ..cloud import Cloud
from ..errors import InputFormatError, InvalidGeometryError
from ._common import decode_metadata, encode_metadata, field_columns, write_binary

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


#: numpy dtypes PLY can store (keyed by kind and size).
_PLY_TYPES = {
    ("i", 1): "i1",
    ("u", 1): "u1",
    ("i", 2): "i2",
    ("u", 2): "u2",
    ("i", 4): "i4",
    ("u", 4): "u4",
    ("f", 4): "f4",
    ("f", 8): "f8",
}


def _ply_values(name: str, values: np.ndarray) -> np.ndarray:
    """``values`` converted to a type PLY can hold, losslessly, or raise."""
    dtype = values.dtype
    if dtype.kind == "b":
        return values.astype("<u1")
    if dtype.kind == "f" and dtype.itemsize < 4:
        return values.astype("<f4")
    key = (dtype.kind, dtype.itemsize)
    if key in _PLY_TYPES:
        return values.astype("<" + _PLY_TYPES[key], copy=False)
    # 64-bit integers: PLY has none.
    for target in ("<i4", "<u4"):
        info = np.iinfo(target)
        if len(values) == 0 or (values.min() >= info.min and values.max() <= info.max):
            return values.astype(target)
    if np.abs(values).max() <= 2**53:
        return values.astype("<f8")
    raise InvalidGeometryError(
        f"field {name!r} holds 64-bit integers beyond 2**53, which PLY cannot store exactly; "
        "use LAS/LAZ or reduce the values"
    )


def write_ply(path: str | Path, cloud: Cloud) -> Path:
    """Write a binary little-endian PLY point cloud.

    Parameters
    ----------
    path : str or Path
        Destination.
    cloud : Cloud
        The points (written as double), fields and metadata (written as comments).

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    InvalidGeometryError
        If a field cannot be stored (non-numeric, name not a single ASCII word).
    InputFormatError
        If the file cannot be written.
    """
    path = Path(path)
    columns = [(name, _ply_values(name, values)) for name, values in field_columns(cloud)]
    for name, _ in columns:
        if not name.isascii() or not name or any(c.isspace() for c in name):
            raise InvalidGeometryError(
                f"field name {name!r} cannot be a PLY property (one ASCII word); rename it"
            )
    dtype = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    dtype += [(name, values.dtype.str) for name, values in columns]
    vertex = np.empty(len(cloud), dtype=dtype)
    vertex["x"], vertex["y"], vertex["z"] = cloud.points.T
    for name, values in columns:
        vertex[name] = values
    comments = [c for c in encode_metadata(cloud.metadata) if c.isascii()]
    try:
        element = plyfile.PlyElement.describe(vertex, "vertex")
        data = plyfile.PlyData([element], text=False, byte_order="<", comments=comments)
    except (ValueError, TypeError) as exc:
        raise InvalidGeometryError(f"the cloud cannot be written as PLY: {exc}") from exc
    write_binary(path, data.write)
    return path


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
