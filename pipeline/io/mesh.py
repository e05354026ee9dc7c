"""Mesh files: read into labelled parts and scenes, written at full precision.

Reading (:func:`load_mesh`, :func:`load_scene`): trimesh reads every format in
:data:`MESH_SUFFIXES`, groups and materials becoming labelled parts; PLY files with a
face ``label`` property are read in float64 by plyfile.

trimesh's PLY exporter writes float32 vertices, which moves a vertex at y = 5 500 000 by
up to 0.5 m; these writers keep float64:

* ``.ply``: binary, ``double x, y, z``, faces with a ``label`` (uint8) property and a
  ``comment treesim label_names`` line;
* ``.obj``: text with 17 significant digits, one ``o``/``usemtl`` group per label
  (``wood``, ``leaf``, ...) and a ``.mtl`` beside it, so treesim and other tools see
  the parts.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..cloud import LABEL_CODES, LABEL_NAMES
from ..errors import EmptyInputError, InputFormatError, InvalidGeometryError, InvalidParameterError
from ..scene import MeshPart, Scene, label_from_name, labelled_parts

__all__ = ["MESH_SUFFIXES", "MESH_WRITE_SUFFIXES", "load_mesh", "load_scene", "write_mesh"]

#: Suffixes :func:`load_mesh` reads.
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
#: Suffixes :func:`write_mesh` writes.
MESH_WRITE_SUFFIXES = (".ply", ".obj")


def load_mesh(path: str | Path, *, label: str | None = None) -> list[MeshPart]:
    """Read a mesh file into labelled parts.

    Groups or materials in the file become parts, labelled from their names (``Leaves``
    -> leaf, ``TrunkAndBranches`` -> wood, ...) unless ``label`` forces one label for
    the whole file. Quads and polygons are triangulated (trimesh), unlike Open3D's
    legacy reader, which drops them silently. A binary triangle PLY, and a PLY whose faces
    carry a ``label`` property (as :func:`write_mesh` writes them, one part per label), are
    read in float64 by plyfile.

    Parameters
    ----------
    path : str or Path
        One of :data:`MESH_SUFFIXES`.
    label : str, optional
        Force this label (``wood``, ``leaf``, ``ground``, ``other``) on every part.

    Returns
    -------
    list of MeshPart
        Vertices (v, 3) float64 in the file's coordinates (m), faces (f, 3) int64.

    Raises
    ------
    InputFormatError
        Missing file, unsupported suffix or unreadable content.
    EmptyInputError
        The file is empty or holds no triangles.
    """
    p = Path(path)
    if not p.exists():
        raise InputFormatError(f"mesh file not found: {p}")
    if p.is_dir():
        raise InputFormatError(f"{p} is a folder, not a mesh file")
    if p.suffix.lower() not in MESH_SUFFIXES:
        raise InputFormatError(f"{p.name}: not a mesh file (supported: {', '.join(MESH_SUFFIXES)})")
    if label is not None and label not in LABEL_CODES:
        raise InvalidParameterError(f"label must be one of {', '.join(LABEL_CODES)}, got {label!r}")
    if p.stat().st_size == 0:  # not every format's reader says so plainly
        raise EmptyInputError(f"{p.name}: the file is empty (0 bytes)")
    if p.suffix.lower() == ".ply":
        ply_parts = _load_ply(p, label)
        if ply_parts is not None:
            return ply_parts
    import trimesh  # imported here: a binary triangle PLY is read without it

    try:
        loaded = trimesh.load(str(p), force="scene", process=False)
    except Exception as exc:  # trimesh raises many kinds; map at the boundary
        raise InputFormatError(f"{p.name}: could not read as a mesh ({exc})") from exc
    parts: list[MeshPart] = []
    file_label = label_from_name(p.stem)
    for node in loaded.graph.nodes_geometry:
        transform, geom_name = loaded.graph[node]
        geom = loaded.geometry[geom_name]
        faces = getattr(geom, "faces", None)
        if faces is None or len(faces) == 0:
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        if not np.allclose(transform, np.eye(4)):
            v = v @ np.asarray(transform[:3, :3], dtype=np.float64).T + transform[:3, 3]
        material = getattr(getattr(geom.visual, "material", None), "name", None) or ""
        part_label = label or label_from_name(f"{geom_name} {material}", default=file_label)
        parts.append(
            MeshPart(
                vertices=v,
                faces=np.asarray(faces, dtype=np.int64),
                label=part_label,
                name=p.name if geom_name == p.name else f"{p.name}:{geom_name}",
            )
        )
    if not parts:
        raise EmptyInputError(f"{p.name}: the file holds no triangles (is it a point cloud?)")
    return parts


def _load_ply(p: Path, label: str | None) -> list[MeshPart] | None:
    """Read a PLY in float64 with plyfile: binary triangle meshes as fixed-length records
    (vectorised; plyfile checks that every face list holds three indices), and any PLY
    whose faces carry a ``label`` property (as :func:`write_mesh` writes them), one part
    per label. ``None`` for anything else: trimesh reads (and triangulates) it."""
    from plyfile import PlyData

    header = _ply_header(p)
    face_props = [line.split()[-1] for line in header.get("face", [])]
    labelled = "label" in face_props
    ply = None
    if header.get("format") == "binary_little_endian" and "vertex_indices" in face_props:
        try:
            ply = PlyData.read(str(p), known_list_len={"face": {"vertex_indices": 3}})
        except Exception:
            ply = None  # not all triangles (or unreadable): read as a whole below
    if ply is None:
        if not labelled:
            return None
        try:
            ply = PlyData.read(str(p))
        except Exception as exc:
            raise InputFormatError(f"{p.name}: could not read as PLY ({exc})") from exc
    names = [e.name for e in ply.elements]
    if "vertex" not in names or "face" not in names:
        return None
    face = ply["face"].data
    vd = ply["vertex"].data
    v = np.stack([np.asarray(vd[c], dtype=np.float64) for c in "xyz"], axis=1)
    key = "vertex_indices" if "vertex_indices" in face.dtype.names else face.dtype.names[0]
    polys = face[key]
    if polys.ndim == 2 and polys.shape[1] == 3:  # read as fixed-length records
        f = np.array(polys, dtype=np.int64)
    elif len(polys) and not all(len(q) == 3 for q in polys):
        return None
    else:
        f = np.stack(polys).astype(np.int64) if len(polys) else np.empty((0, 3), np.int64)
    if not labelled:  # one part, named and labelled as trimesh's reading names it
        if not len(f):
            raise EmptyInputError(f"{p.name}: the file holds no triangles (is it a point cloud?)")
        part_label = label or label_from_name(f"{p.name} ", default=label_from_name(p.stem))
        return [MeshPart(vertices=v, faces=f, label=part_label, name=p.name)]
    codes = np.array(face["label"], dtype=np.int64)
    parts = labelled_parts(v, f, codes, name_prefix=f"{p.name}:", label=label)
    if not parts:
        raise EmptyInputError(f"{p.name}: the file holds no triangles (is it a point cloud?)")
    return parts


def _ply_header(p: Path) -> dict[str, Any]:
    """The header of a PLY file: its format and each element's property lines."""
    out: dict[str, Any] = {}
    element = None
    try:
        with open(p, "rb") as fh:
            for raw in fh:
                line = raw.decode("ascii", "replace").strip()
                if line == "end_header":
                    break
                words = line.split()
                if not words:
                    continue
                if words[0] == "format" and len(words) > 1:
                    out["format"] = words[1]
                elif words[0] == "element" and len(words) > 2:
                    element = words[1]
                    out[element] = []
                elif words[0] == "property" and element is not None:
                    out[element].append(line)
    except (OSError, ValueError):
        return {}
    return out


