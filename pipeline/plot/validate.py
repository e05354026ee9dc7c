"""A simulated plot scan checked against the field scan it should reproduce.

:func:`validate_scans` answers the question a simulation is run for (HELIOS++ issue
#835): how closely does the simulated scan reproduce the real one, from the stations
actually used? Both clouds are moved into one float64 local frame (one origin subtracted
from both) and compared

* per station (the ``station`` field of both clouds, matched by number; a field cloud
  without one is a single group ``"all"``): point density by height above the terrain
  and by range from the station, real and simulated, and their ratio
  (``simulated / real``: 1 when the simulation records as many points as the field);
* per tree of the twin (simulated points by their ``tree_id``; real points given to the
  twin tree whose mesh is nearest, within ``assign_distance_m``, else 0: ground and
  other): points, and the coverage of the tree's surface at one τ (the share of
  area-uniform surface samples, hidden surface left out, within τ of a real point, and
  of a simulated point), and the occlusion profile (that coverage by height band);
* both ways as nearest-neighbour distances: real → simulated (every field point to the
  simulated cloud: AVOHD *completeness* of the simulation, with the field scan as the
  reference) and simulated → real (AVOHD *accuracy*), as :mod:`treesim.compare` names
  them, over all points and per station.

Only the region both describe is compared: within the twin's radius of its centre, or
without a twin, where the two clouds' horizontal extents overlap.

:func:`treesim.plot.validate_report.write_validation` writes ``validation.json``, the
figures and ``validation.html`` (self-contained).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cloud import Cloud
from ..errors import EmptyInputError, InputFormatError, InvalidParameterError
from ..frame import LocalFrame
from ..params._fields import check_bounds, param
from .core import Plot

__all__ = [
    "ASSIGN_DISTANCE_M",
    "VALIDATION_FILES",
    "VERDICT",
    "ValidateParams",
    "ValidationResult",
    "station_positions",
    "validate_scans",
]

#: Real points farther than this from every twin tree's mesh belong to no tree (m).
ASSIGN_DISTANCE_M = 0.25
#: What :func:`write_validation` writes.
VALIDATION_FILES = {
    "json": "validation.json",
    "density_by_height": "density_by_height.png",
    "density_by_range": "density_by_range.png",
    "coverage_by_tree": "coverage_by_tree.png",
    "occlusion_profile": "occlusion_profile.png",
    "distances": "distances.png",
    "html": "validation.html",
}
#: A simulated station farther than this from the field's is reported (m).
STATION_OFFSET_WARN_M = 0.1
#: Most height or range bins a profile may have.
MAX_BINS = 500
#: The verdict "reproduces" needs all of these: the overall density ratio within
#: ``density_ratio``, every station's within ``station_density_ratio``, every twin tree's
#: coverage within ``coverage_points`` percentage points of the field's, every twin
#: tree's *stem* coverage within ``stem_coverage_points`` (trees with a cylinder table),
#: and every station's range profile within ``range_profile_difference`` of the field's
#: shape. A tree's crown is judged by ``coverage_points`` for the one-line account of the
#: parts ("stems reproduce; crowns do not"), not as a criterion of its own.
#: (Set by judgement, not yet calibrated on field campaigns.)
VERDICT = {
    "density_ratio": (0.85, 1.18),
    "station_density_ratio": (0.7, 1.43),
    "coverage_points": 10.0,
    "stem_coverage_points": 10.0,
    "range_profile_difference": 0.1,
}

DEFINITIONS = {
    "density_ratio": "simulated points / real points (1: the simulation records as many)",
    "range_profile_difference": "half the summed absolute difference of the real and "
    "simulated shares of points per range bin (0: same shape, 1: disjoint)",
    "coverage": "share (0-1) of a twin tree's visible surface samples within tau_m of a point",
    "stem": "the part of a twin tree's surface on its cylinder table's stem (branch order "
    "0, within the tubes' faceting of a stem cylinder's surface); null for a tree without "
    "a table (a plain mesh)",
    "crown": "the rest of a twin tree's surface: branches of order >= 1 and leaves; null "
    "for a tree without a table",
    "real_to_simulated": "every real point to its nearest simulated point (m): AVOHD "
    "completeness of the simulation, the field scan as reference",
    "simulated_to_real": "every simulated point to its nearest real point (m): AVOHD accuracy",
    "height_above_terrain_m": "z minus the twin's terrain (without a twin: the field scan's "
    "own DTM of ground_cell_m cells)",
}


@dataclass(frozen=True, kw_only=True)
class ValidateParams:
    """Settings of :func:`validate_scans` (``treesim validate``, the service's
    ``validate`` process): each with its unit and range, checked here.

    Examples
    --------
    >>> from treesim.plot.validate import ValidateParams
    >>> ValidateParams(tau_m=0.02).height_bin_m
    1.0
    """

    tau_m: float = param(
        0.01,
        help="coverage tolerance τ: a twin surface sample within it of a point is covered",
        unit="m",
        gt=0,
        le=1.0,
    )
    height_bin_m: float = param(
        1.0, help="height bins of the density profiles", unit="m", gt=0, le=100.0
    )
    range_bin_m: float = param(
        2.0, help="range bins of the density profiles", unit="m", gt=0, le=1000.0
    )
    assign_distance_m: float = param(
        ASSIGN_DISTANCE_M,
        help="a point is given to the nearest twin tree whose mesh lies within this",
        unit="m",
        gt=0,
        le=10.0,
    )
    ground_cell_m: float = param(
        1.0,
        help="without a twin: cells of the field scan's own DTM (its CSF ground)",
        unit="m",
        gt=0,
        le=100.0,
    )
    max_distance_points: int = param(
        2_000_000,
        help="most points per direction for the distances (seeded subsample)",
        ge=1,
        le=10**9,
    )
    max_samples_per_tree: int = param(
        200_000,
        help="most surface samples per twin tree (else one per τ² of area)",
        ge=200,
        le=10**8,
    )
    seed: int = param(0, help="seed of the surface samples and the subsamples", ge=0, le=2**31 - 1)

    def __post_init__(self) -> None:
        check_bounds(self)


@dataclass
class ValidationResult:
    """What :func:`validate_scans` measured (figures as lists, ready for JSON).

    Attributes
    ----------
    summary : str
        One line: the verdict and the headline figures.
    groups : list of str
        The station groups (``"0"``, ``"1"``, ... or ``"all"``).
    stations : dict
        ``real_m`` and ``simulated_m`` ([x, y, z] per group or None, input
        coordinates), ``offset_m`` (per group, simulated to real) and ``source``.
    density : dict
        Per group ``points_real``, ``points_simulated``, ``density_ratio`` and
        ``range_profile_difference``; and over all groups.
    density_by_height, density_by_range : dict or None
        ``edges_m`` and per group ``real``, ``simulated`` (points per bin) and ``ratio``.
    trees : list of dict or None
        Per twin tree: points real and simulated, ``coverage_real``,
        ``coverage_simulated``, ``coverage_difference_points`` (simulated − real, in
        percentage points), ``samples``, ``area_m2``; and ``stem`` and ``crown``, each
        with ``coverage_real``, ``coverage_simulated``, ``coverage_difference_points``,
        ``samples`` and ``area_m2`` (None for a tree without a cylinder table: a plain
        mesh).
    occlusion_profile : dict or None
        ``edges_m``, ``samples``, ``coverage_real``, ``coverage_simulated`` per height band;
        the same for the stems and the crowns (``stem`` and ``crown``: over the trees with
        a table).
    distances : dict
        ``real_to_simulated`` and ``simulated_to_real`` statistics (m), overall and
        ``by_station``.
    notes, warnings : list of str
        What was left out and why; implausible results.
    verdict : dict
        ``reproduces`` (bool), ``failed`` (the names of the :data:`VERDICT` criteria not
        met), ``criteria`` (per criterion its ``value``, ``bound`` and ``passed``; None
        where it does not apply) and ``parts`` (one line: do the stems, the crowns
        reproduce?).
    parameters : dict
    frame_origin_m : list of float

    Examples
    --------
    >>> import treesim as ts
    >>> result = ts.validate_scans(real, simulated, plot=twin)  # doctest: +SKIP
    >>> print(result.summary)  # doctest: +SKIP
    simulated scan reproduces the field scan: density ratio 1.00, ...
    """

    summary: str
    groups: list[str]
    stations: dict[str, Any]
    density: dict[str, Any]
    density_by_height: dict[str, Any]
    density_by_range: dict[str, Any] | None
    trees: list[dict[str, Any]] | None
    occlusion_profile: dict[str, Any] | None
    distances: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    verdict: dict[str, Any] = field(default_factory=dict)
    parameters: dict[str, Any] = field(default_factory=dict)
    frame_origin_m: list[float] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready figures (units in the names)."""
        from ..jsonio import json_ready

        return json_ready(
            {
                "summary": self.summary,
                "groups": self.groups,
                "stations": self.stations,
                "density": self.density,
                "density_by_height": self.density_by_height,
                "density_by_range": self.density_by_range,
                "trees": self.trees,
                "occlusion_profile": self.occlusion_profile,
                "distances": self.distances,
                "notes": self.notes,
                "warnings": self.warnings,
                "verdict": self.verdict,
                "parameters": self.parameters,
                "frame_origin_m": self.frame_origin_m,
                "definitions": dict(DEFINITIONS),
                "verdict_bounds": {
                    k: list(v) if isinstance(v, tuple) else v for k, v in VERDICT.items()
                },
            }
        )


