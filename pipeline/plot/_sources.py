"""Plot trees from their sources: a procedural species (fitted to a DBH and height), a
mesh file, a QSM cylinder table, or a field cloud reconstructed into a QSM once and kept.

Every source gives the tree "as made" with its stem base at the origin: the lowest
vertex's height, and the x, y centroid of the vertices within :data:`BASE_BAND_M` of it.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..cloud import LABEL_CODES
from ..errors import InputFormatError, InvalidParameterError, ReconstructionError, TreesimError

if TYPE_CHECKING:
    from ..models import CylinderTable, TreeParams

PlotTree = Any  # a treesim.plot.core.PlotTree (not imported: core imports this module)

__all__ = ["BASE_BAND_M", "FIT_ITERATIONS", "fit_species", "local_tree", "stem_base"]

#: Height band above the lowest vertex whose x, y centroid is the stem base (m).
BASE_BAND_M = 0.05
#: Passes of the DBH/height fit of a procedural species (each one generation).
FIT_ITERATIONS = 3
#: Folder (beside the plot file) where reconstructions of field clouds are kept.
CACHE_FOLDER = ".treesim-cache"


def stem_base(v: np.ndarray) -> np.ndarray:
    """(3,) float64: the x, y centroid of the vertices within :data:`BASE_BAND_M` of the
    lowest one, at the lowest one's height."""
    v = np.asarray(v, dtype=np.float64)
    z0 = float(v[:, 2].min())
    low = v[v[:, 2] <= z0 + BASE_BAND_M]
    return np.array([low[:, 0].mean(), low[:, 1].mean(), z0])


@lru_cache(maxsize=512)
def fit_species(species: str, seed: int, dbh_m: float | None, height_m: float | None) -> TreeParams:
    """The species' parameters with ``trunk_length_m`` (for the height) and
    ``radius_ratio`` (for the DBH) adjusted so that the tree of this seed comes close to
    the targets (a few multiplicative corrections; the tree's truth is what its table
    says, not the target). No target: the preset as it is."""
    from ..models import generate_tree, species_preset

    params = species_preset(species)
    if dbh_m is None and height_m is None:
        return params
    # the trunk's length is the target's business now: no random variation (its draw
    # is still made, so the rest of the tree keeps its random numbers)
    params = replace(params, trunk_length_var_m=0.0)
    for _ in range(FIT_ITERATIONS):
        s = generate_tree(params, seed=int(seed), leaves=False).cylinders.summary()
        length, ratio = params.trunk_length_m, params.radius_ratio
        if height_m is not None:
            length = min(200.0, length * height_m / s["height_m"])
        if dbh_m is not None and s["dbh_m"]:
            ratio = min(0.2, ratio * dbh_m / s["dbh_m"])
        try:
            params = replace(params, trunk_length_m=length, radius_ratio=ratio)
        except InvalidParameterError as exc:
            raise InvalidParameterError(
                f"{species}: cannot reach DBH {dbh_m} m and height {height_m} m ({exc})"
            ) from exc
    return params


def _file(tree: PlotTree, base_dir: Path | None) -> Path:
    p = Path(str(tree.path))
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    if not p.is_file():
        raise InputFormatError(
            f"{tree.name}: {p} not found; paths in a plot file are relative to its folder"
        )
    return p


def cloud_table(tree: PlotTree, base_dir: Path | None, reconstruct: Any = None) -> CylinderTable:
    """The QSM of a field cloud, reconstructed once: kept in ``.treesim-cache/`` beside the
    plot file under the cloud's content hash and the reconstruction's parameters."""
    from ..atomic import atomic_path
    from ..io import read_cloud
    from ..models import read_cylinders, write_cylinders
    from ..params import ReconstructParams
    from ..reconstruct import reconstruct as run_reconstruct
    from ..run import file_sha256

    src = _file(tree, base_dir)
    params = reconstruct or ReconstructParams(method="qsm")
    if params.method != "qsm":
        params = replace(params, method="qsm")
    key = hashlib.sha256(
        (file_sha256(src) + json.dumps(params.to_dict(), sort_keys=True, default=str)).encode()
    ).hexdigest()[:16]
    folder = (base_dir or src.parent) / CACHE_FOLDER / f"{src.stem}-{key}"
    table_path = folder / "cylinders.csv"
    if table_path.is_file():
        return read_cylinders(table_path)
    try:
        model = run_reconstruct(read_cloud(src), params)
    except TreesimError as exc:
        raise ReconstructionError(f"{tree.name}: reconstructing {src} failed: {exc}") from exc
    if model.cylinders is None or len(model.cylinders) == 0:
        raise ReconstructionError(f"{tree.name}: {src} gave no cylinders; check the cloud")
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(table_path) as tmp:
        write_cylinders(tmp, model.cylinders)
    return model.cylinders


