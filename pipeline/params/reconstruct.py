"""Reconstruction parameters: preparation, the cylinder QSM, the surface methods."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

from ._fields import check_bounds, param

Method = Literal["qsm", "poisson", "bpa"]
METHODS: tuple[str, ...] = ("qsm", "poisson", "bpa")
LeafMode = Literal["auto", "on", "off"]
LEAF_MODES: tuple[str, ...] = ("auto", "on", "off")

__all__ = [
    "LEAF_MODES",
    "METHODS",
    "MIN_CLOUD_POINTS",
    "PrepareParams",
    "QSMParams",
    "ReconstructParams",
]

#: Fewest points of a cloud that can be measured at all: four can span a volume, three
#: always lie in a plane. Reconstruction never accepts fewer (``PrepareParams.min_points``
#: may not be set below it; its default asks 300 of a tree) and neither does comparison
#: (:func:`treesim.compare.compare`), for the cloud and for a reference cloud.
MIN_CLOUD_POINTS = 4


@dataclass(frozen=True, kw_only=True)
class PrepareParams:
    """How :func:`prepare` thins and cleans a cloud.

    Parameters
    ----------
    voxel_size_m : float or None
        Edge of the downsampling voxels (m); ``None`` keeps every point but still merges
        exact duplicates.
    sor_neighbors : int
        Neighbours per point in statistical outlier removal.
    sor_std_ratio : float or None
        Outlier threshold in standard deviations of the mean neighbour distance;
        ``None`` turns outlier removal off.
    remove_ground : bool
        Look for the terrain under the tree (a plane over a wide, filled area of low,
        level points) and remove the points on it; a cloud with no ground keeps every
        point (:func:`~treesim.reconstruct.preprocess.find_ground`).
    remove_understory : bool
        With ground found, remove what grows from or lies on it but is not the tree:
        litter and fallen wood away from the stem's foot, shrubs and saplings
        (:func:`~treesim.reconstruct.foot.understory`).
    ground_tolerance_m : float
        Points less than this above the ground plane (or below it) are ground.
    normals_neighbors : int or None
        Neighbours per point for PCA normals; ``None`` skips normals.
    min_points : int
        Fewest points a tree cloud may have.
    threads : int
        Threads for the neighbour searches (results do not depend on it).
    """

    voxel_size_m: float | None = param(
        0.005,
        help="voxel size for downsampling the field cloud",
        unit="m",
        none_means="off (exact duplicates still merged)",
        flag="--voxel-m",
        gt=0,
    )
    sor_neighbors: int = param(16, help="neighbours per point in statistical outlier removal", ge=2)
    sor_std_ratio: float | None = param(
        2.5,
        help="statistical outlier removal threshold, in standard deviations",
        none_means="off",
        gt=0,
    )
    remove_ground: bool = param(True, help="find the terrain under the tree and remove it")
    remove_understory: bool = param(
        True, help="with ground found, remove litter, fallen wood and shrubs around the stem"
    )
    ground_tolerance_m: float = param(
        0.05, help="points this close to the ground plane are ground", unit="m", gt=0
    )
    normals_neighbors: int | None = param(
        24, help="neighbours per point for PCA normals", none_means="no normals", ge=3
    )
    min_points: int = param(300, help="fewest points a tree cloud may have", ge=MIN_CLOUD_POINTS)
    threads: int = param(2, help="threads for the neighbour searches", execution_only=True, ge=1)

    def __post_init__(self) -> None:
        check_bounds(self)


@dataclass(frozen=True, kw_only=True)
class QSMParams:
    """Parameters of the cylinder QSM (``None``: derived from the point spacing).

    Parameters
    ----------
    slice_m : float, optional
        Thickness of the geodesic slices (node spacing along branches); default
        ``clamp(6 × spacing, 0.02, 0.08)``.
    neighbors : int
        Neighbours per point in the graph.
    link_m : float, optional
        Longest graph edge before gap bridging; default ``max(4 × spacing, 0.02)``.
    base_band_m : float, optional
        Points this close above the lowest point form the base; default ``slice_m / 2``.
    min_coverage_deg : float
        Arc a circle fit's points must cover to count as measured.
    max_rel_residual : float
        Largest RMS residual of a measured fit, relative to its radius.
    partial_coverage_deg, partial_rel_residual : float
        A fit covering less than ``min_coverage_deg`` (one-sided scans) still counts as
        measured when it covers at least ``partial_coverage_deg`` with an RMS residual
        under ``partial_rel_residual`` of its radius.
    pipe_exponent : float
        Exponent b of the radius model ``r^(1/b) = r_tip^(1/b) + a · S`` (S: growth
        length); 0.5 is the pipe model (cross-section area = tip area + area proportional
        to the length supported).
    min_radius_m : float, optional
        Smallest radius that can be measured; default ``max(resolve_sigmas × σ, 0.5 ×
        spacing)``, σ the noise of the points about the surface, estimated from the
        stem's well-measured circle fits (:func:`treesim.reconstruct.qsm.estimate_noise`;
        ``1.5 × spacing`` when no fit allows an estimate).
    resolve_sigmas : float
        k of the radius a circle fit resolves, ``k σ``: below it a fitted radius is mostly
        noise and the node takes the pipe model (4: the band from which every procedural
        preset's fits are unbiased under 3 mm range noise, as
        ``benchmarks/bench_noise_radii.py`` measures).
    twig_radius_m : float
        Radius prior of branch tips (twigs), m: the radius a branch tends to at its tip,
        where no scan resolves it. 1.5 mm is within the range of measured twig diameters
        (rTwig's database: about 3-5 mm) and keeps the procedural presets' branch volume
        within +5..+16 % (conifer shoots, thinner still, +76 %).
    """

    slice_m: float | None = param(
        None,
        help="geodesic slice thickness",
        unit="m",
        none_means="clamp(6 × spacing, 0.02, 0.08) m",
        gt=0,
    )
    neighbors: int = param(10, help="neighbours per point in the graph", ge=3, le=64)
    link_m: float | None = param(
        None,
        help="longest graph edge before gap bridging",
        unit="m",
        none_means="max(4 × spacing, 0.02) m",
        gt=0,
    )
    base_band_m: float | None = param(
        None,
        help="points this close above the lowest point form the base",
        unit="m",
        none_means="slice_m / 2",
        gt=0,
    )
    min_coverage_deg: float = param(
        180.0, help="arc a circle fit must cover to count as measured", unit="deg", gt=0, le=360
    )
    max_rel_residual: float = param(
        0.12, help="largest RMS residual of a measured fit, relative to its radius", gt=0
    )
    partial_coverage_deg: float = param(
        120.0,
        help="smallest arc of a low-residual partial fit (one-sided scans)",
        unit="deg",
        gt=0,
        le=360,
    )
    partial_rel_residual: float = param(
        0.06, help="largest relative RMS residual of a partial fit", gt=0
    )
    pipe_exponent: float = param(0.5, help="exponent b of the radius model (0.5: pipe model)", gt=0)
    min_radius_m: float | None = param(
        None,
        help="smallest radius that can be measured",
        unit="m",
        none_means="max(resolve_sigmas × the estimated noise σ, 0.5 × spacing)",
        gt=0,
    )
    resolve_sigmas: float = param(
        4.0,
        help="a circle fit's radius counts as measured only from this many noise σ up",
        gt=0,
    )
    twig_radius_m: float = param(0.0015, help="radius prior of branch tips (twigs)", unit="m", gt=0)
    seed: int = param(0, help="seed of the robust fits", ge=0)

    def __post_init__(self) -> None:
        check_bounds(self)

    def resolved(self, spacing_m: float) -> dict[str, float]:
        """The derived values for a cloud with the given point spacing."""
        s = max(spacing_m, 1e-4)
        slice_m = self.slice_m or min(max(6.0 * s, 0.02), 0.08)
        return {
            "slice_m": slice_m,
            "link_m": self.link_m or max(4.0 * s, 0.02),
            "base_band_m": self.base_band_m or 0.5 * slice_m,
            "min_radius_floor_m": 0.5 * s,
        }


@dataclass(frozen=True, kw_only=True)
class ReconstructParams:
    """Everything that decides a reconstruction.

    Parameters
    ----------
    method : {"qsm", "poisson", "bpa"}
    prepare : PrepareParams
        Input preparation (voxel size, outlier removal, ground removal, normals).
    qsm : QSMParams
        Cylinder fitting (qsm only).
    facets : int
        Facets per cylinder ring of the QSM mesh (speed/accuracy knob; the prism of n
        facets holds (n / 2π)·sin(2π / n) of the cylinder's volume: 16 → -2.6 %,
        32 → -0.64 %).
    poisson_depth : int
        Screened Poisson octree depth (speed/accuracy knob).
    poisson_trim_quantile : float
        Share of lowest-density Poisson vertices trimmed (hallucinated surface).
    bpa_radii_m : tuple of float, optional
        Ball radii; default from the point spacing.
    timeout_s : float
        Longest a pymeshlab step may run before it is stopped.
    separate_leaves : {"auto", "on", "off"}
        Label points wood or leaf (:mod:`treesim.reconstruct.leafwood`) and build the
        model from the wood only: ``on`` always, ``off`` never, ``auto`` when the
        classifier calls at least 16.5 % of the points leaf (``leaf_share``; measured
        0.00-0.14 on leaf-off trees, 0.20-0.63 on leaf-on ones). ``auto`` runs the
        classifier on every cloud; a leaf-off cloud pays its time (3-5 s per 100,000
        points on 2 cores) and is modelled as with ``off``.
    leaf_layer : bool
        With leaves separated, add leaf quads (label ``leaf``) in the leaf points' volume
        to the mesh (:mod:`treesim.models.leaves`), so the model can be scanned leaf-on.
    leaf_side_m : float
        Side of a modelled leaf quad (m); 5 cm gives 25 cm², a typical broadleaf leaf.

    Examples
    --------
    >>> import treesim as ts
    >>> ts.ReconstructParams(method="poisson").method
    'poisson'
    """

    method: Method = param("qsm", help="reconstruction method", choices=METHODS)
    separate_leaves: LeafMode = param(
        "auto",
        help="separate wood from leaves before reconstructing (auto: when leaves are found)",
        choices=LEAF_MODES,
    )
    leaf_layer: bool = param(True, help="model the separated leaves as leaf quads in the mesh")
    leaf_side_m: float = param(0.05, help="side of a modelled leaf quad", unit="m", gt=0, le=1)
    prepare: PrepareParams = param(help="input preparation", factory=PrepareParams)
    qsm: QSMParams = param(help="cylinder fitting (qsm only)", factory=QSMParams)
    facets: int = param(32, help="facets per cylinder ring of the QSM mesh", ge=3, le=512)
    poisson_depth: int = param(8, help="screened Poisson octree depth", flag="--depth", ge=4, le=16)
    poisson_trim_quantile: float = param(
        0.1, help="share of lowest-density Poisson vertices trimmed", ge=0, lt=1
    )
    bpa_radii_m: tuple[float, ...] | None = param(
        None,
        help="ball-pivoting radii",
        unit="m",
        none_means="from the point spacing",
        flag="--bpa-radius-m",
        gt=0,
    )
    timeout_s: float = param(
        600.0, help="stop a pymeshlab step after this long", unit="s", execution_only=True, gt=0
    )

    def __post_init__(self) -> None:
        check_bounds(self)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
