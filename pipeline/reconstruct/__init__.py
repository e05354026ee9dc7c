"""Reconstruction (the FMPRT path): a field point cloud of one tree -> a tree mesh.

``reconstruct(cloud, ReconstructParams(method=...))`` prepares the cloud (validation,
voxel downsampling, outlier removal, optional ground removal, normals), then builds

* ``qsm`` (default): a cylinder QSM (:mod:`treesim.reconstruct.qsm`), meshed as one
  closed, mitred tube per branch whose start is sunk into its parent
  (:func:`treesim.models.branch_tubes`: no buried end caps between a branch's
  cylinders, no notches at bends or junctions), labelled wood;
* ``poisson``: a screened Poisson surface (pymeshlab, in a child process), trimmed by
  density;
* ``bpa``: a ball-pivoting surface (pymeshlab, in a child process).

The result, a :class:`TreeModel`, carries the mesh in the input's coordinates
(float64), the cylinder table (qsm), and the tree's figures under the same names as the
model library's ``truth.json`` (``dbh_m``, ``height_m``, ``volume_total_m3``, ...), so a
reconstruction and its truth compare key by key.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..cloud import LABEL_CODES, Cloud
from ..errors import ReconstructionError
from ..jsonio import write_json
from ..models import CylinderTable, branch_tubes, mesh_volume, write_cylinders
from ..params import METHODS, PrepareParams, QSMParams, ReconstructParams

if TYPE_CHECKING:  # the stages import scipy: loaded when a reconstruction runs, so that
    # `import treesim` (every treesim command) does not pay for it
    from .preprocess import PreparedCloud
    from .qsm import QSMResult

__all__ = [
    "METHODS",
    "OUTPUT_FILES",
    "PrepareParams",
    "QSMParams",
    "ReconstructParams",
    "TreeModel",
    "cloud_dbh_m",
    "reconstruct",
]

#: The files :meth:`TreeModel.write` writes into its folder, by key of the paths it
#: returns (``cylinders`` for qsm only).
OUTPUT_FILES = {
    "mesh": "tree.ply",
    "cylinders": "cylinders.csv",
    "json": "tree.json",
    "labels": "labels.laz",
}


@dataclass
class TreeModel:
    """A reconstructed tree.

    Attributes
    ----------
    method : str
    vertices : (v, 3) float64
        Mesh vertices in the input's coordinates.
    faces : (f, 3) int64
    face_label : (f,) uint8
        ``treesim.cloud.LABEL_CODES`` per face (all wood today).
    cylinders : CylinderTable or None
        The QSM in the input's coordinates (qsm only).
    figures : dict
        ``dbh_m``, ``height_m``, ``volume_total_m3``, ``volume_stem_m3``,
        ``volume_branch_m3``, ``n_cylinders``, ``watertight``, ``n_triangles``,
        ``branches_per_order``, crown extent, ``leaves_present`` (with ``separate_leaves``
        auto or on: the wood/leaf classifier's ``leaf_share`` reached
        ``_leaves.LEAF_SHARE_CUT``; with off: preparation's ``leaf_fraction``, a cheaper
        and less reliable measure, reached its cut)... For qsm the volumes
        are the cylinder table's; ``mesh_volume_m3`` is the mesh's (its closed tubes'
        volumes summed: the table's inscribed prisms plus ``junction_volume_m3``, the
        branch starts sunk into their parents), ``n_tubes`` its closed pieces.
    preparation : dict
        What preparation did (points removed per step, spacing).
    params : dict
    timings_s : dict
    diagnostics : dict
    labels : Cloud or None
        With leaves separated: the prepared points in the input's coordinates with a
        ``label`` field (``LABEL_CODES``: 1 wood, 2 leaf), written as ``labels.laz``.
    """

    method: str
    vertices: np.ndarray
    faces: np.ndarray
    face_label: np.ndarray
    cylinders: CylinderTable | None
    figures: dict[str, Any]
    preparation: dict[str, Any]
    params: dict[str, Any]
    timings_s: dict[str, float]
    diagnostics: dict[str, Any] = field(default_factory=dict)
    labels: Cloud | None = None

    def to_dict(self) -> dict[str, Any]:
        """``tree.json``'s content."""
        from .._version import software_versions

        return {
            **self.figures,
            "method": self.method,
            "params": self.params,
            "preparation": self.preparation,
            "timings_s": self.timings_s,
            "diagnostics": self.diagnostics,
            "software": software_versions("pymeshlab", "trimesh"),
        }

    def write(self, outdir: str | Path) -> dict[str, Path]:
        """Write ``tree.ply``, ``cylinders.csv`` (qsm) and ``tree.json`` into ``outdir``."""
        from ..io.mesh import write_mesh

        out = Path(outdir)
        out.mkdir(parents=True, exist_ok=True)
        name = OUTPUT_FILES
        paths = {
            "mesh": write_mesh(
                out / name["mesh"], self.vertices, self.faces, face_label=self.face_label
            )
        }
        if self.cylinders is not None:
            paths["cylinders"] = write_cylinders(out / name["cylinders"], self.cylinders)
        if self.labels is not None:
            from ..io.las import write_las

            paths["labels"] = write_las(out / name["labels"], self.labels)
        paths["json"] = write_json(out / name["json"], self.to_dict())
        return paths


