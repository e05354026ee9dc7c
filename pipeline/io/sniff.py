"""Know a file by its bytes, then open and check all of it.

A file that arrives without a trustworthy name (an upload, whose name is only a label) is
known by its first bytes: :func:`sniff_format`. :func:`inspect_file` then reads the whole
file with treesim's own readers and checks what a stage would trip over later (no points,
no triangles, NaN coordinates, a truncated body), so a bad file is refused at the door with
the reason, never half-way through a job.

Formats: LAS and LAZ (``LASF``; LAZ by the compression bits of the point format), PLY
(``ply``; a mesh when it declares faces), E57 (``ASTM-E57``), binary glTF (``glTF``), binary
STL (the header's triangle count matches the size), ASCII STL (``solid`` … ``facet``), OFF,
OBJ (``v``/``f`` lines) and XYZ text (rows of at least three numbers, after at most one
header line of names).
"""

from __future__ import annotations

import re
import struct
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import (
    EmptyInputError,
    InputFormatError,
    InvalidGeometryError,
    TreesimError,
    UnsupportedFormatError,
)
from .text import _is_number

__all__ = ["FORMAT_SUFFIX", "MESH_FORMATS", "FileInfo", "inspect_file", "sniff_format"]

#: Sniffed format → the suffix treesim's readers know it by.
FORMAT_SUFFIX: dict[str, str] = {
    "las": ".las",
    "laz": ".laz",
    "ply": ".ply",
    "e57": ".e57",
    "xyz": ".xyz",
    "obj": ".obj",
    "stl": ".stl",
    "off": ".off",
    "glb": ".glb",
}
#: Formats that are always meshes (a PLY is a mesh only when it declares faces).
MESH_FORMATS = frozenset({"obj", "stl", "off", "glb"})

_HEAD = 64 * 1024
_OBJ_KEYWORDS = frozenset(
    "v vt vn vp f l p o g s mtllib usemtl cstype deg curv surf parm end".split()
)
_NAMES = "LAS, LAZ, PLY, E57, OBJ, STL, OFF, GLB or XYZ text"


def _text_lines(head: bytes) -> list[str] | None:
    """The head's lines if it is text (UTF-8, no NUL bytes), else None."""
    if b"\x00" in head:
        return None
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not merely a character cut at the head's end
            return None
        text = head[: exc.start].decode("utf-8-sig")
    lines = text.splitlines()
    if len(head) == _HEAD and lines:
        lines = lines[:-1]  # the last line may be cut
    return lines


def _sniff_text(lines: list[str]) -> str | None:
    content = [ln.strip() for ln in lines if ln.strip() and not ln.lstrip().startswith(("#", "//"))]
    if not content:
        return None
    first = content[0].split()
    if first and first[0].upper().endswith("OFF") and first[0].upper() in ("OFF", "COFF", "NOFF"):
        return "off"
    if content[0].lower().startswith("solid") and any(
        ln.startswith("facet") for ln in content[:50]
    ):
        return "stl"
    keywords = [ln.split(maxsplit=1)[0] for ln in content[:200]]
    if all(k in _OBJ_KEYWORDS for k in keywords) and "v" in keywords:
        return "obj"

    def numbers(line: str) -> int:
        tokens = [t for t in re.split(r"[,;\s]+", line.split("#", 1)[0]) if t]
        return len(tokens) if tokens and all(_is_number(t) for t in tokens) else 0

    rows = content[:3]
    if len(rows) >= 2 and numbers(rows[0]) == 1 and rows[0].isdigit():
        rows = rows[1:]  # the point count of a .pts file
    if numbers(rows[0]) >= 3:
        return "xyz"
    if len(rows) > 1 and numbers(rows[1]) >= 3:
        return "xyz"  # one header line of column names
    return None


def sniff_format(path: str | Path, filename: str | None = None) -> str:
    """The file's format from its first bytes (never from its name).

    Parameters
    ----------
    path : str or Path
    filename : str, optional
        The name the file came with, used only in messages.

    Returns
    -------
    str
        A key of :data:`FORMAT_SUFFIX`.

    Raises
    ------
    EmptyInputError
        The file is empty.
    UnsupportedFormatError
        The bytes are none of the formats treesim reads.
    InputFormatError
        The file cannot be read.
    """
    p = Path(path)
    label = filename or p.name
    try:
        size = p.stat().st_size
        with open(p, "rb") as fh:
            head = fh.read(_HEAD)
    except OSError as exc:
        raise InputFormatError(f"{label}: cannot be read ({exc.strerror})") from exc
    if size == 0:
        raise EmptyInputError(f"{label}: the file is empty")
    if head.startswith(b"LASF"):
        if len(head) < 105:
            raise InputFormatError(
                f"{label}: a LAS header cut short ({size} bytes); is it complete?"
            )
        return "laz" if head[104] & 0xC0 else "las"
    if head.startswith((b"ply\n", b"ply\r\n", b"ply\r", b"ply ")):
        return "ply"
    if head.startswith(b"ASTM-E57"):
        return "e57"
    if head.startswith(b"glTF"):
        return "glb"
    if size >= 84 and not head[:5].lower() == b"solid":
        (n,) = struct.unpack_from("<I", head, 80)
        if 84 + 50 * n == size:
            return "stl"
    lines = _text_lines(head)
    if lines is not None:
        found = _sniff_text(lines)
        if found:
            return found
        first = next((ln.strip() for ln in lines if ln.strip()), "")
        raise UnsupportedFormatError(
            f"{label}: text that is not a point cloud or mesh (first line {first[:60]!r}); "
            f"treesim reads {_NAMES}, and XYZ text needs rows of x y z numbers"
        )
    raise UnsupportedFormatError(f"{label}: not a {_NAMES} file: it starts with {head[:8]!r}")


