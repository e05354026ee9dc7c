"""AVOHD comparison: absolute point distances between a cloud and a reference, both ways.

The method judges a (simulated) cloud by the absolute values of its Hausdorff distances
(AVOHD) to a reference, which is a triangle mesh (the tree model that was scanned) or
another cloud (the field scan):

* **accuracy** -- every point of the cloud to the reference: point-to-triangle for a mesh,
  nearest neighbour for a cloud. Small values mean the points lie on the reference.
* **completeness** -- the reference to the cloud: for a mesh, points sampled uniformly by
  area on its surface (seeded, about one per ``sample_spacing_m²``); for a cloud, its
  points. Small values mean the reference was seen. Accuracy alone can never show
  occlusion: a cloud covering half a stem has perfect accuracy and 50 % coverage.

Only surface a scanner could see counts: a mesh made of overlapping closed parts (separate
cylinders whose end caps are buried in the next one, branches starting inside their
parents) has area inside the solid, and samples there would measure the mesh's
construction, not the scan. Samples that lie inside another closed part of the same mesh
(ray parity per part, :func:`treesim.geometry.inside_other_parts`) are dropped, and
``reference.hidden_surface`` says how much area that was (estimated from the
area-uniform samples, with its standard error) and why (``hidden_surface="keep"`` keeps
them).

Definitions used throughout (and written into ``comparison.json``):

* ``hausdorff_m``: ``max(accuracy.max_m, completeness.max_m)``, the symmetric Hausdorff
  distance (for a mesh reference, estimated on the surface samples);
* ``chamfer_m``: ``(accuracy.mean_m + completeness.mean_m) / 2``, the mean of the two
  directions' mean absolute distances (some authors sum them, i.e. twice this, or average
  squared distances; treesim uses the symmetric mean so that it reads in metres);
* ``coverage``: the fraction (0-1) of reference samples that have a cloud point within
  ``tolerance_m``;
* ``tolerance_m`` (τ) defaults to ``3 × point_spacing_m``, where ``point_spacing_m`` is
  the cloud's median nearest-neighbour distance. Rationale: even points scattered at
  random (Poisson) with that median spacing leave only 2⁻⁹ ≈ 0.2 % of a fully sampled
  surface farther than 3s from every point, and a regular grid of spacing ``g`` leaves no
  point farther than ``g/√2``, so surfaces sampled up to 4× more sparsely than the median
  (scan density falls with range and incidence) still count as covered, while real gaps
  (occlusion) do not;
* ``sample_spacing_m`` defaults to ``point_spacing_m``: the mesh is sampled about as
  densely as the cloud (``area / spacing²`` samples, clamped to ``min_samples`` ..
  ``max_samples``).

Precision: everything is float64, in a :class:`~treesim.frame.LocalFrame`. Open3D's
``RaycastingScene`` (float32) only *picks* the closest triangle; the distance to it is
recomputed exactly in float64 (Ericson's region test), so a point lying on the mesh
measures ~1e-15 m, and ~1e-9 m at UTM coordinates (the rounding of the input itself).
Two measured Open3D 0.20 pitfalls are handled:

* its float32 closest-point routine cancels catastrophically on sliver triangles (long,
  thin cylinder facets, as QSM meshes have) whose first corner is the sharp apex: up to
  1.5 mm off, for 47 % of the points on a 0.15 m × 2 m, 256-facet cylinder. treesim hands
  it every triangle with the first corner opposite the longest edge
  (:func:`treesim.geometry.well_conditioned`), which removes the error;
* a float32 near-tie can pick the neighbour of the right triangle: where the closest
  point lies on the picked triangle's boundary, the triangles sharing that edge or
  corner are measured exactly too and the least distance is kept; so are the triangles
  around the picked one's corners where a point lies nearly on it (within float32's tie,
  above float64 noise: a point on the mesh beside a concave edge, which measured up to
  9.5e-9 m before).

What remains is the float32 choice between *non-adjacent* triangles whose distances tie
within float32 resolution (~1e-7 of the local frame's extent; ≤ 1e-7 m measured on the
coffee tree's QSM mesh). Nearest neighbours use SciPy's ``cKDTree`` in float64.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._version import software_versions
from .cloud import LABEL_NAMES, Cloud
from .errors import (
    EmptyInputError,
    InvalidGeometryError,
    InvalidParameterError,
)
from .frame import LocalFrame
from .geometry import (
    inside_other_parts,
    kdtree,
    mesh_parts,
    point_spacing,
    point_to_mesh_distances,
    sample_surface,
)
from .jsonio import write_json
from .params import MIN_CLOUD_POINTS, CompareParams
from .scene import MeshPart, Scene

__all__ = [
    "CompareParams",
    "Comparison",
    "DistanceStats",
    "compare",
    "write_comparison",
]

#: Name of the per-point distance field in the distance clouds (CloudCompare's convention).
DISTANCE_FIELD = "scalar_distance"

#: Plain-language definitions, written into ``comparison.json`` and the report.
DEFINITIONS: dict[str, str] = {
    "accuracy": "distance from every point of the cloud to the reference (m)",
    "completeness": "distance from every reference sample to the nearest cloud point (m)",
    "hausdorff_m": "max(accuracy.max_m, completeness.max_m): the symmetric Hausdorff distance",
    "chamfer_m": "(accuracy.mean_m + completeness.mean_m) / 2: mean of the two directions' means",
    "coverage": "fraction (0-1) of reference samples with a cloud point within tolerance_m",
    "tolerance_m": "default 3 × point_spacing_m (the cloud's median nearest-neighbour distance)",
    "point_spacing_m": "median distance from a cloud point to its nearest other point",
    "sample_spacing_m": "mesh references: one surface sample per sample_spacing_m² of area",
    "hidden_surface": "mesh references: area inside another closed part of the same mesh, "
    "which no scanner outside can see; its samples are left out of completeness and coverage",
}

#: Default coverage tolerance, in multiples of the cloud's median point spacing.
TOLERANCE_FACTOR = 3.0


# -- parameters and statistics --------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class DistanceStats:
    """Summary of absolute distances (m); every figure is ``None`` when ``n == 0``."""

    n: int
    mean_m: float | None
    rms_m: float | None
    median_m: float | None
    p95_m: float | None
    p99_m: float | None
    max_m: float | None

    @classmethod
    def of(cls, distances: np.ndarray) -> DistanceStats:
        """Statistics of ``distances`` : (n,) float64 (linear-interpolated percentiles)."""
        d = np.asarray(distances, dtype=np.float64).ravel()
        if len(d) == 0:
            return cls(
                n=0, mean_m=None, rms_m=None, median_m=None, p95_m=None, p99_m=None, max_m=None
            )
        med, p95, p99 = np.percentile(d, [50.0, 95.0, 99.0])
        return cls(
            n=int(len(d)),
            mean_m=float(d.mean()),
            rms_m=float(np.sqrt(np.mean(d * d))),
            median_m=float(med),
            p95_m=float(p95),
            p99_m=float(p99),
            max_m=float(d.max()),
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# -- helpers --------------------------------------------------------------------------
def _workers(nthreads: int) -> int:
    return -1 if int(nthreads) == 0 else int(nthreads)


# -- references -----------------------------------------------------------------------
@dataclass
class _Reference:
    kind: str  # "mesh" or "cloud"
    points: np.ndarray  # mesh vertices or cloud points (float64, input coordinates)
    faces: np.ndarray | None
    face_label: np.ndarray | None
    point_label: np.ndarray | None
    label_names: dict[int, str]
    info: dict[str, Any]


def _label_names(metadata: Mapping[str, Any]) -> dict[int, str]:
    """``{code: name}`` from a cloud's ``label_names`` metadata (either way round)."""
    value = metadata.get("label_names")
    if isinstance(value, Mapping) and value:
        try:
            return {int(k): str(v) for k, v in value.items()}
        except (TypeError, ValueError):
            try:
                return {int(v): str(k) for k, v in value.items()}
            except (TypeError, ValueError):
                pass
    return dict(LABEL_NAMES)


