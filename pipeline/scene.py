"""Scenes: labelled triangle meshes, float64, validated before Open3D sees them.

The mesh counterpart of :class:`~treesim.cloud.Cloud`, at the bottom of the package:
:class:`MeshPart` is one labelled mesh, :class:`Scene` a validated set of them merged into
one triangle soup. Mesh files are read into scenes by :func:`treesim.io.load_scene`.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .cloud import LABEL_CODES, LABEL_NAMES
from .errors import EmptyInputError, InvalidGeometryError, InvalidParameterError

__all__ = ["MAX_TREE_ID", "MeshPart", "Scene", "label_from_name", "labelled_parts"]

#: Largest tree id a part may carry (ids are stored as uint32 in clouds).
MAX_TREE_ID = 2**32 - 1

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
    tree_id : int
        The tree the part belongs to in a plot (>= 1), or 0 (no tree: terrain, a lone
        tree's scene). A scan of a scene with any tree id labels every point with it.
    """

    vertices: np.ndarray
    faces: np.ndarray
    label: str = "other"
    name: str = ""
    tree_id: int = 0

    def __post_init__(self) -> None:
        if self.label not in LABEL_CODES:
            raise InvalidParameterError(
                f"part label must be one of {', '.join(LABEL_CODES)}, got {self.label!r}"
            )
        if (
            isinstance(self.tree_id, bool)
            or not isinstance(self.tree_id, int | np.integer)
            or not 0 <= int(self.tree_id) <= MAX_TREE_ID
        ):
            raise InvalidParameterError(
                f"{self.name or 'part'}: tree_id must be an integer in [0, {MAX_TREE_ID}], "
                f"got {self.tree_id!r}"
            )


