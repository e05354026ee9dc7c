"""Verification: scan a plan at full resolution and measure each tree for real.

:func:`verify_plan` scans the plot from the stations with the scanner's own settings (the
instrument at the chosen resolution: every pulse of the field of view that can reach the
scene, not the planner's rays to samples), splits the cloud by its ``tree_id`` field and
measures per tree:

* ``coverage``: :func:`treesim.compare.compare` of the tree's points against the tree's
  own mesh at τ (its surface samples, hidden surface dropped: the same definition as the
  goal, with compare's own denser samples);
* ``coverage_samples``: the planner's own coverage samples with a point within τ (the
  predicted figure's sample set, for a like-for-like check of the visibility model);
* ``arc_deg``: the planner's band samples with a point within τ on their own side of the
  stem axis, by the goal's sector rule.

The scan is the one place this module touches the plot's geometry (:func:`_scan_plot`,
through :func:`treesim.plot.scan.scan_plot`, which loads per station only the trees the
station can record).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..cloud import Cloud
from ..compare import compare
from ..errors import EmptyInputError
from ..geometry import kdtree
from ..params import MIN_CLOUD_POINTS, CompareParams, ScannerSpec
from ..scan import Station
from .cover import Objective
from .samples import SampleSet, TreeTarget

__all__ = ["verify_plan"]


def _scan_plot(
    plot: Any,
    stations: Sequence[Station],
    spec: ScannerSpec,
    *,
    nthreads: int,
    progress: Any,
    execution: dict[str, Any] | None = None,
) -> Cloud:
    """The plot scanned from ``stations`` (the trees each station can record, and the
    terrain: :func:`treesim.plot.scan.scan_plot`), each station a task on the executor
    of ``execution`` (``executor``, ``workers``, ``scheduler``; default inline)."""
    from ..params import ScanParams
    from ..plot.scan import scan_plot

    params = ScanParams(scanner=spec)
    return scan_plot(
        plot, list(stations), params, threads=nthreads, progress=progress, **(execution or {})
    ).cloud


def verify_plan(
    plot: Any,
    stations: Sequence[Station],
    spec: ScannerSpec,
    targets: Sequence[TreeTarget],
    samples: SampleSet,
    objective: Objective,
    *,
    tolerance_m: float,
    seed: int = 0,
    nthreads: int = 0,
    progress: Any = None,
    executor: str = "inline",
    workers: int | None = None,
    scheduler: str | None = None,
    cache_dir: str | None = None,
    sectors: int = 1,
) -> dict[str, Any]:
    """Scan ``stations`` at full resolution and measure every tree (module notes).

    ``executor`` (``inline``, ``local``, ``dask``), ``workers``, ``scheduler`` and
    ``cache_dir`` say where the stations' scans run, as for ``batch`` (each station a
    task that reads only the trees it can record; the same cloud, bit for bit, as
    inline; see :func:`treesim.plot.scan.scan_plot`), ``sectors`` in how many azimuth
    sectors each station is scanned.

    Returns
    -------
    dict
        ``trees``: per tree id, ``points``, ``coverage``, ``coverage_samples``,
        ``arc_deg``, ``goal_met``; ``points``, ``all_goals_met``, ``timings_s``.

    Examples
    --------
    >>> from treesim.plan.verify import verify_plan
    >>> figures = verify_plan(  # doctest: +SKIP
    ...     plot, stations, spec, targets, samples, objective, tolerance_m=0.01,
    ...     executor="dask", workers=2,
    ... )
    >>> figures["trees_meeting_goal"]  # doctest: +SKIP
    """
    t0 = time.perf_counter()
    execution = {
        "executor": executor,
        "workers": workers,
        "scheduler": scheduler,
        "cache_dir": cache_dir,
        "sectors": sectors,
    }
    cloud = _scan_plot(
        plot, stations, spec, nthreads=nthreads, progress=progress, execution=execution
    )
    t_scan = time.perf_counter() - t0
    tid = np.asarray(cloud.fields.get("tree_id", np.zeros(len(cloud))), np.int64)
    t1 = time.perf_counter()
    # which samples have a real point within τ: a k-d tree per tree's points
    seen = np.zeros(len(samples), np.uint8)
    out: dict[int, dict[str, Any]] = {}
    for i, t in enumerate(targets):
        sel = np.flatnonzero(tid == t.tree_id)
        entry: dict[str, Any] = {"points": int(len(sel))}
        sl = samples.tree_slice(i)
        if len(sel):
            centre = samples.points[sl].mean(axis=0)
            pts = cloud.points[sel]
            tree = kdtree(pts - centre)
            d, j = tree.query(
                samples.points[sl] - centre, k=1, distance_upper_bound=tolerance_m * (1 + 1e-12)
            )
            ok = d <= tolerance_m
            # a band sample counts only with a point on its own side of the stem axis
            band = samples.band[sl]
            if band.any():
                axis = samples.stem_xy[i]
                js = np.where(ok, j, 0)
                radial_s = samples.points[sl][:, :2] - axis
                radial_p = pts[js, :2] - axis
                same = np.einsum("ij,ij->i", radial_s, radial_p) > 0
                ok &= ~band | same
            seen[sl] = ok.astype(np.uint8)
        if len(sel) >= MIN_CLOUD_POINTS:
            v, f, _ = t.mesh()
            try:
                # the points alone: coverage reads nothing else, and a cloud's station
                # field would have compare split it station by station (a k-d tree and
                # a query per station) for figures nobody reads here
                c = compare(
                    Cloud(cloud.points[sel]),
                    (v, f),
                    params=CompareParams(tolerance_m=tolerance_m, seed=seed, nthreads=nthreads),
                )
                entry["coverage"] = c.coverage
                entry["compare_samples"] = int(c.reference_info.get("samples", 0))
            except EmptyInputError as exc:
                entry["coverage"] = 0.0
                entry["why"] = str(exc)
        else:
            entry["coverage"] = 0.0
            entry["why"] = f"{len(sel)} points: too few to compare"
        out[t.tree_id] = entry
    # a measured sample is covered or not: Λ = inf or 0
    figs = objective.figures(np.where(seen > 0, np.inf, 0.0)[None])
    met = objective.met(figs)[0]
    for i, t in enumerate(targets):
        e = out[t.tree_id]
        e["coverage_samples"] = float(figs["coverage"][0, i])
        e["arc_deg"] = float(figs["arc_deg"][0, i])
        g = float(objective.g_cov[i])
        cov_ok = g == 0 or e["coverage"] >= g - 1e-12
        arc_ok = objective.g_arc == 0 or e["arc_deg"] >= objective.g_arc - 1e-9
        e["goal_met"] = bool(cov_ok and arc_ok)
        e["goal_met_samples"] = bool(met[i])
    return {
        "stations": len(stations),
        "points": int(len(cloud)),
        "resolution_deg": [spec.horizontal_resolution_deg, spec.vertical_resolution_deg],
        "trees": out,
        "trees_meeting_goal": int(sum(e["goal_met"] for e in out.values())),
        "timings_s": {"scan": t_scan, "measure": time.perf_counter() - t1},
    }