def _check_cloud(cloud: Cloud, what: str) -> Cloud:
    if not isinstance(cloud, Cloud):
        raise InvalidParameterError(f"the {what} must be a Cloud, got {type(cloud).__name__}")
    if len(cloud) == 0:
        raise EmptyInputError(f"the {what} has no points; nothing to compare")
    try:
        cloud.validate()
    except InvalidGeometryError as exc:
        raise InvalidGeometryError(f"the {what}: {exc}") from None
    n = len(cloud)
    if n < MIN_CLOUD_POINTS:
        raise EmptyInputError(
            f"the {what} has {'a single point' if n == 1 else f'only {n} points'}; a comparison "
            f"needs at least {MIN_CLOUD_POINTS} (fewer cannot span a volume); check that the "
            "right file was given"
        )
    return cloud


def _as_reference(reference: Any) -> _Reference:
    if isinstance(reference, Cloud):
        ref = _check_cloud(reference, "reference cloud")
        label = ref.fields.get("label")
        return _Reference(
            kind="cloud",
            points=ref.points,
            faces=None,
            face_label=None,
            point_label=None if label is None else np.asarray(label).astype(np.int64),
            label_names=_label_names(ref.metadata),
            info={"kind": "cloud", "points": len(ref)},
        )
    labelled = isinstance(reference, Scene)
    if isinstance(reference, tuple) and len(reference) == 2:
        v, f = reference
        v = np.asarray(v, dtype=np.float64)
        f = np.asarray(f)
        if v.size == 0 or f.size == 0:
            raise EmptyInputError("the reference mesh has no vertices or no triangles")
        if v.ndim != 2 or v.shape[1] != 3:
            raise InvalidGeometryError(f"mesh vertices must have shape (v, 3), got {v.shape}")
        reference = Scene([MeshPart(vertices=v, faces=f, label="other", name="reference mesh")])
    elif not labelled:
        raise InvalidParameterError(
            "the reference must be a Cloud, a Scene or a (vertices, faces) tuple, got "
            f"{type(reference).__name__}"
        )
    scene = reference
    v = np.asarray(scene.vertices, dtype=np.float64)
    f = np.asarray(scene.faces, dtype=np.int64)
    if len(f) == 0:
        raise EmptyInputError("the reference mesh has no triangles; nothing to compare")
    return _Reference(
        kind="mesh",
        points=v,
        faces=f,
        face_label=np.asarray(scene.face_label).astype(np.int64) if labelled else None,
        point_label=None,
        label_names=dict(LABEL_NAMES),
        info={
            "kind": "mesh",
            "vertices": len(v),
            "triangles": len(f),
            "degenerate_triangles_dropped": int(getattr(scene, "dropped_degenerate", 0)),
        },
    )