@dataclass
class Scene:
    """A set of labelled mesh parts, validated and merged into one triangle soup.

    Attributes
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int32, or int64 when the scene has 2**31 vertices or more
        Half the bytes of int64 where the indices fit (the same values).
    face_label : (f,) uint8
        Label code (see ``treesim.cloud.LABEL_CODES``) of every triangle.
    face_tree : (f,) uint32 or None
        The tree id of every triangle (its part's ``tree_id``; 0: no tree), or None
        when no part belongs to a tree and ``keep_tree_ids`` is off.
    parts : list of MeshPart
    dropped_degenerate : int
        Zero-area triangles removed during validation (they give NaN normals).

    Notes
    -----
    Validation: a vertex with a NaN or infinite coordinate that some triangle uses is an
    error (``InvalidGeometryError``, saying how many); vertices no triangle uses are
    ignored whatever they hold (non-finite ones are set to 0). Zero-area triangles
    (collapsed onto a line or a point) are dropped and counted. Duplicate triangles
    (either orientation) and non-manifold edges (shared by three or more triangles) are
    kept: the scanner meets the nearest surface along each ray whatever the topology.

    Examples
    --------
    >>> import treesim as ts
    >>> scene = ts.load_scene(["tree.ply", "ground.obj"])  # doctest: +SKIP
    >>> scene.bounds  # doctest: +SKIP
    """

    parts: list[MeshPart]
    #: keep ``face_tree`` even when every part's id is 0 (a plot station that sees only
    #: the terrain: its points still carry ``tree_id``)
    keep_tree_ids: bool = False
    #: (2, 3) bounds to report instead of the vertices' own, which it must contain: a
    #: part of a larger scene (a plot station's azimuth sector) is then cast with the
    #: whole scene's tolerances and entry distance (:class:`~treesim.scan.caster.Caster`
    #: measures them from the bounds): its pulses meet what they meet in the whole scene,
    #: with the same float64 arithmetic (see :mod:`treesim.plot.sectors` for how close)
    extent: np.ndarray | None = None
    vertices: np.ndarray = field(init=False)
    faces: np.ndarray = field(init=False)
    face_label: np.ndarray = field(init=False)
    face_tree: np.ndarray | None = field(init=False, default=None)
    dropped_degenerate: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        if not self.parts:
            raise EmptyInputError("the scene has no mesh parts")
        verts, faces, labels, trees = [], [], [], []
        offset = 0
        dropped = 0
        # the merged faces in int32 where every index fits (the same values, half the
        # bytes of int64: issue 25), each part's shifted faces converted as they come
        n_vertices = sum(len(np.asarray(p.vertices)) for p in self.parts)
        index = np.int32 if n_vertices < 2**31 else np.int64
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
            f = np.asarray(f, dtype=np.int64)  # read only: no copy when int64
            if f.min() < 0 or f.max() >= len(v):
                raise InvalidGeometryError(f"{where}: faces index vertices that do not exist")
            # the vertices some triangle uses (a mask: no sort of every corner)
            used = np.zeros(len(v), dtype=bool)
            used[f.ravel()] = True
            bad = ~np.isfinite(v[used]).all(axis=1)
            if bad.any():
                raise InvalidGeometryError(
                    f"{where}: {int(bad.sum())} vertices have NaN or infinite coordinates"
                )
            del used, bad
            keep = _non_degenerate(v, f)
            n_drop = int((~keep).sum())
            dropped += n_drop
            if n_drop:
                f = f[keep]
            del keep
            verts.append(v)
            faces.append((f + offset).astype(index, copy=False))
            labels.append(np.full(len(f), LABEL_CODES[part.label], dtype=np.uint8))
            trees.append(np.full(len(f), int(part.tree_id), dtype=np.uint32))
            offset += len(v)
        if not faces or sum(len(f) for f in faces) == 0:
            names = ", ".join(p.name or "mesh" for p in self.parts)
            raise EmptyInputError(f"the scene has no (non-degenerate) triangles: {names}")
        self.vertices = np.concatenate(verts)
        self.faces = np.concatenate(faces)
        self.face_label = np.concatenate(labels)
        if self.keep_tree_ids or any(int(p.tree_id) for p in self.parts):
            self.face_tree = np.concatenate(trees)
        self.dropped_degenerate = dropped
        mask = np.zeros(len(self.vertices), dtype=bool)
        mask[self.faces.ravel()] = True
        # vertices no triangle uses are ignored: non-finite ones become 0 (no NaN reaches
        # the arithmetic done on all vertices at once)
        spare = ~mask & ~np.isfinite(self.vertices).all(axis=1)
        self.vertices[spare] = 0.0
        # which vertices are used, as a mask (1 byte a vertex, not an 8-byte index)
        self._used = mask
        used = self.vertices[mask]
        self._bounds = np.stack([used.min(axis=0), used.max(axis=0)])
        if self.extent is not None:
            self._bounds = _checked_extent(self.extent, self._bounds)

    @classmethod
    def from_labelled_mesh(
        cls,
        vertices: np.ndarray,
        faces: np.ndarray,
        face_label: np.ndarray,
        *,
        name_prefix: str = "",
    ) -> Scene:
        """A scene from one mesh whose triangles carry label codes: one part per label.

        Parameters
        ----------
        vertices : (v, 3) float
            Vertex coordinates (m); each part keeps the ones its triangles use.
        faces : (f, 3) int
            Triangles as vertex indices.
        face_label : (f,) int
            Label code per triangle (``treesim.cloud.LABEL_CODES``; unknown codes
            become ``other``).
        name_prefix : str
            Prefix of the part names, which end in the label (``"model:"`` gives
            ``model:wood``, ...).

        Returns
        -------
        Scene
        """
        return cls(labelled_parts(vertices, faces, face_label, name_prefix=name_prefix))

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
        """Number of (non-degenerate) triangles."""
        return len(self.faces)

    @property
    def tree_ids(self) -> list[int]:
        """The tree ids of the triangles (ascending; 0 where some have none), or [] when
        no part belongs to a tree."""
        if self.face_tree is None:
            return []
        return [int(t) for t in np.unique(self.face_tree)]

    #: The arrays :meth:`spilled` moves to a file (the per-vertex and per-triangle ones).
    SPILLED = ("vertices", "faces", "face_label", "face_tree", "_used")

    @property
    def array_bytes(self) -> int:
        """Bytes of the scene's per-vertex and per-triangle arrays (what :meth:`spilled`
        moves out of memory).

        Examples
        --------
        >>> import numpy as np
        >>> from treesim.scene import MeshPart, Scene
        >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
        >>> Scene([MeshPart(v, np.array([[0, 1, 2]]), "wood")]).array_bytes  # 72 + 12 + 1 + 3
        88
        """
        return sum(a.nbytes for a in (getattr(self, k) for k in self.SPILLED) if a is not None)

    @contextmanager
    def spilled(self, directory: str | None = None) -> Iterator[None]:
        """Meanwhile, the scene's vertices, faces, labels, tree ids and used-vertex mask
        live in temporary files (read-only memory maps of it: pages read only when
        touched), and are read back after into fresh arrays, the same bits, the files
        removed (also on an exception); where the files cannot be written (a full
        disk), the arrays stay in memory. Memory (issue 25): what a caller does meanwhile
        (Open3D building its BVH) peaks without the scene's ~30 B a triangle, provided
        nothing else holds the arrays themselves. ``directory``: where the files go
        (default: Python's temporary folder; a RAM-backed one such as tmpfs saves the
        process's resident memory but not the host's).

        Examples
        --------
        >>> import numpy as np
        >>> from treesim.scene import MeshPart, Scene
        >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
        >>> scene = Scene([MeshPart(v, np.array([[0, 1, 2]]), "wood")])
        >>> with scene.spilled():
        ...     isinstance(scene.vertices, np.memmap)
        True
        >>> isinstance(scene.vertices, np.memmap), scene.vertices[1].tolist()
        (False, [1.0, 0.0, 0.0])
        """
        names = [k for k in self.SPILLED if getattr(self, k) is not None]
        folder = None
        try:
            try:
                folder = tempfile.mkdtemp(prefix="treesim-spill-", dir=directory)
                for k in names:
                    path = os.path.join(folder, f"{k}.npy")
                    np.save(path, getattr(self, k), allow_pickle=False)
                    # the array itself goes (unless held elsewhere): only its map stays
                    setattr(self, k, np.load(path, mmap_mode="r", allow_pickle=False))
            except OSError:  # no room for the files: the arrays stay in memory
                self._read_back(folder, names)
            yield
        finally:
            try:
                self._read_back(folder, names)
            finally:
                if folder is not None:
                    shutil.rmtree(folder, ignore_errors=True)

    def _read_back(self, folder: str | None, names: list[str]) -> None:
        """The arrays ``names`` that :meth:`spilled` mapped from ``folder``, read back
        into memory."""
        for k in names:
            if isinstance(getattr(self, k), np.memmap):
                path = os.path.join(str(folder), f"{k}.npy")
                setattr(self, k, np.load(path, allow_pickle=False))

    def labels_present(self) -> list[str]:
        """Labels (``wood``, ``leaf``, ...) of the triangles, in label-code order."""
        codes = np.unique(self.face_label)
        inv = {v: k for k, v in LABEL_CODES.items()}
        return [inv[int(c)] for c in codes]


