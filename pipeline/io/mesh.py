"""Mesh files written at full precision, with part labels that ``load_mesh`` reads back.

trimesh's PLY exporter writes float32 vertices, which moves a vertex at y = 5 500 000 by
up to 0.5 m; these writers keep float64:

* ``.ply``: binary, ``double x, y, z``, faces with a ``label`` (uint8) property and a
  ``comment treesim label_names`` line;
* ``.obj``: text with 17 significant digits, one ``o``/``usemtl`` group per label
  (``wood``, ``leaf``, ...) and a ``.mtl`` beside it, so treesim and other tools see
  the parts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..cloud import LABEL_CODES, LABEL_NAMES
from ..errors import InputFormatError, InvalidGeometryError

MESH_WRITE_SUFFIXES = (".ply", ".obj")


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
        Label code per face (``pipeline.cloud.LABEL_CODES``); default all ``wood``.
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


def _write_ply(path: Path, v: np.ndarray, f: np.ndarray, lab: np.ndarray) -> None:
    from plyfile import PlyData, PlyElement

    vert = np.empty(len(v), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vert["x"], vert["y"], vert["z"] = v[:, 0], v[:, 1], v[:, 2]
    face = np.empty(len(f), dtype=[("vertex_indices", "O"), ("label", "u1")])
    face["vertex_indices"] = list(f.astype(np.int32))
    face["label"] = lab
    names = ",".join(f"{k}={n}" for k, n in sorted(LABEL_NAMES.items()))
    PlyData(
        [
            PlyElement.describe(vert, "vertex"),
            PlyElement.describe(
                face, "face", len_types={"vertex_indices": "u1"}, val_types={"vertex_indices": "i4"}
            ),
        ],
        text=False,
        byte_order="<",
        comments=[f"treesim label_names {names}"],
    ).write(str(path))


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
