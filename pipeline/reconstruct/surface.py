"""Surface meshes from a prepared cloud: screened Poisson and ball pivoting (pymeshlab).

Both methods run pymeshlab in a spawned child process (:mod:`._pmlworker`): a crash,
a hang past ``timeout_s`` or an empty result fails this reconstruction with a
:class:`~treesim.errors.ReconstructionError`, never the caller. Both work in the
prepared cloud's local frame and return vertices in the input's coordinates (float64).

* :func:`poisson`: screened Poisson (``depth`` is the speed/accuracy knob: the octree has
  at most ``2**depth`` cells across the cloud's bounding box). It needs consistently
  oriented normals: with wrong or zero normals it returns blobs or nothing (an empty
  result is reported as an error). Poisson closes every hole and invents surface where
  there are no points; the density it estimates at each vertex tells them apart, and the
  vertices below the ``trim_density_quantile`` quantile of density are removed with
  their faces. Trimming opens the mesh wherever it cuts, so a trimmed mesh is rarely
  watertight: the untrimmed mesh's figures are reported in ``stats["untrimmed"]``.
* :func:`ball_pivoting`: rolls balls of the given radii (default 1, 2 and 3 × the point
  spacing) over the points; faces only where the data are. It leaves holes wherever the
  scan is one-sided, so its meshes are seldom watertight. Its cost is super-linear in the
  number of points (100k points ≈ 7 s, 200k ≈ 4 min on 2 cores), so clouds above
  ``max_points`` are thinned first (one real point per voxel, deterministic).

Meshes are cleaned (:func:`clean_mesh`) before they are returned: duplicate vertices
merged, degenerate, zero-area and duplicate faces removed, connected pieces with fewer
than ``min_component_fraction`` of the largest piece's faces dropped, unreferenced
vertices removed. ``watertight`` means every edge is shared by exactly two faces that
traverse it in opposite directions (closed and consistently oriented); only then is
``volume_m3`` given.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..cloud import Cloud
from ..errors import InvalidGeometryError, InvalidParameterError, ReconstructionError
from ..frame import LocalFrame
from ..geometry import point_spacing
from ._pmlworker import run_in_child
from .preprocess import PreparedCloud, estimate_normals, prepare, voxel_downsample

__all__ = ["SurfaceResult", "ball_pivoting", "clean_mesh", "edge_topology", "poisson"]

#: Default ball radii of :func:`ball_pivoting`, in multiples of the point spacing.
BPA_RADIUS_FACTORS: tuple[float, ...] = (1.0, 2.0, 3.0)


@dataclass(frozen=True, kw_only=True)
class SurfaceResult:
    """A reconstructed surface mesh.

    Parameters
    ----------
    method : {"poisson", "bpa"}
    vertices : (v, 3) float64
        In the input's coordinates (the frame origin added back).
    faces : (f, 3) int64
    watertight : bool
        Closed and consistently oriented (see the module docstring).
    n_triangles : int
    volume_m3 : float or None
        Enclosed volume when watertight, else ``None``.
    frame : LocalFrame
        The prepared cloud's frame (``vertices - frame.origin`` are local coordinates).
    params : dict
        The parameters used, including derived ones (radii, density threshold).
    timings : dict of str -> float
        Seconds: ``worker_s`` (pymeshlab itself), ``child_s`` (with process start-up and
        transfers), ``clean_s``, ``total_s``.
    stats : dict
        Counts from the raw output, trimming and cleaning; ``boundary_edges``,
        ``components``.
    """

    method: str
    vertices: np.ndarray
    faces: np.ndarray
    watertight: bool
    n_triangles: int
    volume_m3: float | None
    frame: LocalFrame
    params: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def local_vertices(self) -> np.ndarray:
        """The vertices in the local frame, (v, 3) float64."""
        return self.frame.to_local(self.vertices)

    def summary(self) -> dict[str, Any]:
        """A JSON-ready description (no arrays)."""
        return {
            "method": self.method,
            "n_vertices": int(len(self.vertices)),
            "n_triangles": self.n_triangles,
            "watertight": self.watertight,
            "volume_m3": self.volume_m3,
            "params": dict(self.params),
            "timings": dict(self.timings),
            "stats": dict(self.stats),
        }

    def write(self, path: str | Path) -> Path:
        """Write the mesh (``.ply`` or ``.obj``, float64 vertices) with ``write_mesh``."""
        from ..io.mesh import write_mesh

        return write_mesh(path, self.vertices, self.faces)


# --------------------------------------------------------------------------- mesh tools


def edge_topology(faces: np.ndarray) -> dict[str, Any]:
    """Edge-based topology of a triangle mesh.

    Parameters
    ----------
    faces : (f, 3) int

    Returns
    -------
    dict
        ``boundary_edges`` (edges of one face), ``nonmanifold_edges`` (edges of three or
        more faces), ``misoriented_edges`` (edges of two faces that traverse it the same
        way), and ``watertight``: no edge of the three kinds and at least one face.
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return {
            "boundary_edges": 0,
            "nonmanifold_edges": 0,
            "misoriented_edges": 0,
            "watertight": False,
        }
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    lo = directed.min(axis=1)
    hi = directed.max(axis=1)
    forward = (directed[:, 0] == lo).astype(np.int64)
    key = lo * (int(hi.max()) + 1) + hi
    uniq, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    n_forward = np.bincount(inv.reshape(-1), weights=forward, minlength=len(uniq))
    boundary = int((count == 1).sum())
    nonmanifold = int((count > 2).sum())
    misoriented = int(((count == 2) & (n_forward != 1)).sum())
    return {
        "boundary_edges": boundary,
        "nonmanifold_edges": nonmanifold,
        "misoriented_edges": misoriented,
        "watertight": boundary == 0 and nonmanifold == 0 and misoriented == 0,
    }