def load_scene(
    paths: Iterable[str | Path] | str | Path,
    *,
    labels: Sequence[str | None] | None = None,
) -> Scene:
    """Load one or more mesh files into a :class:`~treesim.scene.Scene`.

    Parameters
    ----------
    paths : str, Path or iterable of them
        Mesh files (see :func:`load_mesh`).
    labels : sequence of (str or None), optional
        ``labels[i]`` forces file i's label; ``None`` keeps the names' labels.

    Returns
    -------
    Scene

    Examples
    --------
    >>> import treesim as ts
    >>> scene = ts.load_scene(["tree.obj"])  # doctest: +SKIP
    >>> lo, hi = scene.bounds  # doctest: +SKIP
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise InvalidParameterError("give at least one mesh file")
    labels = list(labels) if labels is not None else [None] * len(paths)
    if len(labels) != len(paths):
        raise InvalidParameterError("give one label per mesh file (or none)")
    parts: list[MeshPart] = []
    for path, lab in zip(paths, labels, strict=True):
        parts.extend(load_mesh(path, label=lab))
    return Scene(parts)


def write_mesh(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    face_label: np.ndarray | None = None,
) -> Path:
    """Write a triangle mesh, atomically.

    Parameters
    ----------
    path : str or Path
        ``.ply`` or ``.obj``.
    vertices : (v, 3) float
    faces : (f, 3) int
    face_label : (f,) uint8, optional
        Label code per face (``treesim.cloud.LABEL_CODES``); default all ``wood``.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in MESH_WRITE_SUFFIXES:
        raise InputFormatError(
            f"{p.name}: cannot write meshes as {suffix or 'no suffix'!r}; "
            f"use one of {', '.join(MESH_WRITE_SUFFIXES)}"
        )
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise InvalidGeometryError("a mesh needs (v, 3) vertices and (f, 3) triangles")
    if not np.isfinite(v).all():
        raise InvalidGeometryError("mesh vertices contain NaN or infinite values")
    lab = (
        np.full(len(f), LABEL_CODES["wood"], dtype=np.uint8)
        if face_label is None
        else np.asarray(face_label, dtype=np.uint8)
    )
    p.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_path(p) as tmp:
            if suffix == ".ply":
                _write_ply(tmp, v, f, lab)
            else:
                mtl = p.with_suffix(".mtl")
                with open(mtl, "w", encoding="ascii") as fh:
                    for code in np.unique(lab):
                        name = LABEL_NAMES.get(int(code), "other")
                        fh.write(f"newmtl {name}\nKd {_MTL_COLOURS.get(name, '0.6 0.6 0.6')}\n")
                _write_obj(tmp, v, f, lab, mtl.name)
    except OSError as exc:
        raise InputFormatError(f"could not write {p}: {exc}") from exc
    return p