# -- inputs ---------------------------------------------------------------------------
def station_positions(cloud: Cloud) -> np.ndarray | None:
    """The station positions a cloud's metadata carries ((n, 3) float64, input
    coordinates): an E57's scan poses (``[x, y, z]``) or a treesim scan's stations
    (``{"position_m": [x, y, z]}``); None when it carries none.

    Examples
    --------
    >>> import treesim as ts
    >>> cloud = ts.Cloud(np.zeros((1, 3)), {}, {"stations": [[1.0, 2.0, 1.5]]})
    >>> station_positions(cloud)
    array([[1. , 2. , 1.5]])
    """
    raw = (cloud.metadata or {}).get("stations")
    if not raw:
        return None
    out = []
    for s in raw:
        p = s.get("position_m") if isinstance(s, dict) else s
        try:
            xyz = [float(c) for c in p]
        except (TypeError, ValueError):
            return None
        if len(xyz) != 3 or not all(math.isfinite(c) for c in xyz):
            return None
        out.append(xyz)
    return np.asarray(out, dtype=np.float64)


def _distance_text(d_m: float) -> str:
    return f"{d_m / 1000:,.1f} km" if d_m >= 1000 else f"{d_m:,.1f} m"


def _check_cloud(cloud: Cloud, what: str) -> np.ndarray:
    if not isinstance(cloud, Cloud):
        raise InputFormatError(f"the {what} must be a point cloud, got {type(cloud).__name__}")
    pts = np.asarray(cloud.points, dtype=np.float64)
    if len(pts) == 0:
        raise EmptyInputError(f"the {what} has no points")
    if not np.isfinite(pts).all():
        raise InputFormatError(f"the {what} has NaN or infinite coordinates")
    return pts