def cloud_dbh_m(
    points: np.ndarray, *, spacing_m: float, height_m: float = 1.3, band_m: float = 0.1
) -> float | None:
    """Diameter at ``height_m`` above the lowest point from a circle fit to the points in
    a ``band_m`` slab (None when the slab holds too few points or the fit is poor)."""
    p = np.asarray(points, dtype=np.float64)
    z0 = float(p[:, 2].min())
    sel = np.abs(p[:, 2] - (z0 + height_m)) <= band_m / 2
    if sel.sum() < 10:
        return None
    q = p[sel, :2] - p[sel, :2].mean(axis=0)
    from .qsm import fit_circle

    fit = fit_circle(q, np.ones(len(q)), np.random.default_rng(0), max(spacing_m, 0.001))
    if fit is None or fit.coverage_deg < 180 or fit.inlier_share < 0.5:
        return None
    return 2.0 * fit.radius


def _edge_watertight(faces: np.ndarray) -> bool:
    """Every edge used exactly twice, once in each direction (closed and oriented).

    The directed edges (a, b) must be distinct, and their reverses (b, a) the same set:
    two sorts of int64 keys (``np.unique`` and ``np.isin`` on the 7.8 M edges of a
    20,000-cylinder QSM took 15 s and 1 GB)."""
    if len(faces) == 0:
        return False
    f = np.asarray(faces, dtype=np.int64)
    base = int(f.max()) + 1
    a, b = f.ravel(), np.roll(f, -1, axis=1).ravel()  # each corner and the next one
    fwd = a * base + b
    fwd.sort()
    if (fwd[1:] == fwd[:-1]).any():
        return False
    rev = b * base + a
    del a, b
    rev.sort()
    return bool(np.array_equal(fwd, rev))


def _crown(points: np.ndarray, base_z: float, crown_base_z: float | None) -> dict[str, Any]:
    p = points
    zc = crown_base_z if crown_base_z is not None else base_z
    sel = p[:, 2] >= zc
    q = p[sel] if sel.sum() >= 3 else p
    ext = np.ptp(q[:, :2], axis=0)
    return {
        "crown_extent_x_m": float(ext[0]),
        "crown_extent_y_m": float(ext[1]),
        "crown_diameter_m": float(ext.mean()),
        "crown_base_height_m": None if crown_base_z is None else float(crown_base_z - base_z),
    }


def reconstruct(
    cloud: Cloud | np.ndarray,
    params: ReconstructParams | None = None,
    *,
    progress: Any = None,
) -> TreeModel:
    """Reconstruct one tree from its point cloud.

    Parameters
    ----------
    cloud : Cloud or (n, 3) float array
        The tree's points, in any coordinates (georeferenced is fine).
    params : ReconstructParams
    progress : callable(fraction, message), optional

    Returns
    -------
    TreeModel

    Examples
    --------
    >>> import treesim as ts
    >>> cloud = ts.read_cloud("tree.laz")  # doctest: +SKIP
    >>> model = ts.reconstruct(cloud, ts.ReconstructParams(method="qsm"))  # doctest: +SKIP
    >>> model.write("out/tree")  # doctest: +SKIP
    """
    params = params or ReconstructParams()
    say = progress or (lambda f, m: None)
    t0 = time.perf_counter()
    say(0.0, "preparing")
    from .preprocess import prepare

    prepared = prepare(cloud, params.prepare, normals=params.method != "qsm")
    t_prep = time.perf_counter() - t0
    separated = _separate(prepared, params, say)
    say(0.3, f"reconstructing ({params.method})")
    model, t_rec = _built(prepared, separated, params)
    if _second_opinion_due(model, params):
        model = _second_opinion(prepared, model, params, say)
    model.timings_s = {
        "prepare": t_prep,
        "reconstruct": t_rec,
        "total": time.perf_counter() - t0,
        **model.timings_s,
    }
    say(1.0, "done")
    return model