# -- the comparison -------------------------------------------------------------------
@dataclass
class Comparison:
    """The result of :func:`compare`.

    Attributes
    ----------
    accuracy, completeness : DistanceStats
        Statistics of the two directions (see the module docstring).
    hausdorff_m, chamfer_m, tolerance_m, coverage : float
        Top-level figures (definitions in :data:`DEFINITIONS`).
    point_spacing_m : float
        The cloud's median nearest-neighbour spacing (NaN when all points coincide and
        both ``tolerance_m`` and ``sample_spacing_m`` were given).
    sample_spacing_m : float or None
        Effective spacing of the mesh samples (None for a cloud reference).
    cloud : Cloud
        The compared cloud (input coordinates, with its fields).
    accuracy_m : (n,) float64
        Per cloud point: distance to the reference.
    reference_points : (m, 3) float64
        The reference samples (mesh) or points (cloud), input coordinates.
    completeness_m : (m,) float64
        Per reference sample: distance to the nearest cloud point.
    reference_label : (m,) int64 or None
        Label code of each reference sample, when the reference carries labels.
    reference_face : (m,) int64 or None
        Triangle of each mesh sample.
    by_label : dict of str -> dict
        Per hit label (``wood``, ``leaf``, ...): ``accuracy`` stats of the cloud points
        with that label; for labelled references also ``completeness`` stats and
        ``coverage`` of the reference samples with that label (to the whole cloud).
    by_station : dict of int -> dict
        Per station: ``accuracy`` stats of its points, and ``coverage`` of the whole
        reference by that station's points alone.
    reference_info : dict
        Kind, size, area of the reference.
    params : CompareParams
    frame : LocalFrame
        The frame the distances were computed in.
    timings_s : dict of str -> float
    station_distance_m : dict of int -> tuple
        Per station, what a report drawn in the same process needs of each reference
        sample's distance to that station's points (its occlusion profile asks the same
        question of the saved, rounded coordinates and queries only the samples this
        cannot answer), compactly: ``(within, index, distance_m)``, the bits (packed,
        :func:`numpy.packbits`) of the samples within τ, and the samples within
        :data:`STATION_DISTANCE_BAND_M` of τ with their distances; in memory only.
    """

    accuracy: DistanceStats
    completeness: DistanceStats
    hausdorff_m: float
    chamfer_m: float
    tolerance_m: float
    coverage: float
    point_spacing_m: float
    sample_spacing_m: float | None
    cloud: Cloud
    accuracy_m: np.ndarray
    reference_points: np.ndarray
    completeness_m: np.ndarray
    reference_label: np.ndarray | None
    reference_face: np.ndarray | None
    label_names: dict[int, str]
    by_label: dict[str, dict[str, Any]]
    by_station: dict[int, dict[str, Any]]
    reference_info: dict[str, Any]
    params: CompareParams
    frame: LocalFrame
    timings_s: dict[str, float] = field(default_factory=dict)
    #: How τ was chosen, in words, when a caller fixed it (a run: from the field cloud);
    #: default ``"given"`` or ``"3 × point_spacing_m"``.
    tolerance_rule: str | None = None
    station_distance_m: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=dict
    )

    def to_dict(self) -> dict[str, Any]:
        """The figures as JSON-ready values (no per-point arrays)."""
        return {
            "accuracy": self.accuracy.to_dict(),
            "completeness": self.completeness.to_dict(),
            "hausdorff_m": self.hausdorff_m,
            "chamfer_m": self.chamfer_m,
            "tolerance_m": self.tolerance_m,
            "coverage": self.coverage,
            "point_spacing_m": self.point_spacing_m,
            "cloud": {"points": len(self.cloud)},
            "reference": dict(self.reference_info),
            "by_label": self.by_label,
            "by_station": {str(k): v for k, v in self.by_station.items()},
            "parameters": {
                **asdict(self.params),
                "tolerance_m": self.tolerance_m,
                "tolerance_rule": self.tolerance_rule
                or ("given" if self.params.tolerance_m is not None else "3 × point_spacing_m"),
                "sample_spacing_m": self.sample_spacing_m,
                "sample_spacing_rule": None
                if self.sample_spacing_m is None
                else ("given" if self.params.sample_spacing_m is not None else "point_spacing_m"),
                "frame_origin_m": list(self.frame.origin),
            },
            "definitions": dict(DEFINITIONS),
            "timings_s": dict(self.timings_s),
        }

    def distance_cloud(self) -> Cloud:
        """The compared cloud with its fields plus ``scalar_distance`` (accuracy, m)."""
        fields = dict(self.cloud.fields)
        fields[DISTANCE_FIELD] = self.accuracy_m
        return Cloud(self.cloud.points, fields, dict(self.cloud.metadata))

    def reference_cloud(self) -> Cloud:
        """The reference samples with ``scalar_distance`` (completeness, m) and, when
        known, ``label`` and ``face_index``."""
        fields: dict[str, np.ndarray] = {DISTANCE_FIELD: self.completeness_m}
        if self.reference_label is not None:
            fields["label"] = self.reference_label.astype(np.uint8)
        if self.reference_face is not None:
            fields["face_index"] = self.reference_face.astype(np.int32)
        meta = {"label_names": dict(self.label_names)} if self.reference_label is not None else {}
        return Cloud(self.reference_points, fields, meta)