def _box_gap_m(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The gap between two clouds' bounding boxes and their centres' distance (m)."""
    lo_a, hi_a, lo_b, hi_b = a.min(0), a.max(0), b.min(0), b.max(0)
    gap = np.maximum(np.maximum(lo_a - hi_b, lo_b - hi_a), 0.0)
    centres = 0.5 * (lo_a + hi_a) - 0.5 * (lo_b + hi_b)
    return float(np.linalg.norm(gap)), float(np.linalg.norm(centres))


def _check_overlap(real: np.ndarray, sim: np.ndarray, plot: Plot | None) -> None:
    gap, apart = _box_gap_m(real, sim)
    if gap > 0.5:
        raise InputFormatError(
            f"the field scan and the simulated scan do not overlap: the clouds are "
            f"{_distance_text(apart)} apart: different coordinate frames?"
        )
    if plot is not None:
        cx, cy = plot.centre_xy
        lo, hi = real.min(0)[:2], real.max(0)[:2]
        d = float(np.linalg.norm(np.maximum(np.maximum(lo - (cx, cy), (cx, cy) - hi), 0.0)))
        if d > float(plot.radius_m):
            c = 0.5 * (lo + hi)
            raise InputFormatError(
                f"the twin's plot (centre {cx:.2f}, {cy:.2f}) lies outside the field scan: "
                f"they are {_distance_text(math.hypot(c[0] - cx, c[1] - cy))} apart: "
                "different coordinate frames?"
            )


@dataclass
class _Side:
    """One cloud in the local frame, within the compared region."""

    pts: np.ndarray  # (n, 3) local
    group: np.ndarray  # (n,) index into groups
    height_m: np.ndarray  # (n,) above the terrain
    range_m: np.ndarray | None  # (n,) from its station
    stations: np.ndarray | None  # (g, 3) local, per group (None: unknown)
    tree_id: np.ndarray | None = None


def _station_ids(cloud: Cloud, n_kept: int) -> np.ndarray | None:
    s = cloud.fields.get("station")
    if s is None:
        return None
    s = np.asarray(s).astype(np.int64)
    if len(s) != n_kept:
        raise InputFormatError("the station field does not have one value per point")
    return s


def _station_count(cloud: Cloud, ids: np.ndarray, pos: np.ndarray | None) -> int:
    return max(int(ids.max(initial=-1)) + 1, 0 if pos is None else len(pos))


def _groups(
    real: Cloud, sim: Cloud, real_pos: np.ndarray | None, sim_pos: np.ndarray | None
) -> tuple[list[str], np.ndarray, np.ndarray, list[str]]:
    """The groups, each cloud's group index per point, and notes."""
    notes: list[str] = []
    r_ids = _station_ids(real, len(real.points))
    s_ids = _station_ids(sim, len(sim.points))
    if r_ids is None or s_ids is None:
        who = "field scan" if r_ids is None else "simulated scan"
        notes.append(
            f"the {who} has no station field: all stations are one group 'all' (per-station "
            "figures need each point's station, as an E57 gives)"
        )
        return ["all"], np.zeros(len(real.points), int), np.zeros(len(sim.points), int), notes
    n_r = _station_count(real, r_ids, real_pos)
    n_s = _station_count(sim, s_ids, sim_pos)
    if n_r != n_s:
        raise InputFormatError(
            f"the field scan has {n_r} station{'s' * (n_r != 1)} and the simulated scan "
            f"{n_s}: simulate from the field's stations (treesim plot scan --stations-from "
            "the field's E57 or stations CSV)"
        )
    return [str(k) for k in range(n_r)], r_ids, s_ids, notes


def _resolve_stations(
    real: Cloud, sim: Cloud, stations: Any
) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """Station positions (input coordinates) of the field and the simulation."""
    if stations is not None:
        given = np.array(
            [s.position_m if hasattr(s, "position_m") else s for s in stations], dtype=np.float64
        )
        if given.ndim != 2 or given.shape[1] != 3 or not np.isfinite(given).all():
            raise InvalidParameterError("stations must be [x, y, z] positions in metres")
        real_pos, source = given, "given"
    else:
        real_pos, source = station_positions(real), "field scan's metadata"
    sim_pos = station_positions(sim)
    if real_pos is None and sim_pos is not None:
        return sim_pos, sim_pos, "simulated scan's metadata (the field's unknown)"
    if real_pos is None:
        return None, None, "unknown"
    return real_pos, (real_pos if sim_pos is None else sim_pos), source


# -- terrain, region ------------------------------------------------------------------
def _ground_from_cloud(pts: np.ndarray, cell_m: float):
    """The field scan's own terrain (local frame): its CSF ground as a DTM raster of
    ``cell_m`` cells (:func:`treesim.plot.dtm.ground_and_dtm`), as a function of xy."""
    from .dtm import ground_and_dtm

    _, dtm, _ = ground_and_dtm(pts, cell_m=cell_m)
    return lambda xy: dtm.height_at(xy[:, 0], xy[:, 1])


def _heights(pts: np.ndarray, frame: LocalFrame, plot: Plot | None, ground: Any) -> np.ndarray:
    if plot is not None:
        o = frame.origin_array
        return pts[:, 2] + o[2] - plot.terrain.height_at(pts[:, 0] + o[0], pts[:, 1] + o[1])
    return pts[:, 2] - ground(pts[:, :2])


def _region(
    real: np.ndarray, sim: np.ndarray, frame: LocalFrame, plot: Plot | None
) -> tuple[np.ndarray, np.ndarray, str]:
    """Masks of the points of each cloud in the compared region, and its description."""
    if plot is not None:
        c = np.asarray(plot.centre_xy) - frame.origin_array[:2]
        r = float(plot.radius_m)

        def inside(p: np.ndarray) -> np.ndarray:
            return np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) <= r

        return inside(real), inside(sim), f"within the twin's radius ({r:g} m) of its centre"
    lo = np.maximum(real[:, :2].min(0), sim[:, :2].min(0))
    hi = np.minimum(real[:, :2].max(0), sim[:, :2].max(0))

    def box(p: np.ndarray) -> np.ndarray:
        return np.all((p[:, :2] >= lo) & (p[:, :2] <= hi), axis=1)

    return box(real), box(sim), "where the two clouds' horizontal extents overlap"


