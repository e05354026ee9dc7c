"""The scan planner's settings: goal, budget, candidates, samples (:class:`PlanParams`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..errors import InvalidParameterError
from ..params._fields import check_bounds, finite, param

__all__ = ["DEFAULT_INSTRUMENT", "PlanParams"]

#: The instrument a plan is made for unless one is named (CLI and service alike).
DEFAULT_INSTRUMENT = "riegl-vz400"


@dataclass(frozen=True, kw_only=True)
class PlanParams:
    """What ``treesim plan`` aims at, what it may spend and where it may stand.

    Goal (per tree; a tree meets it when every part of it that is on is met):

    * ``goal_coverage``: the fraction of the tree's visible surface samples (stem and
      crown, area-uniform; surface inside another closed part of the tree left out, as
      :func:`treesim.compare.compare` does) with a return within ``tolerance_m``;
    * ``dbh_arc_deg``: the stem band ``dbh_band_m`` (1.1-1.5 m above the stem base) seen
      over at least this arc around the stem axis. The band is cut into ``arc_bin_deg``
      sectors; a sector counts as seen when at least half its band samples are seen.

    Budget: at most ``max_stations`` stations and at most ``max_field_time_min`` of field
    time (set-up plus scan per station, :meth:`treesim.params.InstrumentPreset.
    station_time_s`); whichever is tighter.

    Wind: ``wind_speed_m_s`` > 0 says which goals that wind's sway puts at risk on each
    tree (:mod:`treesim.plan.wind`); the stations are still chosen for a still tree.

    Examples
    --------
    >>> import treesim as ts
    >>> params = ts.PlanParams(goal_coverage=0.9, dbh_arc_deg=270.0, max_stations=6)
    >>> params.goal_coverage, params.max_stations
    (0.9, 6)
    """

    goal_coverage: float = param(
        0.8,
        help="goal: fraction of each tree's visible surface seen within the tolerance "
        "(0: no coverage goal)",
        ge=0,
        le=1,
    )
    goal_margin: float = param(
        0.05,
        help="the stations are chosen to reach goal_coverage plus this margin where a "
        "tree can (the visibility model's coverage errs by up to ~0.05 per tree on "
        "average, tests/plan; verification and the verdict judge the goal itself)",
        ge=0,
        le=0.5,
    )
    tolerance_m: float = param(
        0.02,
        help="coverage tolerance τ: a sample is seen with a return this close",
        unit="m",
        gt=0,
        le=1,
    )
    dbh_arc_deg: float = param(
        0.0,
        help="goal: arc of the 1.1-1.5 m stem band seen around the stem axis (0: no DBH goal)",
        unit="deg",
        ge=0,
        le=360,
    )
    dbh_band_m: tuple[float, float] = param(
        (1.1, 1.5), help="stem band for DBH, LOW,HIGH above the stem base", unit="m"
    )
    arc_bin_deg: float = param(
        10.0,
        help="sector width of the DBH arc (a sector is seen when half its samples are)",
        unit="deg",
        gt=0,
        le=90,
    )
    max_stations: int | None = param(
        20, help="budget: most stations", none_means="no limit", gt=0, le=10_000
    )
    max_field_time_min: float | None = param(
        None,
        help="budget: most field time (set-up + scan per station)",
        unit="min",
        none_means="no limit",
        gt=0,
    )
    candidate_spacing_m: float = param(
        2.0, help="spacing of the candidate station grid over the plot", unit="m", gt=0
    )
    height_m: float = param(1.5, help="scanner height above the terrain", unit="m", gt=0, le=10)
    clearance_m: float = param(
        0.5, help="least distance from a candidate to any tree's surface", unit="m", ge=0
    )
    samples_per_tree: int = param(
        1500, help="surface samples per tree (stem and crown)", ge=50, le=1_000_000
    )
    band_samples: int = param(
        360, help="extra samples on each tree's DBH stem band", ge=36, le=100_000
    )
    local_search: bool = param(
        True, help="after the greedy choice, swap stations to drop one or improve the plan"
    )
    ring_distance_m: float | None = param(
        None,
        help="baselines: distance of the ring and cross stations from the plot centre",
        unit="m",
        none_means="half the plot radius (one tree: the station rule)",
        gt=0,
    )
    grid_spacings_m: tuple[float, ...] | None = param(
        None,
        help="baselines: square grid spacings",
        unit="m",
        none_means="1/3, 1/2 and 2/3 of the plot radius, to 0.1 m",
        flag="--grid-spacing-m",
        gt=0,
    )
    verify: bool = param(
        True, help="scan the plan (and the best baseline) at full resolution and measure it"
    )
    wind_speed_m_s: float = param(
        0.0,
        help="expected wind speed: say which goals its sway puts at risk on each tree with "
        "a cylinder table (the stations are still chosen for a still tree; 0: no wind)",
        unit="m/s",
        ge=0,
        le=60,
    )
    sample_seed: int = param(0, help="seed of the surface samples and of the wind", ge=0)
    threads: int = param(0, help="Open3D threads (0: all cores)", ge=0, execution_only=True)

    def __post_init__(self) -> None:
        check_bounds(self)
        lo, hi = (finite("dbh_band_m", v) for v in self.dbh_band_m)
        if not 0 <= lo < hi:
            raise InvalidParameterError(
                f"dbh_band_m must satisfy 0 <= LOW < HIGH, got ({lo}, {hi})"
            )
        if self.goal_coverage == 0 and self.dbh_arc_deg == 0:
            raise InvalidParameterError(
                "the plan needs a goal: give goal_coverage > 0 or dbh_arc_deg > 0"
            )
        if self.grid_spacings_m is not None:
            object.__setattr__(
                self, "grid_spacings_m", tuple(float(v) for v in self.grid_spacings_m)
            )

    def with_(self, **changes: object) -> PlanParams:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)  # type: ignore[arg-type]

    def goal_dict(self) -> dict[str, object]:
        """The goal, for ``plan.json``."""
        return {
            "coverage": self.goal_coverage,
            "margin": self.goal_margin,
            "tolerance_m": self.tolerance_m,
            "dbh_arc_deg": self.dbh_arc_deg,
            "dbh_band_m": list(self.dbh_band_m),
            "arc_bin_deg": self.arc_bin_deg,
            "sector_seen_when": "at least half of the sector's band samples are seen",
        }
