"""Comparison and report parameters."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..errors import InvalidParameterError
from ._fields import check_bounds, param

__all__ = ["HIDDEN_SURFACE", "REPORT_LEVELS", "CompareParams", "ReportLevel", "ReportParams"]

ReportLevel = Literal["auto", "none", "summary", "full"]
#: Which reports a run draws (:attr:`ReportParams.level`).
REPORT_LEVELS: tuple[str, ...] = ("auto", "none", "summary", "full")

#: What a comparison does with mesh surface inside another closed part of the same mesh.
HIDDEN_SURFACE = ("drop", "keep")


@dataclass(frozen=True, kw_only=True)
class CompareParams:
    """How a comparison is made.

    Parameters
    ----------
    tolerance_m : float, optional
        Coverage tolerance τ (m); default ``3 × point_spacing_m`` of the compared cloud
        (``treesim compare``); a run uses one τ for both its comparisons, by default 3 ×
        the field cloud's spacing (:func:`treesim.run.run_tolerance`).
    sample_spacing_m : float, optional
        Mesh references: spacing of the surface samples for completeness (m), i.e. one
        sample per ``sample_spacing_m²``; default ``point_spacing_m``.
    seed : int
        Seed of the surface sampling (and of the spacing estimate's subsample).
    min_samples, max_samples : int
        Bounds on the number of surface samples (the spacing is adjusted to stay within
        them; the effective spacing is reported).
    spacing_subsample : int
        Points used to estimate the cloud's median spacing (all if fewer).
    hidden_surface : {"drop", "keep"}
        Mesh references: surface samples inside another closed part of the same mesh
        (buried end caps, branch bases inside their parents), which no scanner outside
        can see, are left out of completeness and coverage (``drop``, and their area is
        reported) or kept (``keep``).
    nthreads : int
        Threads for Open3D and the k-d tree queries (0: all cores).

    Examples
    --------
    >>> import treesim as ts
    >>> ts.CompareParams(tolerance_m=0.01).tolerance_m
    0.01
    """

    tolerance_m: float | None = param(
        None,
        help="coverage tolerance τ",
        unit="m",
        none_means="3 × the point spacing (a run: the field cloud's, one τ for both)",
        gt=0,
    )
    sample_spacing_m: float | None = param(
        None,
        help="spacing of the mesh surface samples",
        unit="m",
        none_means="the cloud's point spacing",
        gt=0,
    )
    seed: int = param(0, help="seed of the surface sampling", ge=0)
    min_samples: int = param(10_000, help="fewest mesh surface samples", ge=1)
    max_samples: int = param(
        2_000_000, help="most mesh surface samples (the spacing grows to fit)", ge=1
    )
    spacing_subsample: int = param(
        50_000, help="points used to estimate the cloud's median spacing", ge=2
    )
    hidden_surface: str = param(
        "drop",
        help="mesh surface inside another closed part of the same mesh (buried caps, branch "
        "bases inside their parents): drop it from the samples, or keep it",
        choices=HIDDEN_SURFACE,
    )
    nthreads: int = param(
        0,
        help="threads for Open3D and the k-d tree queries (0: all cores)",
        execution_only=True,
        flag="--threads",
        ge=0,
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.max_samples < self.min_samples:
            raise InvalidParameterError(
                f"need 1 <= min_samples <= max_samples, got {self.min_samples}, {self.max_samples}"
            )


@dataclass(frozen=True, kw_only=True)
class ReportParams:
    """How a report is drawn.

    Parameters
    ----------
    max_view_points : int
        Points per data set in the HTML page's 3D view (random subsample, seeded).
    max_plot_points : int
        Points per PNG view (random subsample, seeded).
    seed : int
        Seed of the subsamples.
    dpi : int
        Resolution of the PNG plots.
    plots : bool
        Draw the PNG plots. Off, the report keeps its figures, text and 3D view and says
        where each plot would be: for sweeps and tests, where drawing is most of a run's
        time and only the figures count.
    profile_bin_m : float, optional
        Height of the occlusion profile's slices (m); default a round height giving about
        20 slices (:func:`treesim.report.profile.auto_bin_m`).
    level : {"auto", "full", "summary", "none"}
        Which reports a run draws (``--report``): ``full`` every page and PNG plot;
        ``summary`` every page with its figures, tables and 3D view but no PNG plot (as
        ``plots = false``); ``none`` no comparison report, only ``run.json`` and a run
        page of tables. ``auto``: ``full`` for one run (``treesim run``, ``demo``),
        ``summary`` for each tree of a batch and each point of a sweep (drawing was most
        of their time). No level changes a figure of the run.
    """

    max_view_points: int = param(40_000, help="points per data set in the 3D view", ge=1)
    max_plot_points: int = param(120_000, help="points per PNG view", ge=1)
    seed: int = param(0, help="seed of the subsamples", ge=0)
    dpi: int = param(130, help="resolution of the PNG plots", ge=1)
    plots: bool = param(True, help="draw the PNG plots (off: figures, text and 3D view only)")
    profile_bin_m: float | None = param(
        None,
        help="height of the occlusion profile's slices",
        unit="m",
        none_means="a round height giving about 20 slices",
        gt=0,
    )
    level: ReportLevel = param(
        "auto",
        help="which reports to draw: full (every page and plot), summary (pages, figures "
        "and 3D views, no PNG plots), none (run.json and a page of tables); auto: full "
        "for one run, summary for each tree of a batch or point of a sweep",
        choices=REPORT_LEVELS,
        flag="--report-level",  # run, batch and sweep name it --report (compare's is a switch)
    )

    def __post_init__(self) -> None:
        check_bounds(self)

    def resolved(self, auto: str = "full") -> str:
        """The level drawn: :attr:`level`, with ``auto`` read as ``auto`` (``"full"``
        for one run, ``"summary"`` for a batch's tree or a sweep's point) and ``plots =
        false`` lowering ``full`` to ``summary``.

        Examples
        --------
        >>> ReportParams(level="auto").resolved("summary")
        'summary'
        >>> ReportParams(plots=False).resolved()
        'summary'
        """
        level = auto if self.level == "auto" else self.level
        return "summary" if level == "full" and not self.plots else level