def _ranges(pts: np.ndarray, group: np.ndarray, pos: np.ndarray | None, pooled: bool):
    if pos is None:
        return None
    if pooled:  # one group over several stations: the nearest station
        from scipy.spatial import cKDTree

        return cKDTree(pos).query(pts, k=1)[0]
    return np.linalg.norm(pts - pos[np.minimum(group, len(pos) - 1)], axis=1)


def _side(
    cloud: Cloud,
    pts_all: np.ndarray,
    keep: np.ndarray,
    group: np.ndarray,
    pos: np.ndarray | None,
    ctx: dict[str, Any],
) -> _Side:
    frame = ctx["frame"]
    pts = frame.to_local(pts_all[keep])
    grp = group[keep]
    pos_local = None if pos is None else frame.to_local(pos)
    tid = cloud.fields.get("tree_id")
    return _Side(
        pts=pts,
        group=grp,
        height_m=_heights(pts, frame, ctx["plot"], ctx["ground"]),
        range_m=_ranges(pts, grp, pos_local, ctx["pooled"]),
        stations=pos_local,
        tree_id=None if tid is None else np.asarray(tid).astype(np.int64)[keep],
    )


# -- density --------------------------------------------------------------------------
def _edges(values: list[np.ndarray], step: float, start: float | None = None) -> np.ndarray:
    v = np.concatenate(values) if values else np.zeros(1)
    lo = math.floor(float(v.min(initial=0.0)) / step) * step if start is None else start
    hi = math.ceil(float(v.max(initial=step)) / step + 1e-9) * step
    n = max(1, round((hi - lo) / step))
    if n > MAX_BINS:
        raise InvalidParameterError(
            f"{n} bins of {step:g} m: too many (at most {MAX_BINS}); give larger bins"
        )
    return lo + step * np.arange(n + 1)


def _ratio(sim: np.ndarray, real: np.ndarray) -> list[float | None]:
    return [None if r == 0 else float(s / r) for s, r in zip(sim, real, strict=True)]


def _profile(
    groups: list[str], real_v: np.ndarray, real_g: np.ndarray, sim_v, sim_g, edges
) -> dict[str, Any]:
    per: dict[str, Any] = {}
    for k, g in enumerate(groups):
        r = np.histogram(real_v[real_g == k], edges)[0]
        s = np.histogram(sim_v[sim_g == k], edges)[0]
        per[g] = {"real": r.tolist(), "simulated": s.tolist(), "ratio": _ratio(s, r)}
    return {"edges_m": edges.tolist(), "per_station": per}


def _profile_difference(real: list[int], sim: list[int]) -> float | None:
    r, s = np.asarray(real, float), np.asarray(sim, float)
    if r.sum() == 0 or s.sum() == 0:
        return None
    return float(0.5 * np.abs(r / r.sum() - s / s.sum()).sum())


def _density(
    groups: list[str], real: _Side, sim: _Side, height_bin_m: float, range_bin_m: float
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any] | None]:
    h_edges = _edges([real.height_m, sim.height_m], height_bin_m)
    by_h = _profile(groups, real.height_m, real.group, sim.height_m, sim.group, h_edges)
    by_r = None
    if real.range_m is not None and sim.range_m is not None:
        r_edges = _edges([real.range_m, sim.range_m], range_bin_m, start=0.0)
        by_r = _profile(groups, real.range_m, real.group, sim.range_m, sim.group, r_edges)
    per: dict[str, Any] = {}
    for k, g in enumerate(groups):
        nr, ns = int((real.group == k).sum()), int((sim.group == k).sum())
        rp = by_r["per_station"][g] if by_r else None
        hp = by_h["per_station"][g]
        per[g] = {
            "points_real": nr,
            "points_simulated": ns,
            "density_ratio": ns / nr if nr else None,
            "height_profile_difference": _profile_difference(hp["real"], hp["simulated"]),
            "range_profile_difference": None
            if rp is None
            else _profile_difference(rp["real"], rp["simulated"]),
        }
    nr, ns = len(real.pts), len(sim.pts)
    density = {
        "points_real": nr,
        "points_simulated": ns,
        "density_ratio": ns / nr if nr else None,
        "per_station": per,
    }
    return density, by_h, by_r


# -- trees: assignment, coverage -----------------------------------------------------
def _tree_mesh(plot: Plot, tid: int, frame: LocalFrame) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, n = [], [], 0
    for part in plot.tree_parts(tid):
        verts.append(frame.to_local(np.asarray(part.vertices, dtype=np.float64)))
        faces.append(np.asarray(part.faces, dtype=np.int64) + n)
        n += len(part.vertices)
    return np.concatenate(verts), np.concatenate(faces)


def _assign(
    pts: np.ndarray, meshes: dict[int, tuple[np.ndarray, np.ndarray]], within_m: float
) -> np.ndarray:
    """Each point's nearest twin tree (its mesh within ``within_m``), else 0."""
    from ..geometry import point_to_mesh_distances

    best = np.full(len(pts), np.inf)
    out = np.zeros(len(pts), dtype=np.int64)
    for tid, (v, f) in meshes.items():
        lo, hi = v.min(0) - within_m, v.max(0) + within_m
        cand = np.flatnonzero(np.all((pts >= lo) & (pts <= hi), axis=1))
        if len(cand) == 0:
            continue
        d = point_to_mesh_distances(pts[cand], v, f, 0)
        take = (d <= within_m) & (d < best[cand])
        best[cand[take]] = d[take]
        out[cand[take]] = tid
    return out


def _surface_samples(
    v: np.ndarray, f: np.ndarray, spacing_m: float, max_samples: int, seed: int
) -> tuple[np.ndarray, float, float]:
    """Area-uniform samples of a tree's visible surface (hidden surface dropped), the
    mesh's area and the area each sample stands for (m²)."""
    from ..geometry import inside_other_parts, mesh_parts, sample_surface

    tri = v[f]
    area = float(
        0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    )
    n = int(np.clip(math.ceil(area / spacing_m**2), 200, max_samples))
    s, face = sample_surface(v, f, n, seed=seed)
    hidden = inside_other_parts(s, face, v, f, mesh_parts(v, f), seed=seed)
    return s[~hidden], area, area / n


