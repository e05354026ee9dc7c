"""Scenes: labelled triangle meshes, loaded with trimesh, validated before Open3D sees them."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cloud import LABEL_CODES
from ..errors import EmptyInputError, InputFormatError, InvalidGeometryError, InvalidParameterError

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

_LABEL_PATTERNS: list[tuple[str, re.Pattern[str]]] = [
    ("leaf", re.compile(r"leaf|leaves|foliage|needle|crown_?leaf", re.I)),
    ("ground", re.compile(r"ground|terrain|soil|floor|dtm", re.I)),
    ("wood", re.compile(r"wood|trunk|stem|branch|bark|twig|stick", re.I)),
]


def label_from_name(name: str, default: str = "other") -> str:
    """Guess a part label (wood, leaf, ground, other) from a group or material name."""
    for label, pattern in _LABEL_PATTERNS:
        if pattern.search(name or ""):
            return label
    return default


@dataclass(frozen=True)
class MeshPart:
    """One labelled triangle mesh.

    Parameters
    ----------
    vertices : (v, 3) float64
        Vertex coordinates in scene coordinates (m).
    faces : (f, 3) int64
        Triangles as vertex indices.
    label : str
        One of ``wood``, ``leaf``, ``ground``, ``other``.
    name : str
        Where the part came from (file and group), for messages and reports.
    """

    vertices: np.ndarray
    faces: np.ndarray
    label: str = "other"
    name: str = ""

    def __post_init__(self) -> None:
        if self.label not in LABEL_CODES:
            raise InvalidParameterError(
                f"part label must be one of {', '.join(LABEL_CODES)}, got {self.label!r}"
            )


@dataclass
class Scene:
    """A set of labelled mesh parts, validated and merged into one triangle soup.

    Attributes
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int64
    face_label : (f,) uint8
        Label code (see ``pipeline.cloud.LABEL_CODES``) of every triangle.
    parts : list of MeshPart
    dropped_degenerate : int
        Zero-area triangles removed during validation (they give NaN normals).
    """

    parts: list[MeshPart]
    vertices: np.ndarray = field(init=False)
    faces: np.ndarray = field(init=False)
    face_label: np.ndarray = field(init=False)
    dropped_degenerate: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        if not self.parts:
            raise EmptyInputError("the scene has no mesh parts")
        verts, faces, labels = [], [], []
        offset = 0
        dropped = 0
        for part in self.parts:
            v = np.asarray(part.vertices, dtype=np.float64)
            f = np.asarray(part.faces)
            where = part.name or "mesh"
            if v.ndim != 2 or v.shape[1] != 3:
                raise InvalidGeometryError(f"{where}: vertices must be (n, 3), got {v.shape}")
            if f.size == 0:
                continue
            if f.ndim != 2 or f.shape[1] != 3:
                raise InvalidGeometryError(
                    f"{where}: faces must be triangles (m, 3), got {f.shape}"
                )
            f = f.astype(np.int64)
            if f.min() < 0 or f.max() >= len(v):
                raise InvalidGeometryError(f"{where}: faces index vertices that do not exist")
            used = np.unique(f)
            bad = ~np.isfinite(v[used]).all(axis=1)
            if bad.any():
                raise InvalidGeometryError(
                    f"{where}: {int(bad.sum())} vertices have NaN or infinite coordinates"
                )
            tri = v[f]
            area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
            edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
            keep = area2 > 1e-12 * np.maximum(edge, 1e-300) ** 2
            dropped += int((~keep).sum())
            f = f[keep]
            verts.append(v)
            faces.append(f + offset)
            labels.append(np.full(len(f), LABEL_CODES[part.label], dtype=np.uint8))
            offset += len(v)
        if not faces or sum(len(f) for f in faces) == 0:
            names = ", ".join(p.name or "mesh" for p in self.parts)
            raise EmptyInputError(f"the scene has no (non-degenerate) triangles: {names}")
        self.vertices = np.concatenate(verts)
        self.faces = np.concatenate(faces)
        self.face_label = np.concatenate(labels)
        self.dropped_degenerate = dropped
        mask = np.zeros(len(self.vertices), dtype=bool)
        mask[self.faces.ravel()] = True
        self._used = np.flatnonzero(mask)
        used = self.vertices[self._used]
        self._bounds = np.stack([used.min(axis=0), used.max(axis=0)])

    @property
    def used_vertices(self) -> np.ndarray:
        """(u, 3) float64 vertices referenced by at least one triangle."""
        return self.vertices[self._used]

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64 min and max corner over the vertices used by triangles."""
        return self._bounds.copy()

    @property
    def n_triangles(self) -> int:
        return len(self.faces)

    def labels_present(self) -> list[str]:
        codes = np.unique(self.face_label)
        inv = {v: k for k, v in LABEL_CODES.items()}
        return [inv[int(c)] for c in codes]