#: A face record of the binary PLY: the list's length (always 3), its three vertex
#: indices, the label; packed, as the format lays it out.
_PLY_FACE = np.dtype([("n", "u1"), ("vertex_indices", "<i4", (3,)), ("label", "u1")])


def _write_ply(path: Path, v: np.ndarray, f: np.ndarray, lab: np.ndarray) -> None:
    """Binary little-endian PLY, the header plyfile writes for these elements, the records
    written as two numpy buffers (plyfile writes a list property face by face: 0.2 s for
    59 k faces; tests/io/test_mesh_ply.py holds the bytes to plyfile's own writer's)."""
    if len(v) and int(f.max(initial=0)) >= 2**31:
        raise InvalidGeometryError("a PLY face index must fit 32 bits")
    names = ",".join(f"{k}={n}" for k, n in sorted(LABEL_NAMES.items()))
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment treesim label_names {names}\n"
        f"element vertex {len(v)}\n"
        "property double x\nproperty double y\nproperty double z\n"
        f"element face {len(f)}\n"
        "property list uchar int vertex_indices\nproperty uchar label\nend_header\n"
    )
    face = np.empty(len(f), dtype=_PLY_FACE)
    face["n"] = 3
    face["vertex_indices"] = f
    face["label"] = lab
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(v, dtype="<f8").tobytes())
        fh.write(face.tobytes())


_MTL_COLOURS = {"wood": "0.45 0.33 0.22", "leaf": "0.25 0.55 0.2", "ground": "0.5 0.45 0.35"}


def _write_obj(path: Path, v: np.ndarray, f: np.ndarray, lab: np.ndarray, mtl_name: str) -> None:
    with open(path, "w", encoding="ascii") as fh:
        fh.write("# written by treesim: float64 vertices, one group per part label\n")
        fh.write(f"mtllib {mtl_name}\n")
        np.savetxt(fh, v, fmt="v %.17g %.17g %.17g")
        for code in np.unique(lab):
            name = LABEL_NAMES.get(int(code), "other")
            fh.write(f"o {name}\nusemtl {name}\n")
            np.savetxt(fh, f[lab == code] + 1, fmt="f %d %d %d")