def clean_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    min_component_fraction: float = 0.01,
    min_component_faces: int = 8,
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Remove what reconstruction leaves behind, deterministically.

    In order: exact duplicate vertices are merged; faces that repeat a vertex are removed;
    zero-area faces with three distinct, collinear vertices (area below 1e-12 of the
    squared bounding-box diagonal; marching cubes makes a few) are removed by splitting
    their neighbour across the long edge at the middle vertex, which keeps a closed mesh
    closed (a sliver without a single such neighbour is dropped); faces that duplicate
    another (same three vertices, any order) are removed; connected pieces (sharing vertices)
    with fewer faces than ``max(min_component_faces, min_component_fraction × the
    largest piece)`` are removed; unreferenced vertices are removed.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    min_component_fraction : float
        Smallest piece kept, relative to the largest (0 keeps every piece).
    min_component_faces : int
        Smallest piece kept, in faces.

    Returns
    -------
    vertices : (v', 3) float64
    faces : (f', 3) int64
    stats : dict
        What each step removed, and ``components_kept``.
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    stats = {
        "merged_vertices": 0,
        "degenerate_faces": 0,
        "slivers_split": 0,
        "duplicate_faces": 0,
        "small_component_faces": 0,
        "components_removed": 0,
        "components_kept": 0,
        "unreferenced_vertices": 0,
    }
    if len(f) == 0 or len(v) == 0:
        return v, f.reshape(0, 3), stats
    if f.min() < 0 or f.max() >= len(v):
        raise InvalidGeometryError(f"faces refer to vertices outside 0..{len(v) - 1}")
    # duplicate vertices
    uv, inv = np.unique(v, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    stats["merged_vertices"] = int(len(v) - len(uv))
    v, f = uv, inv[f]
    # degenerate faces (a repeated vertex) go; zero-area slivers are split away
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    stats["degenerate_faces"] = int(repeated.sum())
    f = f[~repeated]
    diag2 = float(np.sum((v.max(axis=0) - v.min(axis=0)) ** 2))
    area2 = np.sum(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]) ** 2, axis=1)
    sliver = area2 <= (1e-12 * diag2) ** 2
    if sliver.any():
        f, split, dropped = _split_slivers(v, f, sliver)
        stats["slivers_split"] = split
        stats["degenerate_faces"] += dropped
    # duplicate faces (first occurrence kept)
    if len(f):
        _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        first = np.sort(first)
        stats["duplicate_faces"] = int(len(f) - len(first))
        f = f[first]
    # small connected pieces
    if len(f):
        nv = len(v)
        rows = np.concatenate([f[:, 0], f[:, 1]])
        cols = np.concatenate([f[:, 1], f[:, 2]])
        graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(nv, nv))
        _, label = connected_components(graph, directed=False)
        face_comp = label[f[:, 0]]
        sizes = np.bincount(face_comp)
        present = np.flatnonzero(sizes)
        limit = max(min_component_faces, min_component_fraction * sizes.max())
        keep_comp = sizes >= limit
        stats["components_removed"] = int((~keep_comp[present]).sum())
        stats["components_kept"] = int(keep_comp[present].sum())
        keep = keep_comp[face_comp]
        stats["small_component_faces"] = int((~keep).sum())
        f = f[keep]
    # unreferenced vertices
    used = np.zeros(len(v), dtype=bool)
    used[f.reshape(-1)] = True
    stats["unreferenced_vertices"] = int((~used).sum())
    remap = np.cumsum(used) - 1
    return v[used], remap[f].astype(np.int64), stats