#: Triangles tested at once by the scene's validation (bounds its temporaries: ~1 KB each).
_CHECK_CHUNK = 1 << 18


def _checked_extent(extent: Any, own: np.ndarray) -> np.ndarray:
    """``extent`` as (2, 3) float64 bounds, checked to contain the bounds ``own``."""
    ext = np.array(extent, dtype=np.float64)
    if ext.shape != (2, 3) or not np.isfinite(ext).all():
        raise InvalidParameterError(f"extent must be finite (2, 3) bounds, got {extent!r}")
    if (ext[0] > own[0]).any() or (ext[1] < own[1]).any():
        raise InvalidParameterError(
            f"extent {ext.tolist()} does not contain the scene's vertices ({own.tolist()})"
        )
    return ext


def _non_degenerate(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(f,) bool: the triangles ``v[f]`` with an area (twice the area over the longest
    edge squared above 1e-12), tested a chunk at a time (row by row the same figures).

    The figures ``np.linalg.norm(np.cross(e1, e2))`` and the largest
    ``np.linalg.norm`` of the edges give, computed as they do (each product rounded,
    then the difference; the squares summed in order; the root of the largest squared
    edge, which is the largest root), from corners gathered one at a time: four times
    faster (issue 25)."""

    def sq_len(e: np.ndarray) -> np.ndarray:
        sq = np.square(e)
        return sq[:, 0] + sq[:, 1] + sq[:, 2]

    keep = np.empty(len(f), dtype=bool)
    for a in range(0, len(f), _CHECK_CHUNK):
        rows = f[a : a + _CHECK_CHUNK]
        p0, p1, p2 = (np.take(v, rows[:, k], axis=0) for k in range(3))
        e1, e2 = p1 - p0, p2 - p0
        n = np.empty_like(e1)  # np.cross(e1, e2)
        n[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
        n[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
        n[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        area2 = np.sqrt(sq_len(n))
        # the edges p0 - p2, p1 - p0, p2 - p1 (a difference's sign leaves its square)
        edge = np.sqrt(np.maximum(np.maximum(sq_len(p2 - p0), sq_len(e1)), sq_len(p2 - p1)))
        keep[a : a + len(rows)] = area2 > 1e-12 * np.maximum(edge, 1e-300) ** 2
    return keep


def labelled_parts(
    vertices: np.ndarray,
    faces: np.ndarray,
    face_label: np.ndarray,
    *,
    name_prefix: str = "",
    label: str | None = None,
    tree_id: int = 0,
) -> list[MeshPart]:
    """Split a mesh whose triangles carry label codes into one part per code.

    Parameters
    ----------
    vertices : (v, 3) float
        Vertex coordinates (m). One label: the part shares them (not copied); several:
        each part gets a copy of the vertices its triangles use.
    faces : (f, 3) int
        Triangles as vertex indices.
    face_label : (f,) int
        Label code per triangle (``treesim.cloud.LABEL_CODES``; unknown codes become
        ``other``).
    name_prefix : str
        Prefix of the part names, which end in the code's label name.
    label : str, optional
        Force this label on every part (the names keep the codes' names).
    tree_id : int
        The parts' tree id (see :class:`MeshPart`).

    Returns
    -------
    list of MeshPart
        In ascending code order; empty if there are no triangles.
    """
    codes = np.asarray(face_label)
    faces = np.asarray(faces)
    present = np.unique(codes)
    parts = []
    for code in present:
        name = LABEL_NAMES.get(int(code), "other")
        part_faces = faces[codes == code]
        part_vertices = vertices
        if len(present) > 1:
            # each part keeps only its own vertices: a plot of leafy trees would
            # otherwise hold every vertex once per label
            used, inverse = np.unique(part_faces, return_inverse=True)
            part_vertices = np.asarray(vertices)[used]
            part_faces = inverse.reshape(-1, 3)
        parts.append(
            MeshPart(
                vertices=part_vertices,
                faces=part_faces,
                label=label or name,
                name=f"{name_prefix}{name}",
                tree_id=tree_id,
            )
        )
    return parts