@dataclass(frozen=True)
class FileInfo:
    """What a file holds, from reading all of it.

    Attributes
    ----------
    format : str
        The sniffed format (a key of :data:`FORMAT_SUFFIX`).
    kind : str
        ``"cloud"`` or ``"mesh"``.
    suffix : str
        The suffix treesim's readers know the format by (store the file under it).
    n_points : int
        Points of a cloud, vertices of a mesh.
    n_triangles : int or None
        Triangles of a mesh (after triangulating polygons); None for a cloud.
    bounds : tuple of two lists
        ``([xmin, ymin, zmin], [xmax, ymax, zmax])`` in the file's coordinates (m).
    fields : list of str
        Per-point fields of a cloud besides x, y, z (intensity, ...).
    """

    format: str
    kind: str
    suffix: str
    n_points: int
    n_triangles: int | None
    bounds: tuple[list[float], list[float]]
    fields: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types."""
        return {
            "format": self.format,
            "kind": self.kind,
            "suffix": self.suffix,
            "n_points": int(self.n_points),
            "n_triangles": None if self.n_triangles is None else int(self.n_triangles),
            "bounds": [list(map(float, self.bounds[0])), list(map(float, self.bounds[1]))],
            "fields": list(self.fields),
        }


def _bounds(points: np.ndarray) -> tuple[list[float], list[float]]:
    return points.min(axis=0).tolist(), points.max(axis=0).tolist()


def _read(link: Path, fmt: str, label: str) -> FileInfo:
    from . import e57, las, ply, text
    from .mesh import load_mesh

    readers = {"las": las.read_las, "laz": las.read_las, "ply": ply.read_ply,
               "xyz": text.read_text, "e57": e57.read_e57}  # fmt: skip

    if fmt in MESH_FORMATS or (fmt == "ply" and ply.ply_has_faces(link)):
        parts = load_mesh(link)
        vertices = np.concatenate([np.asarray(p.vertices, dtype=np.float64) for p in parts])
        n_tri = sum(len(p.faces) for p in parts)
        if n_tri == 0 or len(vertices) == 0:
            raise EmptyInputError(f"{label}: the mesh has no triangles")
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        if bad:
            raise InvalidGeometryError(
                f"{label}: {bad:,} vertices have NaN or infinite coordinates"
            )
        return FileInfo(fmt, "mesh", FORMAT_SUFFIX[fmt], len(vertices), n_tri, _bounds(vertices))
    cloud = readers[fmt](link).validate()
    return FileInfo(
        fmt, "cloud", FORMAT_SUFFIX[fmt], len(cloud.points), None, _bounds(cloud.points),
        sorted(cloud.fields),
    )  # fmt: skip


def inspect_file(path: str | Path, filename: str | None = None) -> FileInfo:
    """Sniff a file's format, read all of it with treesim's readers, and check it.

    Parameters
    ----------
    path : str or Path
        The file; its own name and suffix do not matter.
    filename : str, optional
        The name it came with, used in messages only.

    Returns
    -------
    FileInfo

    Raises
    ------
    EmptyInputError
        Empty file, no points, a mesh without triangles.
    UnsupportedFormatError
        Not a format treesim reads.
    InvalidGeometryError
        NaN or infinite coordinates (the message counts them).
    InputFormatError
        A broken file: truncated, corrupt, unparsable; every reader's failure ends here
        (never a library's own exception).
    """
    p = Path(path).resolve()
    label = filename or p.name
    fmt = sniff_format(p, label)
    with tempfile.TemporaryDirectory(prefix="treesim-inspect-") as tmp:
        # the readers choose by suffix: a link under the sniffed format's suffix, no copy
        link = Path(tmp) / f"upload{FORMAT_SUFFIX[fmt]}"
        link.symlink_to(p)
        try:
            return _read(link, fmt, label)
        except MemoryError:
            raise
        except TreesimError as exc:
            message = str(exc).replace(str(link), label).replace(link.name, label)
            if label not in message:
                message = f"{label}: {message}"
            raise type(exc)(message) from None
        except Exception as exc:  # noqa: BLE001 - a reader's own failure is a broken file
            detail = str(exc).replace(str(link), label) or type(exc).__name__
            raise InputFormatError(
                f"{label}: could not be read as {fmt.upper()}: {detail}"
            ) from None