def _split_slivers(v: np.ndarray, f: np.ndarray, sliver: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Remove zero-area faces ``f[sliver]`` by splitting their neighbours (edge split).

    A sliver ``(p, q, m)`` with ``m`` on the segment ``pq`` and the neighbour ``(q, p, d)``
    across ``pq`` become ``(q, m, d)`` and ``(m, p, d)``: every edge keeps its partner
    and its direction, so closedness and orientation are preserved.

    Returns the new faces, the number of slivers split and the number dropped.
    """
    nf = len(f)
    nv = len(v)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = directed[:, 0] * nv + directed[:, 1]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    drop = np.zeros(nf, dtype=bool)
    added: list[tuple[int, int, int]] = []
    split = dropped = 0
    for t in np.flatnonzero(sliver):
        if drop[t]:
            continue
        a, b, c = (int(x) for x in f[t])
        rotations = ((a, b, c), (b, c, a), (c, a, b))  # edge p -> q, opposite vertex m
        lengths = [float(np.sum((v[p] - v[q]) ** 2)) for p, q, _ in rotations]
        p, q, m = rotations[int(np.argmax(lengths))]
        k = q * nv + p
        lo, hi = np.searchsorted(skey, k), np.searchsorted(skey, k, side="right")
        cands = {int(order[i] % nf) for i in range(lo, hi)} - {int(t)}
        cands = {n for n in cands if not drop[n]}
        drop[t] = True
        if len(cands) != 1:
            dropped += 1
            continue
        n = cands.pop()
        d = next(int(x) for x in f[n] if x != p and x != q)
        drop[n] = True
        added.extend([(q, m, d), (m, p, d)])
        split += 1
    out = f[~drop]
    if added:
        out = np.vstack([out, np.asarray(added, dtype=np.int64)])
    return out, split, dropped


def _finish(
    *,
    method: str,
    prepared: PreparedCloud,
    v_local: np.ndarray,
    f: np.ndarray,
    min_component_fraction: float,
    params: dict[str, Any],
    stats: dict[str, Any],
    timings: dict[str, float],
    what: str,
    t_start: float,
) -> SurfaceResult:
    from ..models.mesh import mesh_volume

    t = time.perf_counter()
    v_local, f, cleaning = clean_mesh(v_local, f, min_component_fraction=min_component_fraction)
    topo = edge_topology(f)
    volume = None
    if topo["watertight"]:
        volume = mesh_volume(v_local, f)
        if volume < 0:  # closed but inside out: flip every face
            f = f[:, ::-1].copy()
            volume = -volume
            stats["flipped"] = True
    timings["clean_s"] = time.perf_counter() - t
    if len(f) == 0:
        raise ReconstructionError(
            f"{what} left no faces after cleaning (pieces under "
            f"{min_component_fraction:.0%} of the largest are dropped); check the input "
            "and the parameters"
        )
    stats["cleaning"] = cleaning
    stats.update({k: topo[k] for k in ("boundary_edges", "nonmanifold_edges", "misoriented_edges")})
    stats["components"] = cleaning["components_kept"]
    timings["total_s"] = time.perf_counter() - t_start
    return SurfaceResult(
        method=method,
        vertices=prepared.frame.to_global(v_local),
        faces=f,
        watertight=bool(topo["watertight"]),
        n_triangles=int(len(f)),
        volume_m3=None if volume is None else float(volume),
        frame=prepared.frame,
        params=params,
        timings={k: float(x) for k, x in timings.items()},
        stats=stats,
    )


def _prepared(prepared: PreparedCloud | Cloud | np.ndarray) -> PreparedCloud:
    if isinstance(prepared, PreparedCloud):
        return prepared
    return prepare(prepared)


def _normals_for(prepared: PreparedCloud, points: np.ndarray | None = None) -> np.ndarray:
    """The prepared normals, checked; estimated here if ``prepare`` skipped them."""
    pts = prepared.points if points is None else points
    if prepared.normals is None or points is not None:
        return estimate_normals(pts, 24, spacing_m=prepared.spacing_m)
    nrm = np.asarray(prepared.normals, dtype=np.float64)
    if nrm.shape != pts.shape:
        raise InvalidGeometryError(
            f"normals have shape {nrm.shape} for points of shape {pts.shape}; re-run prepare()"
        )
    length = np.linalg.norm(nrm, axis=1)
    bad = ~np.isfinite(length) | (length < 0.5)
    if bad.any():
        raise InvalidGeometryError(
            f"{int(bad.sum())} of {len(nrm)} normals are zero or not finite (first at row "
            f"{int(np.flatnonzero(bad)[0])}); surface reconstruction needs unit normals "
            "(Poisson returns no surface without them); re-estimate them with "
            "estimate_normals()"
        )
    return nrm / length[:, None]


def _check_common(timeout_s: float, min_component_fraction: float) -> None:
    if not (math.isfinite(timeout_s) and timeout_s > 0):
        raise InvalidParameterError(
            f"timeout_s must be a positive number of seconds, got {timeout_s}"
        )
    if not (0.0 <= min_component_fraction < 1.0):
        raise InvalidParameterError(
            f"min_component_fraction must be in [0, 1), got {min_component_fraction}"
        )


# --------------------------------------------------------------------------- Poisson


def _check_poisson(
    depth: int,
    trim_density_quantile: float | None,
    threads: int,
    samples_per_node: float,
    point_weight: float,
    trim_distance_m: float | None,
    timeout_s: float,
    min_component_fraction: float,
) -> float:
    """Raise :class:`InvalidParameterError` for a :func:`poisson` parameter out of range;
    returns the density trim's quantile (0: no trim)."""
    if int(depth) != depth or not 4 <= depth <= 16:
        raise InvalidParameterError(f"depth must be an integer in 4..16, got {depth}")
    q = 0.0 if trim_density_quantile is None else float(trim_density_quantile)
    if not 0.0 <= q < 1.0:
        raise InvalidParameterError(
            f"trim_density_quantile must be in [0, 1) or None, got {trim_density_quantile}"
        )
    if int(threads) != threads or threads < 1:
        raise InvalidParameterError(f"threads must be a positive integer, got {threads}")
    if not (samples_per_node > 0 and point_weight >= 0):
        raise InvalidParameterError(
            "samples_per_node must be positive and point_weight non-negative, got "
            f"{samples_per_node} and {point_weight}"
        )
    _check_common(timeout_s, min_component_fraction)
    if trim_distance_m is not None and not (math.isfinite(trim_distance_m) and trim_distance_m > 0):
        raise InvalidParameterError(
            f"trim_distance_m must be a positive length in metres or None, got {trim_distance_m}"
        )
    return q


def poisson(
    prepared: PreparedCloud | Cloud | np.ndarray,
    *,
    depth: int = 8,
    trim_density_quantile: float | None = 0.1,
    threads: int = 2,
    timeout_s: float = 600.0,
    samples_per_node: float = 1.5,
    point_weight: float = 4.0,
    trim_distance_m: float | None = None,
    min_component_fraction: float = 0.01,
) -> SurfaceResult:
    """Screened Poisson surface reconstruction (pymeshlab), trimmed by density.

    Parameters
    ----------
    prepared : PreparedCloud
        From :func:`~treesim.reconstruct.preprocess.prepare` (a ``Cloud`` or an array is
        prepared with the defaults first). Its normals must point outward.
    depth : int
        Octree depth, 4..16: 8 is ~1/256 of the cloud's extent (2.5 cm on a 6 m tree).
        Time and memory grow about 4× per level on surfaces (500k points: depth 8 3.5 s,
        10 43 s, 12 77 s).
    trim_density_quantile : float or None
        Vertices whose density is below this quantile of all vertex densities are removed
        with their faces (hallucinated surface has low density). ``None`` or 0: no trim.
    threads : int
        Threads pymeshlab may use.
    timeout_s : float
        The child process is killed after this long.
    samples_per_node : float
        Minimum points per octree node (pymeshlab ``samplespernode``); raise it for noisy
        clouds.
    point_weight : float
        Screening weight (pymeshlab ``pointweight``): how closely the surface follows the
        points.
    trim_distance_m : float, optional
        Also remove vertices farther than this from every input point (m), with their
        faces. Off by default. On whole trees whose thin branches are smaller than the
        octree cell (``params["cell_m"]``), Poisson also invents large sheets that the
        density does not flag (a 17 m simulated aspen at depth 8: 438 m² left after the
        density trim against 40 m² of true bark); about two cells removes them.
    min_component_fraction : float
        Pieces with fewer faces than this share of the largest piece are dropped.

    Returns
    -------
    SurfaceResult
        ``params["density_threshold"]`` is the trim threshold; ``stats["untrimmed"]``
        has the untrimmed mesh's triangles, watertightness and volume.

    Raises
    ------
    InvalidParameterError
        A parameter out of range.
    InvalidGeometryError
        Zero or non-finite normals.
    ReconstructionError
        pymeshlab crashed, timed out, raised, or returned no surface.
    """
    t_start = time.perf_counter()
    q = _check_poisson(
        depth,
        trim_density_quantile,
        threads,
        samples_per_node,
        point_weight,
        trim_distance_m,
        timeout_s,
        min_component_fraction,
    )
    prep = _prepared(prepared)
    normals = _normals_for(prep)
    n = len(prep.points)
    extent = float(np.max(prep.points.max(axis=0) - prep.points.min(axis=0)))
    what = f"screened Poisson (depth {depth}) on {n} points"
    params: dict[str, Any] = {
        "method": "poisson",
        "depth": int(depth),
        "trim_density_quantile": q,
        "threads": int(threads),
        "samples_per_node": float(samples_per_node),
        "point_weight": float(point_weight),
        "trim_distance_m": None if trim_distance_m is None else float(trim_distance_m),
        "min_component_fraction": float(min_component_fraction),
        "timeout_s": float(timeout_s),
        "n_points": n,
        # pymeshlab's octree cube is the bounding cube enlarged by its scale (1.1)
        "cell_m": 1.1 * extent / 2 ** int(depth),
        "normals": "prepared" if prep.normals is not None else "estimated",
    }
    t = time.perf_counter()
    out, worker_s = run_in_child(
        "poisson",
        {"points": prep.points, "normals": normals},
        params,
        timeout_s=timeout_s,
        what=what,
        advice="Try a smaller depth, fewer points (a larger voxel_size_m) or a longer timeout_s.",
    )
    timings = {"worker_s": worker_s, "child_s": time.perf_counter() - t}
    v, f = out["vertices"], out["faces"]
    if len(f) == 0:
        raise ReconstructionError(
            f"{what} returned no surface (0 faces): Poisson does this silently when the "
            "normals are not consistently oriented outward or the points are too few or "
            "too flat; check the normals (estimate_normals with axis_points from a "
            "skeleton) and the input"
        )
    density = out.get("density")
    stats: dict[str, Any] = {"raw_vertices": int(len(v)), "raw_triangles": int(len(f))}
    untrimmed_topo = edge_topology(f)
    stats["untrimmed"] = {
        "n_triangles": int(len(f)),
        "watertight": bool(untrimmed_topo["watertight"]),
        "volume_m3": _volume_or_none(v, f, untrimmed_topo["watertight"]),
    }
    params["density_threshold"] = None
    if q > 0 and density is not None and len(density) == len(v):
        threshold = float(np.quantile(density, q))
        params["density_threshold"] = threshold
        low = density < threshold
        f = f[~low[f].any(axis=1)]
        stats["trimmed_vertices"] = int(low.sum())
        stats["trimmed_triangles"] = int(stats["raw_triangles"] - len(f))
    if trim_distance_m is not None:
        dist, _ = cKDTree(prep.points).query(v)
        far = dist > trim_distance_m
        before = len(f)
        f = f[~far[f].any(axis=1)]
        stats["distance_trimmed_vertices"] = int(far.sum())
        stats["distance_trimmed_triangles"] = int(before - len(f))
    return _finish(
        method="poisson",
        prepared=prep,
        v_local=v,
        f=f,
        min_component_fraction=min_component_fraction,
        params=params,
        stats=stats,
        timings=timings,
        what=what,
        t_start=t_start,
    )


def _volume_or_none(v: np.ndarray, f: np.ndarray, closed: bool) -> float | None:
    if not closed:
        return None
    from ..models.mesh import mesh_volume

    return float(abs(mesh_volume(v, f)))


# --------------------------------------------------------------------------- ball pivoting


def _thin_to(points: np.ndarray, spacing_m: float, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` points: per voxel, the point nearest its centroid.

    The voxel grows (×1.15 per try, from ``spacing × sqrt(n / max_points)``, the surface
    scaling) until the count fits. Deterministic.
    """
    n = len(points)
    h = max(spacing_m, 1e-6) * math.sqrt(n / max_points)
    while True:
        cent, _, inv = voxel_downsample(points, h)
        if len(cent) <= max_points:
            break
        h *= 1.15
    d = np.sum((points - cent[inv]) ** 2, axis=1)
    order = np.lexsort((np.arange(n), d, inv))
    first = np.ones(n, dtype=bool)
    first[1:] = inv[order][1:] != inv[order][:-1]
    return np.sort(order[first])


def ball_pivoting(
    prepared: PreparedCloud | Cloud | np.ndarray,
    *,
    radii_m: list[float] | tuple[float, ...] | None = None,
    max_points: int = 100_000,
    timeout_s: float = 600.0,
    clustering_pct: float = 20.0,
    crease_angle_deg: float = 90.0,
    min_component_fraction: float = 0.01,
) -> SurfaceResult:
    """Ball-pivoting surface reconstruction (pymeshlab).

    Parameters
    ----------
    prepared : PreparedCloud
        From :func:`~treesim.reconstruct.preprocess.prepare` (a ``Cloud`` or an array is
        prepared with the defaults first).
    radii_m : sequence of float, optional
        Ball radii (m), applied smallest first, each pass keeping the faces of the
        previous ones. Default ``BPA_RADIUS_FACTORS`` (1, 2, 3) × the spacing of the
        points used.
    max_points : int
        Clouds with more points are thinned to at most this many first (one real point,
        with its normal, per voxel), since the cost is super-linear.
    timeout_s : float
        The child process is killed after this long.
    clustering_pct : float
        pymeshlab ``clustering``: vertices closer than this percentage of the radius are
        merged.
    crease_angle_deg : float
        pymeshlab ``creasethr``: the largest angle between faces the ball may pivot over.
    min_component_fraction : float
        Pieces with fewer faces than this share of the largest piece are dropped.

    Returns
    -------
    SurfaceResult
        ``params["radii_m"]`` are the radii used, ``params["n_points"]`` the points.

    Raises
    ------
    InvalidParameterError, InvalidGeometryError, ReconstructionError
        As :func:`poisson`.
    """
    t_start = time.perf_counter()
    if int(max_points) != max_points or max_points < 100:
        raise InvalidParameterError(f"max_points must be an integer >= 100, got {max_points}")
    if not (0 <= clustering_pct <= 100 and 0 < crease_angle_deg <= 180):
        raise InvalidParameterError(
            "clustering_pct must be in [0, 100] and crease_angle_deg in (0, 180], got "
            f"{clustering_pct} and {crease_angle_deg}"
        )
    _check_common(timeout_s, min_component_fraction)
    if radii_m is not None:
        radii = sorted(float(r) for r in radii_m)
        if not radii or not all(math.isfinite(r) and r > 0 for r in radii):
            raise InvalidParameterError(
                f"radii_m must be positive lengths in metres, got {list(radii_m)}"
            )
    prep = _prepared(prepared)
    pts = prep.points
    thinned = len(pts) > max_points
    if thinned:
        idx = _thin_to(pts, prep.spacing_m, int(max_points))
        pts = pts[idx]
        normals = _normals_for(prep)[idx] if prep.normals is not None else _normals_for(prep, pts)
        spacing = point_spacing(pts, distinct=False, workers=1)
    else:
        normals = _normals_for(prep)
        spacing = prep.spacing_m
    if radii_m is None:
        if not spacing > 0:
            raise InvalidGeometryError("the point spacing is zero; give radii_m explicitly")
        radii = [k * spacing for k in BPA_RADIUS_FACTORS]
    n = len(pts)
    what = f"ball pivoting on {n} points (radii {', '.join(f'{r * 1000:.3g}' for r in radii)} mm)"
    params: dict[str, Any] = {
        "method": "bpa",
        "radii_m": radii,
        "spacing_m": float(spacing),
        "max_points": int(max_points),
        "thinned": thinned,
        "n_points": n,
        "clustering_pct": float(clustering_pct),
        "crease_angle_deg": float(crease_angle_deg),
        "min_component_fraction": float(min_component_fraction),
        "timeout_s": float(timeout_s),
        "normals": "prepared" if prep.normals is not None else "estimated",
    }
    t = time.perf_counter()
    out, worker_s = run_in_child(
        "ball_pivoting",
        {"points": pts, "normals": normals},
        params,
        timeout_s=timeout_s,
        what=what,
        advice="Try a smaller max_points, fewer or smaller radii, or a longer timeout_s.",
    )
    timings = {"worker_s": worker_s, "child_s": time.perf_counter() - t}
    v, f = out["vertices"], out["faces"]
    if len(f) == 0:
        raise ReconstructionError(
            f"{what} made no faces: the radii are too small for the point spacing "
            f"({spacing * 1000:.3g} mm); give larger radii_m"
        )
    stats: dict[str, Any] = {"raw_vertices": int(len(v)), "raw_triangles": int(len(f))}
    return _finish(
        method="bpa",
        prepared=prep,
        v_local=v,
        f=f,
        min_component_fraction=min_component_fraction,
        params=params,
        stats=stats,
        timings=timings,
        what=what,
        t_start=t_start,
    )