def _covered(tree: Any, samples: np.ndarray, tau_m: float) -> np.ndarray:
    if tree is None or len(samples) == 0:
        return np.zeros(len(samples), dtype=bool)
    d, _ = tree.query(samples, k=1, distance_upper_bound=tau_m, workers=-1)
    return np.isfinite(d)


# -- trees: stem and crown -----------------------------------------------------------
#: A sample lies on the stem when it is this close to a stem cylinder's surface: the
#: tubes' faceting (a polygon of ``facets`` sides inside the circle) plus this share of
#: the radius and this many metres (junctions, rounding).
STEM_SLACK_RADIUS = 0.03
STEM_SLACK_M = 0.002
#: Below this share of the stem cylinders' side area found on the mesh, the tree's table
#: does not describe its mesh: its parts are left out (null), with a warning.
STEM_FIT_MIN = 0.5


def _placed_stem(plot: Plot, tid: int, frame: LocalFrame) -> dict[str, np.ndarray] | None:
    """The tree's stem cylinders (branch order 0) as the plot places its mesh, in the
    local frame: ``start``, unit ``axis``, ``length_m``, ``r0_m`` and ``r1_m`` (radius at
    the start and the end); None for a tree without a cylinder table (a plain mesh)."""
    table = plot.tree_table(tid)
    if table is None:
        return None
    stem = np.flatnonzero(np.asarray(table.branch_order) == 0)
    if len(stem) == 0:
        return None
    axis = np.asarray(table.axis, dtype=np.float64)[stem]
    return {
        "start": frame.to_local(np.asarray(table.start, dtype=np.float64)[stem]),
        "axis": axis / np.linalg.norm(axis, axis=1, keepdims=True),
        "length_m": np.asarray(table.length_m, dtype=np.float64)[stem],
        "r0_m": np.asarray(table.radius_m, dtype=np.float64)[stem],
        "r1_m": np.asarray(table.end_radius_m, dtype=np.float64)[stem],
    }


def _on_stem(samples: np.ndarray, stem: dict[str, np.ndarray], facets: int) -> np.ndarray:
    """Which samples lie on the surface of one of the stem's cylinders (within the
    faceting's slack): distance to the side at the sample's height along the axis, or to
    the nearer end disc beyond the ends. Only the pairs of a sample and a cylinder whose
    bounding sphere (widened by the slack) holds it are measured."""
    from scipy.spatial import cKDTree

    s, a, length = stem["start"], stem["axis"], stem["length_m"]
    r0, r1 = stem["r0_m"], stem["r1_m"]
    facet = 1.0 - math.cos(math.pi / max(int(facets), 3)) + STEM_SLACK_RADIUS
    out = np.zeros(len(samples), dtype=bool)
    if len(samples) == 0 or len(s) == 0:
        return out
    r_max = np.maximum(r0, r1)
    reach = np.hypot(0.5 * length, r_max) + facet * r_max + STEM_SLACK_M + 1e-9
    near = cKDTree(samples).query_ball_point(s + 0.5 * length[:, None] * a, reach)
    k = np.repeat(np.arange(len(s)), [len(n) for n in near])
    if len(k) == 0:
        return out
    i = np.concatenate([np.asarray(n, dtype=np.int64) for n in near])
    d = samples[i] - s[k]
    t = np.einsum("mj,mj->m", d, a[k])
    rho = np.linalg.norm(d - t[:, None] * a[k], axis=1)
    tc = np.clip(t, 0.0, length[k])
    r = r0[k] + (r1[k] - r0[k]) * tc / length[k]
    side = np.abs(rho - r)
    end = np.hypot(t - tc, np.maximum(rho - r, 0.0))
    dist = np.where(t == tc, side, end)
    out[i[dist <= facet * r + STEM_SLACK_M]] = True
    return out


def _stem_side_area_m2(stem: dict[str, np.ndarray]) -> float:
    return float(np.sum(math.pi * (stem["r0_m"] + stem["r1_m"]) * stem["length_m"]))


def _part(in_r: np.ndarray, in_s: np.ndarray, mask: np.ndarray, w_m2: float) -> dict[str, Any]:
    """One part's coverage figures (its samples ``mask``)."""
    n = int(mask.sum())
    c_r = float(in_r[mask].mean()) if n else None
    c_s = float(in_s[mask].mean()) if n else None
    return {
        "coverage_real": c_r,
        "coverage_simulated": c_s,
        "coverage_difference_points": None if c_r is None else 100.0 * (c_s - c_r),
        "samples": n,
        "area_m2": n * w_m2,
    }