def _spacing_and_tolerance(
    cloud_local: np.ndarray, cloud_tree: Any, ref: _Reference, params: CompareParams, workers: int
) -> tuple[float, float]:
    """The cloud's median point spacing and the coverage tolerance τ."""
    try:
        spacing = point_spacing(
            cloud_local,
            subsample=params.spacing_subsample,
            seed=params.seed,
            tree=cloud_tree,
            workers=workers,
        )
    except InvalidGeometryError:
        needed = params.tolerance_m is None or (
            ref.kind == "mesh" and params.sample_spacing_m is None
        )
        if needed:
            raise
        spacing = math.nan  # every point coincides, but nothing derives from the spacing
    tau = (
        float(params.tolerance_m) if params.tolerance_m is not None else TOLERANCE_FACTOR * spacing
    )
    return spacing, tau


@dataclass
class _Measured:
    """The cloud's accuracy against a reference, and the reference's samples (local
    frame) whose completeness is measured next."""

    acc: np.ndarray
    ref_local: np.ndarray
    ref_label: np.ndarray | None
    ref_face: np.ndarray | None = None
    sample_spacing: float | None = None


def _against_mesh(
    cloud_local: np.ndarray,
    ref: _Reference,
    frame: LocalFrame,
    spacing: float,
    params: CompareParams,
    info: dict[str, Any],
    timings: dict[str, float],
) -> _Measured:
    """Accuracy to a mesh (point to triangle), then its surface samples (the visible ones
    unless ``hidden_surface="keep"``); adds the area and the samples to ``info``."""
    t0 = time.perf_counter()
    assert ref.faces is not None
    verts_local = frame.to_local(ref.points)
    acc = point_to_mesh_distances(cloud_local, verts_local, ref.faces, params.nthreads)
    timings["accuracy"] = time.perf_counter() - t0
    # completeness: surface samples -> cloud
    t0 = time.perf_counter()
    tri = verts_local[ref.faces]
    area = float(
        0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    )
    s_asked = float(params.sample_spacing_m) if params.sample_spacing_m is not None else spacing
    n_samples = int(np.clip(math.ceil(area / s_asked**2), params.min_samples, params.max_samples))
    sample_spacing = math.sqrt(area / n_samples)
    samples_local, ref_face = sample_surface(verts_local, ref.faces, n_samples, seed=params.seed)
    timings["sampling"] = time.perf_counter() - t0
    info.update(area_m2=area, samples=n_samples)
    if params.hidden_surface == "drop":
        t0 = time.perf_counter()
        visible, hidden_info = _visible_samples(
            samples_local, ref_face, verts_local, ref.faces, area, params
        )
        samples_local, ref_face = samples_local[visible], ref_face[visible]
        info.update(samples=int(visible.sum()), hidden_surface=hidden_info)
        timings["hidden_surface"] = time.perf_counter() - t0
    ref_label = ref.face_label[ref_face] if ref.face_label is not None else None
    return _Measured(acc, samples_local, ref_label, ref_face, sample_spacing)


