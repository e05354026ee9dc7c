"""Point cloud files: read and write :class:`~treesim.cloud.Cloud` by file suffix.

One module per format family (``text``, ``las``, ``ply``); :data:`FORMATS` maps each
lower-case suffix to its reader and writers, and :func:`read_cloud` / :func:`write_cloud`
dispatch through it (suffixes are matched case-insensitively).

:func:`open_cloud_writer` writes a cloud that arrives in chunks (a scan, as it is cast)
without holding it: a :class:`CloudWriter` per format, with the same output as
:func:`write_cloud` (which is one chunk through the same writers).

* ``.xyz`` ``.txt`` ``.csv`` ``.asc`` ``.pts``: :mod:`treesim.io.text`
* ``.las`` ``.laz``: :mod:`treesim.io.las` (laspy, LAZ through lazrs)
* ``.ply``: :mod:`treesim.io.ply` (plyfile)
* ``.e57``: :mod:`treesim.io.e57` (read, and written whole; needs the optional ``pye57``)

A file without a trustworthy name (an upload) is known by its bytes:
:func:`sniff_format`, and :func:`inspect_file` reads and checks all of it
(:mod:`treesim.io.sniff`).

Meshes (:mod:`treesim.io.mesh`): :func:`load_mesh` / :func:`load_scene` read them into
labelled parts and a :class:`~treesim.scene.Scene`, :func:`write_mesh` writes them;
:func:`read_reference` reads a comparison reference, mesh or cloud, by content.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike, DTypeLike

from ..cloud import Cloud
from ..errors import InputFormatError, InvalidParameterError
from ..scene import Scene
from . import e57, las, ply, text
from .mesh import MESH_SUFFIXES, load_mesh, load_scene, write_mesh
from .sniff import FileInfo, inspect_file, sniff_format
from .writer import CloudWriter

__all__ = [
    "FORMATS",
    "MESH_SUFFIXES",
    "CloudFormat",
    "CloudWriter",
    "FileInfo",
    "inspect_file",
    "load_mesh",
    "load_scene",
    "open_cloud_writer",
    "read_cloud",
    "read_reference",
    "sniff_format",
    "supported_suffixes",
    "write_cloud",
    "write_mesh",
]


@dataclass(frozen=True)
class CloudFormat:
    """A point cloud file format: its reader, its writers and the options each accepts.

    Parameters
    ----------
    name : str
        Human-readable name (``"text"``, ``"LAS/LAZ"``, ``"PLY"``).
    read : callable
        ``read(path, **read_options) -> Cloud``.
    write : callable
        ``write(path, cloud, **write_options) -> Path``.
    open_writer : callable
        ``open_writer(path, *, fields, metadata, **writer_options) -> CloudWriter``.
    read_options : frozenset of str
        Keyword options of :func:`read_cloud` that ``read`` accepts.
    write_options : frozenset of str
        Keyword options of :func:`write_cloud` that ``write`` accepts.
    writer_options : frozenset of str
        Keyword options of :func:`open_cloud_writer` that ``open_writer`` accepts.
    """

    name: str
    read: Callable[..., Cloud]
    write: Callable[..., Path]
    open_writer: Callable[..., CloudWriter]
    read_options: frozenset[str] = field(default_factory=frozenset)
    write_options: frozenset[str] = field(default_factory=frozenset)
    writer_options: frozenset[str] = field(default_factory=frozenset)


_TEXT = CloudFormat(
    "text", text.read_text, text.write_text, text.TextCloudWriter, frozenset({"columns"})
)
_LAS = CloudFormat(
    "LAS/LAZ",
    las.read_las,
    las.write_las,
    las.LasCloudWriter,
    write_options=frozenset({"las_scale_m"}),
    writer_options=frozenset({"las_scale_m", "origin_hint_m", "threads"}),
)
_PLY = CloudFormat("PLY", ply.read_ply, ply.write_ply, ply.PlyCloudWriter)


def _e57_open_writer(path: str | Path, **_: Any) -> CloudWriter:
    raise InputFormatError(
        f"{path}: E57 is written whole (write_cloud), not streamed; write .laz or .ply here"
    )


_E57 = CloudFormat("E57", e57.read_e57, e57.write_e57, _e57_open_writer)

#: Lower-case suffix -> format.
FORMATS: dict[str, CloudFormat] = {
    **{suffix: _TEXT for suffix in text.SUFFIXES},
    **{suffix: _LAS for suffix in las.SUFFIXES},
    **{suffix: _PLY for suffix in ply.SUFFIXES},
    **{suffix: _E57 for suffix in e57.SUFFIXES},
}


def supported_suffixes() -> list[str]:
    """The suffixes :func:`read_cloud` and :func:`write_cloud` handle, sorted."""
    return sorted(FORMATS)


def _format_for(path: Path) -> CloudFormat:
    suffix = path.suffix.lower()
    try:
        return FORMATS[suffix]
    except KeyError:
        shown = repr(path.suffix) if path.suffix else "no suffix"
        raise InputFormatError(
            f"{path}: {shown} is not a supported point cloud format; use one of "
            f"{', '.join(supported_suffixes())}"
        ) from None


def _options(fmt: CloudFormat, allowed: frozenset[str], given: dict[str, Any]) -> dict[str, Any]:
    """The options ``fmt`` accepts; an option given explicitly that it ignores is an error."""
    for name, value in given.items():
        if value is not None and name not in allowed:
            raise InvalidParameterError(f"{name}= does not apply to {fmt.name} files; leave it out")
    return {k: v for k, v in given.items() if k in allowed}


def read_cloud(path: str | Path, *, columns: Sequence[str | None] | None = None) -> Cloud:
    """Read a point cloud file, choosing the reader by suffix.

    Parameters
    ----------
    path : str or Path
        The file; its suffix (any case) selects the format, see :data:`FORMATS`.
    columns : sequence of str or None, optional
        Text formats only: one name per column, overriding the header; must name
        ``x``, ``y`` and ``z`` (``None`` skips a column).

    Returns
    -------
    Cloud
        Points (n, 3) float64 in the file's coordinates, per-point fields, and metadata
        (always ``source_path``). The cloud is not validated: call ``.validate()`` to
        reject empty clouds and NaN coordinates.

    Raises
    ------
    InputFormatError
        If the suffix is not supported, the file does not exist, or it cannot be parsed.
    InvalidParameterError
        If ``columns`` is given for a format that has no columns.

    Examples
    --------
    >>> import numpy as np
    >>> import treesim as ts
    >>> _ = ts.write_cloud("two.ply", ts.Cloud(np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 2.0]])))
    >>> ts.read_cloud("two.ply").points
    array([[0. , 0. , 0. ],
           [1. , 0.5, 2. ]])
    """
    path = Path(path)
    fmt = _format_for(path)
    options = _options(fmt, fmt.read_options, {"columns": columns})
    if not path.exists():
        raise InputFormatError(f"{path} not found; check the path")
    if not path.is_file():
        raise InputFormatError(f"{path} is not a file")
    return fmt.read(path, **options)


def write_cloud(path: str | Path, cloud: Cloud, *, las_scale_m: float = 1e-4) -> Path:
    """Write a point cloud file, choosing the writer by suffix.

    Parameters
    ----------
    path : str or Path
        Destination; its suffix (any case) selects the format. Written atomically:
        a failed write leaves no partial file.
    cloud : Cloud
        The points, fields and metadata to write; may be empty (an empty file of the
        format, which :func:`read_cloud` reads back as an empty cloud).
    las_scale_m : float, optional
        LAS/LAZ only: coordinate resolution in metres (default 0.1 mm); ignored by the
        other formats, which store coordinates as float64.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    InputFormatError
        If the suffix is not supported or the file cannot be written.
    InvalidGeometryError
        If the cloud cannot be stored in that format (see the format modules).

    Examples
    --------
    >>> import numpy as np
    >>> import treesim as ts
    >>> cloud = ts.Cloud(np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 2.0]]))
    >>> ts.write_cloud("two.laz", cloud).name
    'two.laz'
    """
    path = Path(path)
    fmt = _format_for(path)
    options = {"las_scale_m": las_scale_m} if "las_scale_m" in fmt.write_options else {}
    return fmt.write(path, cloud, **options)


def open_cloud_writer(
    path: str | Path,
    *,
    fields: Mapping[str, DTypeLike],
    metadata: Mapping[str, Any] | None = None,
    origin_hint_m: ArrayLike | None = None,
    las_scale_m: float = 1e-4,
    threads: int = 0,
) -> CloudWriter:
    """Open a point cloud file to write in chunks, choosing the writer by suffix.

    The file holds what :func:`write_cloud` would write for the concatenated chunks
    (LAS/LAZ: up to the offsets, see ``origin_hint_m``). Memory does not grow with the
    number of points: PLY and text write each chunk as it comes, LAS/LAZ buffer at most
    :data:`treesim.io.las.BATCH_POINTS` points.

    Parameters
    ----------
    path : str or Path
        Destination; its suffix (any case) selects the format. Written atomically: a
        temporary file beside it is moved onto it on close; on abort or any error
        nothing is left and an existing file is untouched.
    fields : mapping of str -> dtype
        The per-point fields every chunk must carry, in file order; values are cast to
        these dtypes.
    metadata : mapping, optional
        ``Cloud.metadata`` of the result (stored by LAS/LAZ and PLY; text drops it).
    origin_hint_m : (3,) float, optional
        LAS/LAZ only: a point inside the scene (e.g. its bounds' minimum); the offsets
        are its floor. Without it, the floor of the first non-empty chunk's minimum.
    las_scale_m : float, optional
        LAS/LAZ only: coordinate resolution in metres (default 0.1 mm).
    threads : int, optional
        LAZ only: compression threads; 0 (default) all cores, 1 a single one (see
        :class:`treesim.io.las.LasCloudWriter`).

    Returns
    -------
    CloudWriter
        A context manager: ``write(points, fields)`` each chunk, then ``close()`` (or
        leave the ``with`` block); ``abort()`` to give up.

    Raises
    ------
    InputFormatError
        If the suffix is not supported or not writable (E57), or the file cannot be
        created.
    InvalidGeometryError
        If a field cannot be stored in that format (see the format modules).
    InvalidParameterError
        If ``las_scale_m``, ``origin_hint_m`` or ``threads`` is invalid.

    Notes
    -----
    The options that do not apply to the format (``origin_hint_m``, ``las_scale_m``,
    ``threads`` for PLY and text) are ignored, so that a caller can pass the same
    options whatever the format it is asked to write.
    """
    path = Path(path)
    fmt = _format_for(path)
    given = {"origin_hint_m": origin_hint_m, "las_scale_m": las_scale_m, "threads": threads}
    options = {k: v for k, v in given.items() if k in fmt.writer_options}
    return fmt.open_writer(path, fields=fields, metadata=metadata, **options)


def read_reference(path: str | Path) -> tuple[Scene | Cloud, str]:
    """A comparison reference file as a ``Scene`` (mesh) or a ``Cloud``.

    Mesh suffixes (:data:`MESH_SUFFIXES`) are read as meshes, except a PLY without
    faces, which is a point cloud; other cloud suffixes are read as clouds.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    reference : Scene or Cloud
    kind : str
        ``"mesh"`` or ``"cloud"``.

    Raises
    ------
    InputFormatError
        If the file does not exist or its suffix is neither a mesh's nor a cloud's.
    """
    p = Path(path)
    if not p.exists():
        raise InputFormatError(f"{p} not found; check the path")
    suffix = p.suffix.lower()
    if suffix in MESH_SUFFIXES and (suffix != ".ply" or ply.ply_has_faces(p)):
        return load_scene([p]), "mesh"
    if suffix in supported_suffixes():
        return read_cloud(p), "cloud"
    raise InputFormatError(
        f"{p.name}: not a mesh ({', '.join(MESH_SUFFIXES)}) or point cloud "
        f"({', '.join(supported_suffixes())}) file"
    )
