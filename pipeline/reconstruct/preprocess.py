"""Preparing a field point cloud for reconstruction: checks, thinning, cleaning, normals.

:func:`prepare` turns a :class:`~treesim.cloud.Cloud` (any coordinates, georeferenced
or not) into a :class:`PreparedCloud` in a float64 local frame, in this order:

1. **Checks** (:func:`validate_tree_cloud`): enough points, no NaN/inf rows, not all
   identical, not a plane or a line; each failure names the problem.
2. **Voxel downsampling** (``voxel_size_m``, default 5 mm): one point per occupied voxel,
   the centroid of the points in it, computed in float64; ``weights`` count the input
   points each output point stands for. Duplicate points always collapse (with the voxel
   grid off, exact duplicates are merged instead): duplicates break PCA normals and change
   Poisson and ball-pivoting output.
3. **Statistical outlier removal** (``sor_neighbors``, ``sor_std_ratio``): a point whose
   mean distance to its ``k`` nearest neighbours exceeds the mean of that figure over the
   cloud by more than ``sor_std_ratio`` standard deviations (PCL's and Open3D's rule) and
   is also more than three times its neighbours' median is dropped: sparse but consistent
   regions (a treetop far from the scanner) stay.
4. **Ground removal** (``remove_ground``, on by default): see :func:`find_ground`. A
   horizontal or gently sloping plane is fitted (RANSAC with a fixed seed) to the points
   of the lowest 0.5 m whose local surface is near horizontal; it is taken for ground only when its
   inliers cover a wide, filled area (at least 0.25 m² and a quarter of their bounding
   box), so the cut end of a stem with no ground under it is never removed. Then every
   point less than ``ground_tolerance_m`` above the plane (or below it) is dropped. Then
   the stem's foot and the understory (``remove_understory``): see
   :mod:`treesim.reconstruct.foot`.
5. **Spacing**: the median nearest-neighbour distance of what is left.
6. **Normals** (:func:`estimate_normals`): PCA of the ``normals_neighbors`` nearest
   neighbours, oriented outward (away from the local centroid at the smallest telling
   scale, see there).
7. **Leaves** (:func:`leaf_measure`): the share of points whose ~10 cm neighbourhood has
   normals pointing every way (foliage), as opposed to normals perpendicular to one axis
   (stems, branches, even twigs whose PCA normals are noisy).

Every step records how many points it removed in :attr:`PreparedCloud.steps`.
Everything is deterministic and vectorised (``scipy.spatial.cKDTree``; no O(n²) step).
Each step's code lives in a module of its topic: :mod:`~treesim.reconstruct.validate`,
:mod:`~treesim.reconstruct.thin`, :mod:`~treesim.reconstruct.outliers`,
:mod:`~treesim.reconstruct.ground` (and :mod:`~treesim.reconstruct.foot`),
:mod:`~treesim.reconstruct.normals`, :mod:`~treesim.reconstruct.leaf_measure`, with the
neighbour searches they share in :mod:`~treesim.reconstruct.neighbours`; their public
names are importable from here too.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..cloud import Cloud
from ..errors import EmptyInputError
from ..frame import LocalFrame
from ..params import PrepareParams
from .foot import StemFoot, find_foot, understory

# the steps' public names, importable from here as they were before the split by topic
from .ground import (  # noqa: F401
    GROUND_BAND_M,
    GROUND_MAX_TILT_DEG,
    GROUND_MIN_AREA_M2,
    GROUND_MIN_FILL,
    GROUND_RANSAC_SEED,
    GROUND_RANSAC_TRIALS,
    find_ground,
)
from .leaf_measure import (  # noqa: F401
    LEAF_NORMAL_SPREAD,
    LEAF_PRESENT_FRACTION,
    LEAF_RADIUS_M,
    leaf_measure,
)
from .neighbours import KEPT_NEIGHBORS, _neighbors_of_kept, _spacing, nearest_neighbors
from .normals import LINE_NEIGHBOURHOOD, _estimate_normals, _local_pca, estimate_normals  # noqa: F401
from .outliers import SOR_LOCAL_RATIO, SOR_MAX_SPARSITY, statistical_outliers  # noqa: F401
from .thin import voxel_downsample
from .validate import LINE_SD_RATIO, PLANE_SD_RATIO, _as_points, validate_tree_cloud  # noqa: F401

__all__ = [
    "PrepareParams",
    "PreparedCloud",
    "estimate_normals",
    "find_ground",
    "leaf_measure",
    "nearest_neighbors",
    "prepare",
    "validate_tree_cloud",
    "voxel_downsample",
]


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True, kw_only=True)
class PreparedCloud:
    """A cloud ready for reconstruction, in a local frame.

    Parameters
    ----------
    frame : LocalFrame
        Add ``frame.origin`` to local coordinates to get the input's coordinates.
    points : (n, 3) float64
        Local coordinates (m).
    weights : (n,) int64
        Input points each point stands for (points merged into its voxel).
    normals : (n, 3) float64 or None
        Unit normals oriented outward, or ``None`` when not asked for.
    spacing_m : float
        Median nearest-neighbour distance of ``points`` (m).
    steps : list of dict
        One record per step: ``step``, ``points_before``, ``points_after``, ``removed``,
        ``params`` (including ``enabled``).
    leaves_present : bool
        ``leaf_fraction >= LEAF_PRESENT_FRACTION``.
    leaf_fraction : float
        Share of input points (weighted) in foliage-like neighbourhoods, see
        :func:`leaf_measure`.
    n_input : int
        Points in the input cloud.
    params : PrepareParams
        The parameters used.
    neighbors : (n, k) int32 or None
        Each point's ``k = max(KEPT_NEIGHBORS, normals_neighbors)`` nearest points (itself
        first), sorted by distance (:func:`nearest_neighbors`); the QSM builds its graph
        from them instead of searching the cloud again. ``None`` on a cloud built by
        hand.
    foot : StemFoot or None
        The terrain under the tree and the stem's foot on it
        (:func:`~treesim.reconstruct.foot.find_foot`); the QSM grows from it.
    """

    frame: LocalFrame
    points: np.ndarray
    weights: np.ndarray
    normals: np.ndarray | None
    spacing_m: float
    steps: list[dict[str, Any]]
    leaves_present: bool
    leaf_fraction: float
    n_input: int
    params: PrepareParams = field(default_factory=PrepareParams)
    neighbors: np.ndarray | None = field(default=None, repr=False, compare=False)
    foot: StemFoot | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def global_points(self) -> np.ndarray:
        """The points in the input's coordinates, (n, 3) float64."""
        return self.frame.to_global(self.points)

    def summary(self) -> dict[str, Any]:
        """A JSON-ready description: counts, spacing, leaves, steps and parameters."""
        return {
            "n_input": self.n_input,
            "n_points": len(self.points),
            "spacing_m": self.spacing_m,
            "leaves_present": self.leaves_present,
            "leaf_fraction": self.leaf_fraction,
            "frame_origin": list(self.frame.origin),
            "steps": [dict(s) for s in self.steps],
            "params": asdict(self.params),
        }