def _built(
    prepared: PreparedCloud,
    separated: Any,
    params: ReconstructParams,
    leaf_model: str | None = None,
) -> tuple[TreeModel, float]:
    """The model built from ``prepared`` (its wood points where ``separated`` is used),
    with the separation's labels and figures and the plausibility figures and warnings
    (``figures["plausibility"]``, ``figures["warnings"]``); and its build's seconds.
    ``leaf_model``: the classifier that labelled it, as ``figures["leaf_model"]``."""
    if separated is not None and separated.used:
        prepared = separated.wood
    t1 = time.perf_counter()
    if params.method == "qsm":
        model = _qsm_model(prepared, params)
    else:
        model = _surface_model(prepared, params)
    t_rec = time.perf_counter() - t1
    if separated is not None:
        separated.apply(model, params)
    if leaf_model is not None:
        model.figures["leaf_model"] = leaf_model
    from .plausibility import add_plausibility

    add_plausibility(model, prepared)
    return model, t_rec


#: Warnings of a first QSM after which the frond model separates the leaves again (a
#: second opinion): both say that leaves may have been taken for wood. Palms' leaflets
#: hang in curtains that the shipped classifier takes for twigs at field density.
SECOND_OPINION_CODES = frozenset({"leaves_as_wood", "volume_total_high"})


def _codes(model: TreeModel) -> set[str]:
    return {str(w["code"]) for w in model.figures.get("warnings") or []}


def _second_opinion_due(model: TreeModel, params: ReconstructParams) -> bool:
    return (
        params.method == "qsm"
        and params.separate_leaves in ("auto", "on")
        and bool(_codes(model) & SECOND_OPINION_CODES)
    )


#: Largest change of the DBH that a second opinion on the leaves may bring: leaves are
#: not at breast height on a stem, so a larger change means the frond model took stem
#: points for leaves (a palm scanned at 0.3°: DBH 158 mm low, the stem 85 % short).
SECOND_OPINION_DBH_CHANGE = 0.05


def _second_opinion(
    prepared: PreparedCloud, first: TreeModel, params: ReconstructParams, say: Any
) -> TreeModel:
    """Separate the leaves again with the frond model and rebuild; keep the second model
    only where it clears :data:`SECOND_OPINION_CODES`, ends with no more warnings in all
    (the real palm's: its column of a stem reads a form factor of 0.67, above the range
    published for conifers and broadleaves, in place of two volume warnings) and keeps
    the DBH within :data:`SECOND_OPINION_DBH_CHANGE`. Either way
    ``diagnostics["second_opinion"]`` says what was tried and found, and
    ``figures["leaf_model"]`` which classifier the kept model's labels come from."""
    from ._leaves import separate
    from .leafwood import fronds_model

    say(0.6, "leaves taken for wood? separating again with the frond model")
    t0 = time.perf_counter()
    separated = separate(prepared, params.separate_leaves, fronds_model())
    second = None
    if separated is not None and separated.used:
        second, _ = _built(prepared, separated, params, leaf_model="fronds")
    before = _codes(first)
    after = None if second is None else _codes(second)
    dbh = [first.figures.get("dbh_m"), None if second is None else second.figures.get("dbh_m")]
    same_stem = bool(dbh[0] and dbh[1]) and abs(dbh[1] / dbh[0] - 1) <= SECOND_OPINION_DBH_CHANGE
    keep = (
        after is not None
        and not after & SECOND_OPINION_CODES
        and len(after) <= len(before)
        and same_stem
    )
    chosen = second if keep and second is not None else first
    chosen.figures["leaf_model"] = "fronds" if chosen is second else "default"
    chosen.diagnostics["second_opinion"] = {
        "why": sorted(before & SECOND_OPINION_CODES),
        "model": "fronds",
        "leaf_share": None if separated is None else separated.figures.get("leaf_share"),
        "warnings": None if after is None else sorted(after),
        "dbh_m": dbh,
        "kept": chosen is second,
    }
    chosen.timings_s["second_opinion"] = time.perf_counter() - t0
    return chosen


def _separate(prepared: PreparedCloud, params: ReconstructParams, say: Any) -> Any:
    """Wood/leaf separation when ``params.separate_leaves`` asks for it (else None)."""
    mode = params.separate_leaves
    if mode == "off":
        return None
    say(0.2, "separating wood from leaves" if mode == "on" else "looking for leaves")
    from ._leaves import separate

    return separate(prepared, mode)