def source_table(
    tree: PlotTree, base_dir: Path | None, reconstruct: Any = None
) -> CylinderTable | None:
    """The tree's cylinder table as made (None for a mesh tree)."""
    from ..models import generate_tree, read_cylinders

    if tree.source == "species":
        params = fit_species(str(tree.species), tree.seed, tree.dbh_m, tree.height_m)
        return generate_tree(params, seed=int(tree.seed), leaves=False).cylinders
    if tree.source == "qsm":
        src = _file(tree, base_dir)
        try:
            return read_cylinders(src)
        except TreesimError as exc:
            raise InputFormatError(f"{tree.name}: {exc}") from exc
    if tree.source == "cloud":
        return cloud_table(tree, base_dir, reconstruct)
    return None


def local_tree(
    tree: PlotTree,
    facets: int,
    base_dir: Path | None,
    reconstruct: Any = None,
    table: CylinderTable | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, CylinderTable | None]:
    """The tree as made: vertices, faces, label codes, its stem base (3,) in the
    source's coordinates (subtract it to stand the tree at the origin) and its cylinder
    table (None for a mesh tree).

    ``table``: the tree's table as an earlier build made it (a plot rebuilding a tree it
    dropped): a leafless procedural tree is then meshed from it, neither fitted nor
    generated again (the same mesh: its wood is its table's tubes).

    Examples
    --------
    >>> import treesim as ts
    >>> from treesim.plot._sources import local_tree
    >>> tree = ts.PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species="sapling", leaves=False)
    >>> v, f, lab, base, table = local_tree(tree, 8, None)
    >>> again = local_tree(tree, 8, None, table=table)
    >>> bool((again[0] == v).all() and (again[1] == f).all()), again[4] is table
    (True, True)
    """
    from ..models import generate_tree, qsm_mesh, tubes_to_mesh
    from ..params.models import ModelParams

    if tree.source == "species":
        if table is not None and not _leafy(tree):
            # a leafless procedural tree's mesh is its table's tubes (ProceduralTree.mesh)
            wood = tubes_to_mesh(table, facets=facets)
            lab = np.full(len(wood.faces), LABEL_CODES["wood"], dtype=np.uint8)
            return wood.vertices, wood.faces, lab, np.zeros(3), table
        params = fit_species(str(tree.species), tree.seed, tree.dbh_m, tree.height_m)
        made = generate_tree(params, seed=int(tree.seed), leaves=tree.leaves)
        v, f, lab = made.mesh(facets)
        return v, f, lab, np.zeros(3), made.cylinders
    if tree.source == "mesh":
        from ..io import load_mesh

        src = _file(tree, base_dir)
        parts = load_mesh(src)
        vs, fs, ls, off = [], [], [], 0
        for part in parts:
            pv = np.asarray(part.vertices, dtype=np.float64)
            pf = np.asarray(part.faces, dtype=np.int64)
            vs.append(pv)
            fs.append(pf + off)
            ls.append(np.full(len(pf), LABEL_CODES[part.label], dtype=np.uint8))
            off += len(pv)
        v, f, lab = np.concatenate(vs), np.concatenate(fs), np.concatenate(ls)
        if len(f) == 0:
            raise InputFormatError(f"{tree.name}: {src} has no triangles")
        used = v[np.unique(f)]
        if not np.isfinite(used).all():
            raise InputFormatError(f"{tree.name}: {src} has NaN or infinite vertices")
        return v, f, lab, stem_base(used), None
    table = source_table(tree, base_dir, reconstruct)
    assert table is not None
    v, f, _ = qsm_mesh(table, facets=facets, joints=ModelParams().joints)
    lab = np.full(len(f), LABEL_CODES["wood"], dtype=np.uint8)
    return v, f, lab, stem_base(v), table


def _leafy(tree: PlotTree) -> bool:
    """Whether a procedural tree has leaves (its ``leaves``, else its species' own: the
    fit changes the trunk's length and the radius ratio, never the leaves)."""
    from ..models import species_preset

    return bool(species_preset(str(tree.species)).leaves_on if tree.leaves is None else tree.leaves)


def placed_table(
    table: CylinderTable, base: np.ndarray, scale: float, rot: np.ndarray, shift: np.ndarray
) -> CylinderTable:
    """``table`` moved as its tree is placed: base to the origin, scaled, turned by ``rot``
    (3, 3), shifted by ``shift`` (3,)."""
    start = ((np.asarray(table.start) - base) * scale) @ rot.T + shift
    axis = np.asarray(table.axis) @ rot.T
    return replace(
        table,
        start=start,
        axis=axis,
        length_m=np.asarray(table.length_m) * scale,
        radius_m=np.asarray(table.radius_m) * scale,
        end_radius_m=np.asarray(table.end_radius_m) * scale,
        unmod_radius_m=np.asarray(table.unmod_radius_m) * scale,
    )


def rotation(deg: float) -> np.ndarray:
    """(3, 3) turn about +z, counter-clockwise by ``deg``."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