# --------------------------------------------------------------------------- prepare


def _kept(
    pts: np.ndarray,
    weights: np.ndarray,
    neighbors: np.ndarray,
    keep: np.ndarray,
    k: int,
    tree: cKDTree | None,
    workers: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points, weights and ``k`` nearest kept neighbours
    (:func:`~treesim.reconstruct.neighbours._neighbors_of_kept`) of the points ``keep``
    marks; ``tree`` is ``pts``'s (built here when None)."""
    tree = cKDTree(pts) if tree is None else tree
    kept_neighbors = _neighbors_of_kept(pts, neighbors, keep, k, tree, workers=workers)
    return pts[keep], weights[keep], kept_neighbors


def _step(name: str, before: int, after: int, **params: Any) -> dict[str, Any]:
    return {
        "step": name,
        "points_before": int(before),
        "points_after": int(after),
        "removed": int(before - after),
        "params": params,
    }


@dataclass
class _Working:
    """The cloud between preparation's steps: points, weights, each point's nearest
    neighbours, and (until a step removes points) the search's nearest distances and
    k-d tree, which later steps reuse instead of searching again."""

    pts: np.ndarray
    weights: np.ndarray
    neighbors: np.ndarray
    nearest: np.ndarray | None
    tree: cKDTree | None

    def keep(self, mask: np.ndarray, k: int, workers: int) -> None:
        """Keep the points ``mask`` marks, with their ``k`` nearest kept neighbours."""
        self.pts, self.weights, self.neighbors = _kept(
            self.pts, self.weights, self.neighbors, mask, k, self.tree, workers
        )
        self.nearest, self.tree = None, None

    def spacing(self) -> float:
        """The median nearest-neighbour distance (:func:`_spacing`)."""
        return _spacing(self.pts, self.neighbors, self.nearest)


def _thin(
    local: np.ndarray, params: PrepareParams, k_keep: int, w: int, steps: list[dict[str, Any]]
) -> _Working:
    """Step 1, voxel downsampling (or deduplication), and the neighbour search of the
    thinned cloud."""
    n0 = len(local)
    pts, weights, _ = voxel_downsample(local, params.voxel_size_m)
    if params.voxel_size_m is None:
        steps.append(_step("deduplicate", n0, len(pts), enabled=True, voxel_size_m=None))
    else:
        steps.append(
            _step("voxel_downsample", n0, len(pts), enabled=True, voxel_size_m=params.voxel_size_m)
        )
    # one neighbour search of the thinned cloud serves outlier removal, the spacing, the
    # PCA and the QSM's graph (see step 4)
    tree = cKDTree(pts)
    k_search = k_keep if params.sor_std_ratio is None else max(k_keep, params.sor_neighbors + 1)
    neighbors, nearest = nearest_neighbors(pts, k_search, tree, workers=w)
    return _Working(pts=pts, weights=weights, neighbors=neighbors, nearest=nearest, tree=tree)


def _remove_outliers(
    c: _Working, params: PrepareParams, k_keep: int, w: int, steps: list[dict[str, Any]]
) -> None:
    """Step 2, statistical outlier removal (``c`` in place)."""
    n1 = len(c.pts)
    if params.sor_std_ratio is not None:
        keep = statistical_outliers(
            c.pts, params.sor_neighbors, params.sor_std_ratio, workers=w, knn=c.neighbors
        )
        if not keep.all():
            c.keep(keep, k_keep, w)
    c.neighbors = c.neighbors[:, :k_keep]
    steps.append(
        _step(
            "outlier_removal",
            n1,
            len(c.pts),
            enabled=params.sor_std_ratio is not None,
            neighbors=params.sor_neighbors,
            std_ratio=params.sor_std_ratio,
        )
    )


def _remove_ground(
    c: _Working, params: PrepareParams, k_keep: int, w: int, steps: list[dict[str, Any]]
) -> tuple[float, ...] | None:
    """Step 3a, ground removal (``c`` in place); returns the ground plane (a, b, c, d),
    None when none was detected."""
    n2 = len(c.pts)
    ground_info: dict[str, Any] = {}
    plane = None
    if params.remove_ground:
        c.tree = cKDTree(c.pts) if c.tree is None else c.tree
        ground, ground_info = find_ground(
            c.pts, params.ground_tolerance_m, c.spacing(), tree=c.tree, workers=w
        )
        if ground_info.get("detected"):
            plane = tuple(ground_info["plane"])
        if ground.any():
            c.keep(~ground, k_keep, w)
    steps.append(
        _step(
            "ground_removal",
            n2,
            len(c.pts),
            enabled=params.remove_ground,
            tolerance_m=params.ground_tolerance_m,
            **ground_info,
        )
    )
    return plane


def _remove_understory(
    c: _Working,
    params: PrepareParams,
    plane: tuple[float, ...] | None,
    k_keep: int,
    w: int,
    steps: list[dict[str, Any]],
) -> StemFoot | None:
    """Step 3b, the stem's foot (returned) and understory removal (``c`` in place)."""
    n3 = len(c.pts)
    spacing = c.spacing()
    foot = find_foot(c.pts, c.neighbors, spacing, plane=plane, weights=c.weights)
    under_info: dict[str, Any] = {}
    if params.remove_understory and foot is not None and plane is not None:
        under, under_info = understory(c.pts, c.neighbors, spacing, foot)
        if under.any() and (~under).sum() >= max(10, params.normals_neighbors or 0):
            c.keep(~under, k_keep, w)
    steps.append(
        _step(
            "understory_removal",
            n3,
            len(c.pts),
            enabled=params.remove_understory and plane is not None,
            foot=None if foot is None else foot.to_dict(),
            **under_info,
        )
    )
    return foot


def _normals_and_leaves(
    c: _Working, params: PrepareParams, normals: bool, k_pca: int, w: int
) -> tuple[float, np.ndarray | None, float]:
    """Step 4: the spacing (median nearest-neighbour distance), the oriented normals
    (None unless asked for) and the leaf fraction, from the neighbours found in step 1.
    Releases ``c.tree``."""
    spacing = c.spacing()
    oriented: np.ndarray | None = None
    if params.normals_neighbors is not None and normals:
        oriented, evals, unoriented = _estimate_normals(
            c.pts, k_pca, spacing_m=spacing, workers=w, tree=c.tree, neighbors=c.neighbors
        )
    else:
        evals, unoriented = _local_pca(c.pts, k_pca, c.tree, workers=w, neighbors=c.neighbors)
    c.tree = None
    leaf_fraction, _ = leaf_measure(c.pts, unoriented, spacing, c.weights, evals=evals, workers=w)
    return spacing, oriented, leaf_fraction


def prepare(
    cloud: Cloud | np.ndarray, params: PrepareParams | None = None, *, normals: bool = True
) -> PreparedCloud:
    """Check, thin and clean a tree cloud, and estimate its normals.

    Parameters
    ----------
    cloud : Cloud or (n, 3) float
        Points in the input's coordinates (georeferenced or not).
    params : PrepareParams, optional
        Defaults: 5 mm voxels, outlier removal (16 neighbours, 2.5 σ), ground and
        understory removal, normals from 24 neighbours.
    normals : bool
        Orient normals (``params.normals_neighbors``); ``False`` leaves
        :attr:`PreparedCloud.normals` ``None`` for a method that does not use them (the
        QSM), which saves their orientation, the dearest step on large clouds. The leaf
        measure is the same either way: it reads the unoriented PCA.

    Returns
    -------
    PreparedCloud
        See the module docstring for the steps.

    Raises
    ------
    EmptyInputError, InvalidGeometryError
        From :func:`validate_tree_cloud`, or when cleaning leaves too few points.
    """
    params = PrepareParams() if params is None else params
    w = int(params.threads)
    pts_in = _as_points(cloud)
    validate_tree_cloud(pts_in, min_points=params.min_points)
    frame = LocalFrame.around(pts_in)
    local = frame.to_local(pts_in)
    steps: list[dict[str, Any]] = []
    k_pca = params.normals_neighbors or 24
    k_keep = max(KEPT_NEIGHBORS, k_pca)

    c = _thin(local, params, k_keep, w, steps)  # 1. voxel downsampling / deduplication
    _remove_outliers(c, params, k_keep, w, steps)  # 2. statistical outlier removal
    # 3. ground removal, the stem's foot, understory (treesim.reconstruct.foot)
    plane = _remove_ground(c, params, k_keep, w, steps)
    foot = _remove_understory(c, params, plane, k_keep, w, steps)
    if len(c.pts) < max(10, params.normals_neighbors or 0):
        raise EmptyInputError(
            f"only {len(c.pts)} points are left after cleaning ({len(local)} in the input); "
            "use a smaller voxel_size_m, a larger sor_std_ratio, or turn ground removal off"
        )
    validate_tree_cloud(c.pts, min_points=min(params.min_points, len(c.pts)))
    spacing, oriented, leaf_fraction = _normals_and_leaves(c, params, normals, k_pca, w)  # 4.
    return PreparedCloud(
        frame=frame,
        points=c.pts,
        weights=c.weights,
        normals=oriented,
        neighbors=c.neighbors,
        spacing_m=spacing,
        steps=steps,
        leaves_present=leaf_fraction >= LEAF_PRESENT_FRACTION,
        leaf_fraction=leaf_fraction,
        n_input=len(local),
        params=params,
        foot=foot,
    )