def _common_figures(prepared: PreparedCloud) -> dict[str, Any]:
    pts = prepared.points
    return {
        "dbh_cloud_m": cloud_dbh_m(pts, spacing_m=prepared.spacing_m),
        "height_cloud_m": float(np.ptp(pts[:, 2])),
        "leaves_present": bool(prepared.leaves_present),
        "leaf_fraction": float(prepared.leaf_fraction),
        "points_input": int(prepared.n_input),
        "points_used": int(len(prepared.points)),
        "spacing_m": float(prepared.spacing_m),
    }


def _qsm_model(prepared: PreparedCloud, params: ReconstructParams) -> TreeModel:
    from .qsm import fit_qsm

    res: QSMResult = fit_qsm(
        prepared.points,
        spacing_m=prepared.spacing_m,
        weights=prepared.weights,
        params=params.qsm,
        neighbors=prepared.neighbors,
        foot=prepared.foot,
    )
    origin = prepared.frame.origin_array
    table = replace(res.table, start=res.table.start + origin)
    table.validate()
    t0 = time.perf_counter()
    tubes, sunk = branch_tubes(table, facets=params.facets)
    v, f = tubes.vertices, tubes.faces
    t_mesh = time.perf_counter() - t0
    s = table.summary()
    base_z = float(prepared.points[:, 2].min())
    order1 = table.branch_order == 1
    crown_base = None
    if order1.any():
        crown_base = float(table.start[order1, 2].min() - origin[2])
    figures = {
        "dbh_m": s["dbh_m"],
        "height_m": s["height_m"],
        "volume_total_m3": s["volume_total_m3"],
        "volume_stem_m3": s["volume_stem_m3"],
        "volume_branch_m3": s["volume_branch_m3"],
        "n_cylinders": s["n_cylinders"],
        "branches_per_order": s["branches_per_order"],
        "watertight": _edge_watertight(f),
        "n_triangles": int(len(f)),
        "n_tubes": tubes.n_tubes,
        "mesh_volume_m3": float(mesh_volume(v, f)),
        "junction_volume_m3": sunk.plug_volume_m3(params.facets),
        "cylinders_by_tag": res.diagnostics["cylinders_by_tag"],
        "noise_sd_m": res.diagnostics["noise"]["sd_m"],
        **_crown(prepared.points, base_z, crown_base),
        **_common_figures(prepared),
    }
    return TreeModel(
        method="qsm",
        vertices=v,
        faces=f,
        face_label=np.full(len(f), LABEL_CODES["wood"], dtype=np.uint8),
        cylinders=table,
        figures=figures,
        preparation=prepared.summary(),
        params=params.to_dict(),
        timings_s={"mesh": t_mesh},
        diagnostics={
            **res.diagnostics,
            "mesh": {
                "joints": "miter",
                "tubes": tubes.n_tubes,
                "branch_starts": sunk.branch_starts,
                "branch_starts_sunk": sunk.n_plugs,
            },
        },
    )


def _surface_model(prepared: PreparedCloud, params: ReconstructParams) -> TreeModel:
    from .surface import ball_pivoting, poisson

    if params.method == "poisson":
        sr = poisson(
            prepared,
            depth=params.poisson_depth,
            trim_density_quantile=params.poisson_trim_quantile,
            timeout_s=params.timeout_s,
        )
    else:
        sr = ball_pivoting(prepared, radii_m=params.bpa_radii_m, timeout_s=params.timeout_s)
    if sr.n_triangles == 0:
        raise ReconstructionError(f"{params.method} produced no triangles")
    base_z = float(prepared.points[:, 2].min())
    figures = {
        "dbh_m": _common_figures(prepared)["dbh_cloud_m"],
        "height_m": float(np.ptp(sr.vertices[:, 2])),
        "volume_total_m3": sr.volume_m3,
        "volume_stem_m3": None,
        "volume_branch_m3": None,
        "n_cylinders": 0,
        "branches_per_order": {},
        "watertight": bool(sr.watertight),
        "n_triangles": int(sr.n_triangles),
        "mesh_volume_m3": sr.volume_m3,
        **_crown(prepared.points, base_z, None),
        **_common_figures(prepared),
    }
    return TreeModel(
        method=params.method,
        vertices=sr.vertices,
        faces=sr.faces,
        face_label=np.full(len(sr.faces), LABEL_CODES["wood"], dtype=np.uint8),
        cylinders=None,
        figures=figures,
        preparation=prepared.summary(),
        params=params.to_dict(),
        timings_s={f"surface_{k}": v for k, v in sr.timings.items()},
        diagnostics=sr.summary(),
    )
