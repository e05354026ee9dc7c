"""``validate``: a simulated plot scan set beside the field scan (as ``treesim validate``)."""

from __future__ import annotations

import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from treesim.params import merge

from .base import Input, Process, Progress, job_schema

if TYPE_CHECKING:  # the plot package is imported in jobs, never at the API's start-up
    from treesim.plot.validate import ValidateParams


def _params() -> type[ValidateParams]:
    from treesim.plot.validate import ValidateParams

    return ValidateParams


def _parse_validate(parameters: Mapping[str, Any]) -> ValidateParams:
    """The request's settings over :class:`ValidateParams`' defaults, checked by the
    model (its ranges are the schema's)."""
    return merge(_params()(), dict(parameters))


def _execute_validate(
    inputs: Mapping[str, Path],
    job: ValidateParams,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.io import read_cloud
    from treesim.plot.validate import validate_scans
    from treesim.plot.validate_report import write_validation

    from ..plots import read_unpacked_plot, unpack_plot

    progress(0.0, "reading")
    real = read_cloud(inputs["real"])
    sim = read_cloud(inputs["simulated"])
    plot = None
    work = out / ".plot"
    try:
        if "plot" in inputs:
            plot_file = unpack_plot(inputs["plot"], work, label="the twin archive")
            plot = read_unpacked_plot(plot_file, work, "the twin archive")
        progress(0.2, "measuring")
        result = validate_scans(real, sim, job, plot=plot)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    progress(0.9, "writing the report")
    write_validation(result, out, names=("field scan", "simulated scan"))
    return result.to_dict()


PROCESS = Process(
    id="validate",
    title="Check a simulated plot scan against the field scan",
    description="Set the simulated scan beside the field scan, per station and per twin "
    "tree: point density by height and by range, each tree's coverage (whole, stem and "
    "crown) and the occlusion profile, distances both ways, and a one-line verdict (as "
    "treesim validate).",
    inputs=(
        Input("real", ("cloud",), "the field scan (an E57 with its scans' poses, or LAS/LAZ)"),
        Input("simulated", ("cloud",), "the simulated scan (a plot-scan job's plot_scan.laz)"),
        Input(
            "plot",
            ("plot",),
            "the twin: a zip archive of its plot.toml and the files it names (a "
            "plot-from-cloud job's twin.zip); without it no coverage figures",
            required=False,
        ),
    ),
    outputs=(
        ("validation.json", "every figure, per station and per tree, and the verdict"),
        ("validation.html", "the report with its figures"),
        ("density_by_height.png", "points per height bin, per station"),
        ("distances.png", "distances both ways"),
    ),
    extra_schema=dict,
    base_schema=lambda: job_schema(_params()),
    parse=_parse_validate,
    execute=_execute_validate,
)
