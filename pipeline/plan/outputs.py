"""What a plan writes: ``plan.json``, ``stations.csv``, ``map.png``, ``curve.png``.

Figures use matplotlib's object API on the Agg canvas (no pyplot, no global backend), as
:mod:`treesim.report.figures` does.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np

from .._version import software_versions
from ..atomic import atomic_path, write_text
from ..jsonio import write_json
from .planner import PlanResult

__all__ = ["PLAN_FILES", "write_plan"]

#: The files :func:`write_plan` writes in its folder.
PLAN_FILES = ("plan.json", "stations.csv", "map.png", "curve.png")

_CSV_COLUMNS = (
    "order",
    "x_m",
    "y_m",
    "z_m",
    "heading_deg",
    "field_time_min",
    "cumulative_field_time_min",
    "predicted_gain",
)


def stations_csv(result: PlanResult) -> str:
    """``stations.csv``: one row per chosen station, in order."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_CSV_COLUMNS)
    for row in result.stations_table():
        w.writerow(
            [row["order"]]
            + [f"{row[k]:.4f}" for k in ("x_m", "y_m", "z_m")]
            + [f"{row['heading_deg']:g}"]
            + [f"{row[k]:.3f}" for k in ("field_time_min", "cumulative_field_time_min")]
            + [f"{row['predicted_gain']:.6g}"]
        )
    return buf.getvalue()


def _figure(w: float, h: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h))
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png", metadata={"Software": None})
    return path


def map_png(result: PlanResult, path: Path) -> Path:
    """The plot from above: trees coloured by predicted coverage (verified when there is
    a verification), candidates, the plan's stations numbered, the best baseline's."""
    from matplotlib import colormaps
    from matplotlib.patches import Circle

    fig = _figure(7.0, 6.2)
    ax = fig.add_subplot(1, 1, 1)
    cx, cy = result.plot_info["centre_xy"]
    ax.add_patch(Circle((cx, cy), result.plot_info["radius_m"], fill=False, ls="--", color="0.5"))
    c = result.candidates
    ax.scatter(c[:, 0], c[:, 1], s=6, c="0.75", marker="s", label="candidates", zorder=1)
    ver = result.verification
    cov = np.array(
        [
            ver["trees"][t.tree_id]["coverage"] if ver else result.predicted["coverage"][i]
            for i, t in enumerate(result.targets)
        ]
    )
    xy = np.array([t.base_xyz[:2] for t in result.targets])
    sc = ax.scatter(
        xy[:, 0],
        xy[:, 1],
        c=cov,
        cmap=colormaps["viridis"],
        vmin=0,
        vmax=1,
        s=70,
        edgecolors="k",
        linewidths=0.5,
        zorder=3,
    )
    out = ~result.reachable  # trees no candidate can bring to the goal: ringed in red
    if out.any():
        ax.scatter(xy[out, 0], xy[out, 1], s=160, facecolors="none", edgecolors="red", zorder=4)
    fig.colorbar(sc, ax=ax, label="coverage (" + ("verified" if ver else "predicted") + ")")
    best = result.comparison.get("best_baseline")
    lay = next((x for x in result.baseline_layouts if x.name == best), None)
    if lay is not None:
        ax.scatter(
            lay.positions[:, 0],
            lay.positions[:, 1],
            marker="^",
            s=60,
            c="tab:orange",
            edgecolors="k",
            label=f"baseline {best}",
            zorder=5,
        )
    st = np.array([result.candidates[j] for j in result.selection.chosen]).reshape(-1, 3)
    ax.scatter(
        st[:, 0], st[:, 1], marker="*", s=180, c="tab:red", edgecolors="k", label="plan", zorder=6
    )
    for k, (x, y, _) in enumerate(st):
        ax.annotate(
            str(k + 1),
            (x, y),
            xytext=(5, 5),
            textcoords="offset points",
            fontsize=10,
            fontweight="bold",
            zorder=7,
        )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"{len(st)} stations, {len(result.targets)} trees; goal "
        + ("met" if result.goal_met else "not met")
        + " (predicted)"
        + (f"; verified {ver['trees_meeting_goal']}/{len(result.targets)} trees" if ver else "")
    )
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    return _save(fig, path)


def curve_png(result: PlanResult, path: Path) -> Path:
    """Mean coverage (and trees meeting the goal) against stations, plan and baselines;
    field time on the top axis."""
    fig = _figure(7.0, 4.5)
    ax = fig.add_subplot(1, 1, 1)
    ks = [c["stations"] for c in result.curve]
    ax.plot(
        ks,
        [c["mean_coverage"] for c in result.curve],
        "o-",
        color="tab:red",
        label="plan: mean coverage",
    )
    n = max(1, len(result.targets))
    ax.plot(
        ks,
        [c["trees_meeting_goal"] / n for c in result.curve],
        "s--",
        color="tab:red",
        alpha=0.6,
        label="plan: share of trees meeting the goal",
    )
    for i, b in enumerate(result.baselines):
        ax.scatter([b["n_stations"]], [b["mean_coverage"]], marker="^", s=50, zorder=3)
        ax.annotate(
            b["name"],
            (b["n_stations"], b["mean_coverage"]),
            xytext=(4, -10 - 9 * (i % 3)),
            textcoords="offset points",
            fontsize=7,
            rotation=0,
        )
    if result.params.goal_coverage > 0:
        ax.axhline(result.params.goal_coverage, color="0.5", ls=":", label="coverage goal")
    ax.set_xlabel("stations")
    ax.set_ylabel("coverage / share")
    ax.set_ylim(0, 1.05)
    ax.set_xscale("log") if max(
        [*ks, *(b["n_stations"] for b in result.baselines), 1]
    ) > 30 else None
    per = result.station_time_s / 60.0
    top = ax.secondary_xaxis("top", functions=(lambda k: k * per, lambda t: t / per))
    top.set_xlabel("field time (min)")
    ax.legend(loc="lower right", fontsize=8)
    return _save(fig, path)


def write_plan(
    result: PlanResult,
    outdir: str | Path,
    *,
    inputs: dict[str, Any] | None = None,
    figures: bool = True,
) -> dict[str, Path]:
    """Write the plan's files (:data:`PLAN_FILES`) into ``outdir`` (created).

    Parameters
    ----------
    result : PlanResult
        What :func:`treesim.plan.plan_scans` returned.
    outdir : str or Path
        The folder to write into.
    inputs : dict, optional
        What the plan was made from (files, options), recorded in ``plan.json``.
    figures : bool
        Draw ``map.png`` and ``curve.png`` too.

    Returns
    -------
    dict of str to Path
        Each file written, by its name in :data:`PLAN_FILES`.

    Examples
    --------
    >>> import treesim as ts
    >>> result = ts.plan_scans(plot, spec=spec, instrument=vz400)  # doctest: +SKIP
    >>> sorted(ts.write_plan(result, "plan/"))  # doctest: +SKIP
    """
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    data = result.to_dict()
    data["inputs"] = inputs or {}
    data["software"] = software_versions()
    paths = {"plan.json": write_json(out / "plan.json", data)}
    paths["stations.csv"] = write_text(out / "stations.csv", stations_csv(result))
    if figures:
        paths["map.png"] = map_png(result, out / "map.png")
        paths["curve.png"] = curve_png(result, out / "curve.png")
    return paths