def _against_cloud(
    cloud_local: np.ndarray,
    ref: _Reference,
    frame: LocalFrame,
    workers: int,
    timings: dict[str, float],
) -> _Measured:
    """Accuracy to a reference cloud (nearest neighbour); its points are the samples."""
    t0 = time.perf_counter()
    ref_local = frame.to_local(ref.points)
    ref_tree = kdtree(ref_local)
    acc, _ = ref_tree.query(cloud_local, k=1, workers=workers)
    timings["accuracy"] = time.perf_counter() - t0
    return _Measured(acc, ref_local, ref.point_label)


def compare(
    cloud: Cloud,
    reference: Any,
    *,
    tolerance_m: float | None = None,
    sample_spacing_m: float | None = None,
    seed: int = 0,
    params: CompareParams | None = None,
) -> Comparison:
    """Compare a cloud with a reference mesh or cloud, both ways, in float64.

    Parameters
    ----------
    cloud : Cloud
        The (simulated) cloud. Its ``label`` and ``station`` fields, when present, split
        the figures by hit label and by station.
    reference : Cloud, Scene or (vertices (v, 3) float, faces (f, 3) int)
        The reference: a mesh (a ``treesim.scan.Scene`` keeps its part labels) or a cloud.
    tolerance_m : float, optional
        Coverage tolerance τ (m); default ``3 × point_spacing_m``.
    sample_spacing_m : float, optional
        Spacing of the mesh surface samples (m); default ``point_spacing_m``.
    seed : int
        Seed of the surface sampling.
    params : CompareParams, optional
        All settings at once (overrides the three keywords above).

    Returns
    -------
    Comparison

    Raises
    ------
    EmptyInputError
        If the cloud or the reference is empty, or either cloud has fewer than
        :data:`~treesim.params.MIN_CLOUD_POINTS` points (too few to measure).
    InvalidGeometryError
        If either holds NaN or infinite coordinates.
    InvalidParameterError
        If a parameter is out of range.

    Examples
    --------
    >>> import treesim as ts
    >>> cloud = ts.read_cloud("scan.laz")  # doctest: +SKIP
    >>> result = ts.compare(cloud, "tree.ply", tolerance_m=0.01)  # doctest: +SKIP
    >>> result.to_dict()["coverage"]  # doctest: +SKIP
    """

    if params is None:
        params = CompareParams(
            tolerance_m=tolerance_m, sample_spacing_m=sample_spacing_m, seed=seed
        )
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    cloud = _check_cloud(cloud, "cloud")
    ref = _as_reference(reference)
    used = ref.points if ref.faces is None else ref.points[np.unique(ref.faces)]
    frame = LocalFrame.around(used)
    cloud_local = frame.to_local(cloud.points)
    workers = _workers(params.nthreads)

    t0 = time.perf_counter()
    cloud_tree = kdtree(cloud_local)
    spacing, tau = _spacing_and_tolerance(cloud_local, cloud_tree, ref, params, workers)
    timings["cloud_index"] = time.perf_counter() - t0

    # accuracy: cloud -> reference (and the reference's samples)
    info = dict(ref.info)
    if ref.kind == "mesh":
        m = _against_mesh(cloud_local, ref, frame, spacing, params, info, timings)
    else:
        m = _against_cloud(cloud_local, ref, frame, workers, timings)
    ref_local, ref_label = m.ref_local, m.ref_label
    t0 = time.perf_counter()
    comp, _ = cloud_tree.query(ref_local, k=1, workers=workers)
    timings["completeness"] = time.perf_counter() - t0
    acc = np.asarray(m.acc, dtype=np.float64)
    comp = np.asarray(comp, dtype=np.float64)

    acc_stats = DistanceStats.of(acc)
    comp_stats = DistanceStats.of(comp)
    covered = comp <= tau
    coverage = float(covered.mean())
    assert acc_stats.max_m is not None and comp_stats.max_m is not None
    assert acc_stats.mean_m is not None and comp_stats.mean_m is not None

    # splits
    t0 = time.perf_counter()
    names = _label_names(cloud.metadata)
    if ref.kind == "cloud":
        names = {**ref.label_names, **names}
    by_label = _split_by_label(cloud, acc, ref_label, comp, tau, names)
    by_station, station_d = _split_by_station(cloud, cloud_local, acc, ref_local, tau, workers)
    timings["splits"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start

    return Comparison(
        accuracy=acc_stats,
        completeness=comp_stats,
        hausdorff_m=float(max(acc_stats.max_m, comp_stats.max_m)),
        chamfer_m=float(0.5 * (acc_stats.mean_m + comp_stats.mean_m)),
        tolerance_m=tau,
        coverage=coverage,
        point_spacing_m=spacing,
        sample_spacing_m=m.sample_spacing,
        cloud=cloud,
        accuracy_m=acc,
        reference_points=frame.to_global(ref_local),
        completeness_m=comp,
        reference_label=None if ref_label is None else np.asarray(ref_label, dtype=np.int64),
        reference_face=m.ref_face,
        label_names=names,
        by_label=by_label,
        by_station=by_station,
        reference_info=info,
        params=params,
        frame=frame,
        timings_s=timings,
        station_distance_m=station_d,
    )


#: Why hidden surface is left out of completeness (``reference.hidden_surface.why``).
HIDDEN_WHY = (
    "surface inside another closed part of the same mesh (buried end caps, branch bases "
    "inside their parents) cannot be seen by a scanner outside the mesh"
)


def _visible_samples(
    samples: np.ndarray,
    sample_face: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    area: float,
    params: CompareParams,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Which surface samples a scanner outside the mesh could see, and the account of
    the area left out (estimated from the samples: they are area-uniform)."""
    parts = mesh_parts(vertices, faces)
    hidden = inside_other_parts(
        samples, sample_face, vertices, faces, parts, seed=params.seed, nthreads=params.nthreads
    )
    n = len(samples)
    share = float(hidden.mean()) if n else 0.0
    return ~hidden, {
        "rule": "drop",
        "why": HIDDEN_WHY,
        "parts": parts.n_parts,
        "closed_parts": parts.n_closed,
        "samples_drawn": n,
        "samples_dropped": int(hidden.sum()),
        "area_m2": area * share,
        "area_share": share,
        # binomial standard error of the estimate from n area-uniform samples
        "area_se_m2": area * math.sqrt(share * (1.0 - share) / n) if n else 0.0,
        "visible_area_m2": area * (1.0 - share),
    }


def _split_by_label(
    cloud: Cloud,
    acc: np.ndarray,
    ref_label: np.ndarray | None,
    comp: np.ndarray,
    tau: float,
    names: dict[int, str],
) -> dict[str, dict[str, Any]]:
    cloud_label = cloud.fields.get("label")
    codes: set[int] = set()
    if cloud_label is not None:
        cloud_label = np.asarray(cloud_label).astype(np.int64)
        codes |= {int(c) for c in np.unique(cloud_label)}
    if ref_label is not None:
        codes |= {int(c) for c in np.unique(ref_label)}
    if cloud_label is None and (ref_label is None or len(codes) < 2):
        return {}  # nothing to split
    out: dict[str, dict[str, Any]] = {}
    for code in sorted(codes):
        entry: dict[str, Any] = {"code": code}
        if cloud_label is not None:
            entry["accuracy"] = DistanceStats.of(acc[cloud_label == code]).to_dict()
        if ref_label is not None:
            sel = ref_label == code
            entry["completeness"] = DistanceStats.of(comp[sel]).to_dict()
            entry["coverage"] = float((comp[sel] <= tau).mean()) if sel.any() else None
        out[names.get(code, f"label_{code}")] = entry
    return out


#: How far from τ :attr:`Comparison.station_distance_m` keeps distances (m): more than
#: the 0.1 mm LAS rounding can move a distance (√3 × the scale), so that a report drawn
#: from the rounded coordinates knows which samples are surely in or out of τ.
STATION_DISTANCE_BAND_M = 5e-4


def _split_by_station(
    cloud: Cloud,
    cloud_local: np.ndarray,
    acc: np.ndarray,
    ref_local: np.ndarray,
    tau: float,
    workers: int,
) -> tuple[dict[int, dict[str, Any]], dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Per station: its points' accuracy and the reference's coverage by its points
    alone; and :attr:`Comparison.station_distance_m` (the queries reach τ plus
    :data:`STATION_DISTANCE_BAND_M`: the same nearest points within τ, the same
    coverage)."""
    station = cloud.fields.get("station")
    if station is None:
        return {}, {}
    station = np.asarray(station).astype(np.int64)
    out: dict[int, dict[str, Any]] = {}
    dists: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    bound = tau * (1 + 1e-12) + STATION_DISTANCE_BAND_M
    for s in np.unique(station):
        sel = station == s
        entry: dict[str, Any] = {
            "points": int(sel.sum()),
            "accuracy": DistanceStats.of(acc[sel]).to_dict(),
        }
        tree = kdtree(cloud_local[sel])
        d, _ = tree.query(ref_local, k=1, distance_upper_bound=bound, workers=workers)
        within = d <= tau
        entry["coverage"] = float(within.mean())
        out[int(s)] = entry
        band = np.flatnonzero(np.abs(d - tau) < STATION_DISTANCE_BAND_M)
        dists[int(s)] = (np.packbits(within), band, np.asarray(d[band], dtype=np.float64))
    return out, dists


# -- output ---------------------------------------------------------------------------
#: The figures of ``comparison.json`` that reports and ``run.json`` carry (same names).
COMPARISON_FIGURES = (
    "accuracy",
    "completeness",
    "hausdorff_m",
    "chamfer_m",
    "tolerance_m",
    "coverage",
    "point_spacing_m",
    "cloud",
    "reference",
    "by_label",
    "by_station",
)


def write_comparison(
    comparison: Comparison,
    outdir: str | Path,
    *,
    inputs: Mapping[str, Any] | None = None,
    formats: tuple[str, ...] = (".ply", ".laz"),
) -> dict[str, Path]:
    """Write ``comparison.json`` and the distance clouds into ``outdir``.

    Parameters
    ----------
    comparison : Comparison
    outdir : str or Path
        Created if missing.
    inputs : mapping, optional
        Extra JSON-ready facts to record (input paths, the scan's settings).
    formats : tuple of str
        Suffixes of the distance clouds (``.ply`` carries ``scalar_distance`` as a
        CloudCompare scalar field; ``.laz`` as an extra dimension).

    Returns
    -------
    dict of str -> Path
        ``comparison``, ``cloud_distances<suffix>``, ``reference_distances<suffix>``.
    """

    from .io import write_cloud

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    dist_cloud = comparison.distance_cloud()
    ref_cloud = comparison.reference_cloud()
    for suffix in formats:
        key = suffix.lstrip(".").lower()
        written[f"cloud_distances_{key}"] = write_cloud(
            out / f"cloud_distances{suffix}", dist_cloud
        )
        written[f"reference_distances_{key}"] = write_cloud(
            out / f"reference_distances{suffix}", ref_cloud
        )
    summary = {
        "kind": "treesim.comparison",
        **comparison.to_dict(),
        "inputs": dict(inputs or {}),
        "outputs": {k: p.name for k, p in written.items()},
        "software": software_versions(),
    }
    written["comparison"] = write_json(out / "comparison.json", summary)
    return written