def load_mesh(path: str | Path, *, label: str | None = None) -> list[MeshPart]:
    """Read a mesh file into labelled parts.

    Groups or materials in the file become parts, labelled from their names (``Leaves``
    -> leaf, ``TrunkAndBranches`` -> wood, ...) unless ``label`` forces one label for
    the whole file. Quads and polygons are triangulated (trimesh), unlike Open3D's
    legacy reader, which drops them silently.
    """
    import trimesh

    p = Path(path)
    if not p.exists():
        raise InputFormatError(f"mesh file not found: {p}")
    if p.is_dir():
        raise InputFormatError(f"{p} is a folder, not a mesh file")
    if p.suffix.lower() not in MESH_SUFFIXES:
        raise InputFormatError(f"{p.name}: not a mesh file (supported: {', '.join(MESH_SUFFIXES)})")
    if label is not None and label not in LABEL_CODES:
        raise InvalidParameterError(f"label must be one of {', '.join(LABEL_CODES)}, got {label!r}")
    if p.suffix.lower() == ".ply":
        ply_parts = _load_labelled_ply(p, label)
        if ply_parts is not None:
            return ply_parts
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


def _load_labelled_ply(p: Path, label: str | None) -> list[MeshPart] | None:
    """Read a PLY whose faces carry a ``label`` property (as treesim writes them), in
    float64; ``None`` when the file has no such property (trimesh reads it then)."""
    from plyfile import PlyData

    try:
        ply = PlyData.read(str(p))
    except Exception as exc:
        raise InputFormatError(f"{p.name}: could not read as PLY ({exc})") from exc
    names = [e.name for e in ply.elements]
    if "vertex" not in names or "face" not in names:
        return None
    face = ply["face"].data
    if "label" not in face.dtype.names:
        return None
    vd = ply["vertex"].data
    v = np.stack([vd["x"], vd["y"], vd["z"]], axis=1).astype(np.float64)
    key = "vertex_indices" if "vertex_indices" in face.dtype.names else face.dtype.names[0]
    polys = face[key]
    if len(polys) and not all(len(q) == 3 for q in polys):
        return None
    f = np.stack(polys).astype(np.int64) if len(polys) else np.empty((0, 3), np.int64)
    codes = np.asarray(face["label"], dtype=np.int64)
    inv = {c: n for n, c in LABEL_CODES.items()}
    parts = []
    for c in np.unique(codes):
        name = inv.get(int(c), "other")
        parts.append(
            MeshPart(vertices=v, faces=f[codes == c], label=label or name, name=f"{p.name}:{name}")
        )
    if not parts:
        raise EmptyInputError(f"{p.name}: the file holds no triangles (is it a point cloud?)")
    return parts


def load_scene(
    paths: Iterable[str | Path] | str | Path,
    *,
    labels: Sequence[str | None] | None = None,
) -> Scene:
    """Load one or more mesh files into a ``Scene``; ``labels[i]`` forces file i's label."""
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