def _tree_row(
    tid: int, mesh: tuple[np.ndarray, np.ndarray], real: _Side, sim: _Side, kd: dict, ctx: dict
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """One twin tree's row and its samples' heights, coverage and part (``stem``: True,
    False, or all False with ``has_parts`` False for a tree without a table)."""
    plot, frame, p = ctx["plot"], ctx["frame"], ctx["params"]
    samples, area, w = _surface_samples(*mesh, p.tau_m, p.max_samples_per_tree, p.seed)
    in_r, in_s = _covered(kd["real"], samples, p.tau_m), _covered(kd["sim"], samples, p.tau_m)
    n_r, n_s = int((real.tree_id == tid).sum()), int((sim.tree_id == tid).sum())
    hit = None if ctx["labelled"] is None else ctx["labelled"] == tid
    whole = _part(in_r, in_s, np.ones(len(samples), dtype=bool), w)
    stem = _placed_stem(plot, tid, frame)
    on_stem = np.zeros(len(samples), dtype=bool)
    parts: dict[str, Any] = {"stem": None, "crown": None}
    if stem is not None:
        on_stem = _on_stem(samples, stem, int(plot.facets))
        fit = on_stem.sum() * w / _stem_side_area_m2(stem)
        if fit < STEM_FIT_MIN:
            ctx["warnings"].append(
                f"tree {tid}: only {100 * fit:.0f} % of its stem cylinders' surface lies on "
                "its mesh: its table does not describe the mesh, stem and crown left out"
            )
            stem, on_stem = None, np.zeros(len(samples), dtype=bool)
        else:
            parts = {"stem": _part(in_r, in_s, on_stem, w), "crown": _part(in_r, in_s, ~on_stem, w)}
    row = {
        "tree_id": int(tid),
        "points_real": n_r,
        "points_simulated": n_s,
        "density_ratio": n_s / n_r if n_r else None,
        "coverage_real": whole["coverage_real"],
        "coverage_simulated": whole["coverage_simulated"],
        "coverage_difference_points": whole["coverage_difference_points"],
        **parts,
        "points_simulated_tree_id": None if hit is None else int(hit.sum()),
        "assignment_agreement": None
        if hit is None or not hit.any()
        else float((sim.tree_id[hit] == tid).mean()),
        "samples": int(len(samples)),
        "area_m2": area,
    }
    arrays = {
        "height_m": _heights(samples, frame, plot, None),
        "real": in_r,
        "sim": in_s,
        "stem": on_stem,
        "has_parts": np.full(len(samples), stem is not None),
    }
    return row, arrays


def _band_coverage(k: np.ndarray, n_bins: int, a: dict[str, np.ndarray], mask) -> dict:
    n = np.bincount(k[mask], minlength=n_bins)
    return {
        "samples": n.tolist(),
        "coverage_real": _ratio(np.bincount(k[mask], a["real"][mask], n_bins), n),
        "coverage_simulated": _ratio(np.bincount(k[mask], a["sim"][mask], n_bins), n),
    }


def _trees(
    plot: Plot, real: _Side, sim: _Side, kd: dict[str, Any], ctx: dict[str, Any]
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Per-tree points and coverage (whole, stem, crown), and the occlusion profile
    (coverage by height band)."""
    frame, p = ctx["frame"], ctx["params"]
    meshes = {tid: _tree_mesh(plot, tid, frame) for tid in plot.tree_ids}
    # both clouds' points go to trees by one rule (the simulated tree_id only checks it)
    ctx["labelled"] = sim.tree_id
    real.tree_id = _assign(real.pts, meshes, p.assign_distance_m)
    sim.tree_id = _assign(sim.pts, meshes, p.assign_distance_m)
    rows, per = [], []
    for tid, mesh in meshes.items():
        row, arrays = _tree_row(tid, mesh, real, sim, kd, ctx)
        rows.append(row)
        per.append(arrays)
    plot.release(list(meshes))
    a = {key: np.concatenate([x[key] for x in per]) for key in per[0]}
    edges = _edges([a["height_m"]], p.height_bin_m)
    k = np.clip(np.searchsorted(edges, a["height_m"], side="right") - 1, 0, len(edges) - 2)
    nb = len(edges) - 1
    prof = {
        "edges_m": edges.tolist(),
        **_band_coverage(k, nb, a, np.ones(len(k), dtype=bool)),
        "stem": None,
        "crown": None,
        "tau_m": p.tau_m,
    }
    if a["has_parts"].any():
        prof["stem"] = _band_coverage(k, nb, a, a["has_parts"] & a["stem"])
        prof["crown"] = _band_coverage(k, nb, a, a["has_parts"] & ~a["stem"])
    return rows, prof


# -- distances ------------------------------------------------------------------------
def _pick(n: int, cap: int, seed: int) -> np.ndarray:
    if n <= cap:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, cap, replace=False))


def _nn(tree: Any, query: np.ndarray, cap: int, seed: int) -> np.ndarray:
    if tree is None or len(query) == 0:
        return np.empty(0)
    return tree.query(query[_pick(len(query), cap, seed)], k=1, workers=-1)[0]


def _stats(d: np.ndarray) -> dict[str, Any]:
    from ..compare import DistanceStats

    return DistanceStats.of(d).to_dict()


def _histogram(a: np.ndarray, b: np.ndarray, bins: int = 60) -> dict[str, Any]:
    both = np.concatenate([a, b])
    top = float(np.percentile(both, 99.0)) if len(both) else 1.0
    edges = np.linspace(0.0, max(top, 1e-6), bins + 1)
    return {
        "edges_m": edges.tolist(),
        "real_to_simulated": np.histogram(np.minimum(a, edges[-1]), edges)[0].tolist(),
        "simulated_to_real": np.histogram(np.minimum(b, edges[-1]), edges)[0].tolist(),
    }


def _distances(
    groups: list[str], real: _Side, sim: _Side, kd: dict[str, Any], cap: int, seed: int
) -> dict[str, Any]:
    from ..geometry import kdtree

    a, b = _nn(kd["sim"], real.pts, cap, seed), _nn(kd["real"], sim.pts, cap, seed + 1)
    out: dict[str, Any] = {
        "real_to_simulated": _stats(a),
        "simulated_to_real": _stats(b),
        "avohd": {"real_to_simulated": "completeness", "simulated_to_real": "accuracy"},
        "histogram": _histogram(a, b),
        "by_station": {},
    }
    if len(groups) > 1:
        for k, g in enumerate(groups):
            r, s = real.pts[real.group == k], sim.pts[sim.group == k]
            tr = kdtree(r) if len(r) else None
            ts = kdtree(s) if len(s) else None
            out["by_station"][g] = {
                "real_to_simulated": _stats(_nn(ts, r, cap, seed + 2 + 2 * k)),
                "simulated_to_real": _stats(_nn(tr, s, cap, seed + 3 + 2 * k)),
            }
    return out


# -- the verdict ----------------------------------------------------------------------
def _worst(values: Any) -> float | None:
    vals = [abs(v) for v in values if v is not None]
    return max(vals) if vals else None


def _criterion(value: Any, bound: Any, passed: bool | None) -> dict[str, Any]:
    shown = list(bound) if isinstance(bound, tuple) else bound
    return {"value": value, "bound": shown, "passed": passed}


def _verdict(density: dict[str, Any], trees: list | None) -> dict[str, Any]:
    """Each :data:`VERDICT` criterion's worst value and whether it is met (None: it does
    not apply), the criteria that failed, and one line on the stems and crowns."""
    ratio = density["density_ratio"]
    per = [v["density_ratio"] for v in density["per_station"].values() if v["density_ratio"]]
    counted = [t for t in trees or [] if t["points_real"]]
    whole = _worst(t["coverage_difference_points"] for t in counted)
    stem = _worst(t["stem"]["coverage_difference_points"] for t in counted if t["stem"])
    crown = _worst(t["crown"]["coverage_difference_points"] for t in counted if t["crown"])
    shape = _worst(v["range_profile_difference"] for v in density["per_station"].values())
    lo, hi = VERDICT["density_ratio"]
    slo, shi = VERDICT["station_density_ratio"]
    cov, stem_cov, diff = (
        VERDICT["coverage_points"],
        VERDICT["stem_coverage_points"],
        VERDICT["range_profile_difference"],
    )
    criteria = {
        "density_ratio": _criterion(ratio, (lo, hi), ratio is not None and lo <= ratio <= hi),
        "station_density_ratio": _criterion(
            [min(per), max(per)] if per else None,
            (slo, shi),
            all(slo <= r <= shi for r in per) if per else None,
        ),
        "coverage_points": _criterion(whole, cov, None if whole is None else whole <= cov),
        "stem_coverage_points": _criterion(
            stem, stem_cov, None if stem is None else stem <= stem_cov
        ),
        "range_profile_difference": _criterion(
            shape, diff, None if shape is None else shape <= diff
        ),
    }
    failed = [k for k, c in criteria.items() if c["passed"] is False]
    parts = None
    if stem is not None:
        said = "stems reproduce" if stem <= stem_cov else "stems do not reproduce"
        parts = f"{said} (coverage within {stem:.1f} points)"
        if crown is not None:
            said = "crowns reproduce" if crown <= cov else "crowns do not"
            parts += f"; {said} (within {crown:.1f} points)"
    return {"reproduces": not failed, "failed": failed, "criteria": criteria, "parts": parts}


def _summary(density: dict[str, Any], verdict: dict[str, Any], dist: dict[str, Any]) -> str:
    from ..report.text import length

    ratio = density["density_ratio"]
    per = [v["density_ratio"] for v in density["per_station"].values() if v["density_ratio"]]
    crit = verdict["criteria"]
    bits = [
        "density ratio n/a"
        if ratio is None
        else f"density ratio {ratio:.2f}"
        + (f" (per-station range {min(per):.2f}-{max(per):.2f})" if len(per) > 1 else "")
    ]
    if crit["coverage_points"]["value"] is not None:
        bits.append(f"tree coverage within {crit['coverage_points']['value']:.1f} points")
    a, b = dist["real_to_simulated"]["p95_m"], dist["simulated_to_real"]["p95_m"]
    bits.append(f"distances p95 {length(a)} real→simulated, {length(b)} simulated→real")
    said = "reproduces" if verdict["reproduces"] else "does not reproduce"
    out = f"simulated scan {said} the field scan: " + ", ".join(bits)
    if verdict["parts"]:
        out += f"; {verdict['parts']}"
    if verdict["failed"]:
        out += f" (failed: {', '.join(verdict['failed'])})"
    return out


def _warnings(res: dict[str, Any], groups: list[str]) -> list[str]:
    out = []
    offsets = res["stations"]["offset_m"] or []
    for g, off in zip(groups, offsets, strict=False):
        if off is not None and off > STATION_OFFSET_WARN_M:
            out.append(
                f"simulated station {g} stands {off:.2f} m from the field's: simulate from the "
                "stations actually used (treesim plot scan --stations-from)"
            )
    for g, v in res["density"]["per_station"].items():
        r = v["density_ratio"]
        if r is not None and not 0.5 <= r <= 2.0:
            out.append(
                f"station {g}: the simulation records {r:.2f} × the field's points; check the "
                "scanner's angular step and range limits"
            )
        if v["points_real"] == 0 or v["points_simulated"] == 0:
            who = "field scan" if v["points_real"] == 0 else "simulated scan"
            out.append(f"station {g}: the {who} has no points in the compared region")
    for t in res["trees"] or []:
        d = t["coverage_difference_points"]
        if d is not None and abs(d) > 20.0:
            out.append(
                f"tree {t['tree_id']}: coverage differs by {d:+.0f} points (simulated − real)"
            )
    return out


def _params(params: ValidateParams | None, settings: dict[str, Any]) -> ValidateParams:
    """``params`` (default the model's) with the keyword ``settings`` over it, checked."""
    from ..params import merge

    if params is not None and not isinstance(params, ValidateParams):
        raise InvalidParameterError(f"params must be a ValidateParams, got {type(params).__name__}")
    return merge(params or ValidateParams(), settings)


def validate_scans(
    real: Cloud,
    simulated: Cloud,
    params: ValidateParams | None = None,
    *,
    plot: Plot | None = None,
    stations: Sequence[Any] | None = None,
    **settings: Any,
) -> ValidationResult:
    """How closely ``simulated`` reproduces the field scan ``real`` (see the module notes).

    Parameters
    ----------
    real : Cloud
        The field scan (a ``station`` field and ``metadata["stations"]`` from an E57; a
        merged cloud without them is one group ``"all"``).
    simulated : Cloud
        The simulated scan (``treesim plot scan``: ``station`` and ``tree_id`` fields).
    params : ValidateParams, optional
        The settings: τ (``tau_m``), the profiles' bins, the assignment distance, ...
        (default :class:`ValidateParams`' own).
    plot : Plot, optional
        The plot's digital twin: its terrain gives the heights, its trees the coverage
        figures (left out without it, and said so in ``notes``), their cylinder tables
        the stem and crown split.
    stations : sequence of [x, y, z] or Station, optional
        The field's station positions (default the real cloud's metadata).
    **settings
        Fields of :class:`ValidateParams` by name (``tau_m=0.02``, ``height_bin_m``,
        ``range_bin_m``, ``assign_distance_m``, ``ground_cell_m``,
        ``max_distance_points``, ``max_samples_per_tree``, ``seed``): set over
        ``params``, checked the same way.

    Returns
    -------
    ValidationResult

    Raises
    ------
    EmptyInputError
        If either cloud has no points (or none in the compared region).
    InputFormatError
        If the clouds (or the twin) do not overlap, or the station counts differ.
    InvalidParameterError
        If a setting is unknown or out of its range (the message names it).

    Examples
    --------
    >>> import treesim as ts
    >>> from treesim.plot.validate import ValidateParams, validate_scans
    >>> real = ts.read_cloud("field.e57")  # doctest: +SKIP
    >>> sim = ts.read_cloud("sim/plot_scan.laz")  # doctest: +SKIP
    >>> twin = ts.read_plot("twin/plot.toml")  # doctest: +SKIP
    >>> result = validate_scans(real, sim, ValidateParams(tau_m=0.02), plot=twin)  # doctest: +SKIP
    >>> print(result.summary)  # doctest: +SKIP
    >>> result.verdict["parts"]  # doctest: +SKIP
    'stems reproduce (coverage within 4.2 points); crowns do not (within 31.0 points)'
    """
    p = _params(params, settings)
    r_all, s_all = _check_cloud(real, "field scan"), _check_cloud(simulated, "simulated scan")
    _check_overlap(r_all, s_all, plot)
    real_pos, sim_pos, pos_source = _resolve_stations(real, simulated, stations)
    groups, r_grp, s_grp, notes = _groups(real, simulated, real_pos, sim_pos)
    frame = plot.frame() if plot is not None else LocalFrame.around(r_all)
    keep_r, keep_s, region = _region(frame.to_local(r_all), frame.to_local(s_all), frame, plot)
    if not keep_r.any() or not keep_s.any():
        who = "field scan" if not keep_r.any() else "simulated scan"
        raise EmptyInputError(f"the {who} has no points in the compared region ({region})")
    ctx: dict[str, Any] = {
        "params": p,
        "frame": frame,
        "plot": plot,
        "pooled": groups == ["all"],
        "ground": None,
        "real_pos": real_pos,
        "sim_pos": sim_pos,
        "pos_source": pos_source,
        "region": region,
        "counts": (len(r_all), len(s_all)),
        "warnings": [],
    }
    if plot is None:
        ctx["ground"] = _ground_from_cloud(frame.to_local(r_all[keep_r]), p.ground_cell_m)
        notes.append(
            "no twin given: heights are above the field scan's own ground (a DTM of "
            f"{p.ground_cell_m:g} m cells), and the tree coverage and occlusion profile are "
            "left out"
        )
    rs = _side(real, r_all, keep_r, r_grp, real_pos, ctx)
    # the simulated points' ranges are from the field's stations: the density as the
    # stations actually used see it (a simulated station elsewhere shows there)
    ss = _side(simulated, s_all, keep_s, s_grp, real_pos, ctx)
    return _measure(groups, rs, ss, ctx, notes)


def _measure(
    groups: list[str], rs: _Side, ss: _Side, ctx: dict[str, Any], notes: list[str]
) -> ValidationResult:
    """The figures, once both clouds are in the local frame (see :func:`validate_scans`)."""
    from dataclasses import asdict

    from ..geometry import kdtree

    plot, frame, p = ctx["plot"], ctx["frame"], ctx["params"]
    real_pos, sim_pos = ctx["real_pos"], ctx["sim_pos"]
    if rs.range_m is None:
        notes.append("no station positions known: the density by range is left out")
    elif groups == ["all"] and real_pos is not None and len(real_pos) > 1:
        notes.append("ranges are from each point's nearest station (no station field)")
    density, by_h, by_r = _density(groups, rs, ss, p.height_bin_m, p.range_bin_m)
    kd = {"real": kdtree(rs.pts), "sim": kdtree(ss.pts)}
    trees, occl = (None, None)
    if plot is not None:
        trees, occl = _trees(plot, rs, ss, kd, ctx)
        if not any(t["stem"] for t in trees):
            notes.append(
                "no twin tree has a cylinder table (plain meshes): stem and crown are not "
                "told apart"
            )
    dist = _distances(groups, rs, ss, kd, p.max_distance_points, p.seed)
    offsets = None
    if real_pos is not None and sim_pos is not None and groups != ["all"]:
        n = min(len(real_pos), len(sim_pos))
        offsets = np.linalg.norm(real_pos[:n] - sim_pos[:n], axis=1).tolist()
    stations = {
        "real_m": None if real_pos is None else real_pos.tolist(),
        "simulated_m": None if sim_pos is None else sim_pos.tolist(),
        "offset_m": offsets,
        "source": ctx["pos_source"],
    }
    res = {"stations": stations, "density": density, "trees": trees}
    verdict = _verdict(density, trees)
    return ValidationResult(
        summary=_summary(density, verdict, dist),
        groups=groups,
        stations=stations,
        density=density,
        density_by_height=by_h,
        density_by_range=by_r,
        trees=trees,
        occlusion_profile=occl,
        distances=dist,
        notes=notes,
        warnings=ctx["warnings"] + _warnings(res, groups),
        verdict=verdict,
        parameters={
            **asdict(p),
            "region": ctx["region"],
            "points_in_region_real": len(rs.pts),
            "points_in_region_simulated": len(ss.pts),
            "points_real": ctx["counts"][0],
            "points_simulated": ctx["counts"][1],
        },
        frame_origin_m=list(frame.origin),
    )
