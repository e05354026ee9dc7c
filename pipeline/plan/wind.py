"""Wind against the plan's goals: how far each tree sways at an expected wind speed.

``treesim plan --wind-speed-m-s U`` keeps the planning as it is (the stations are chosen
for a still tree) and says, per tree, which goals that wind puts at risk. Each tree with
a cylinder table (a plot's procedural or QSM trees) gets the sway model of
:mod:`treesim.scan.wind` (:meth:`SwayModel.turbulent`, forcing seeded by the plan's
``sample_seed``, wind along +x, turbulence intensity 0.3, the tree's leaves loading
its branches), sampled over :data:`WINDOW_S` every :data:`STEP_S`:

* a part's *sway* is the 95th percentile over time of its displacement from rest (m);
  the parts are the table's cylinders, each at its mid point;
* ``crown_sway_p95_m``: the 95th percentile of the sway over the crown's parts (every
  cylinder not on the stem), weighted by their lateral area (coverage samples are
  area-uniform), and ``crown_sway_max_m`` its largest part;
* ``stem_sway_dbh_m``: the sway of the stem's axis 1.3 m along it from its base;
* ``surface_within_tolerance``: the area share of all cylinders whose sway is at most τ.

A goal is *at risk* when the wind can undo it: the coverage goal when the tree's
predicted coverage times ``surface_within_tolerance`` falls below ``goal_coverage``
(returns from parts swaying farther than τ no longer count; pessimistic: a part that
moves along its own surface stays within τ), the DBH arc goal when the stem sways more
than τ at 1.3 m (the band's points then fall farther than τ from the still stem). A
tree with no cylinder table (a plain mesh) is ``unknown``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..scan.wind import (
    Forcing,
    Structure,
    SwayModel,
    assign_vertices,
    cylinders_from,
    leaf_area_per_cylinder,
    mode_shape,
)

__all__ = ["STEP_S", "WINDOW_S", "sway_figures", "tree_structure", "wind_risk"]

#: Time the sway is sampled over (s) and the step (s).
WINDOW_S = 120.0
STEP_S = 0.2
#: Percentile of a part's displacement over time, and of the crown's parts.
PERCENTILE = 95.0
#: Turbulence intensity of the expected wind (the wind model's default).
TURBULENCE_INTENSITY = 0.3


def tree_structure(plot: Any, tree_id: int) -> Structure | None:
    """The sway model's :class:`~treesim.scan.wind.Structure` of a plot tree: its cylinder
    table placed in the plot, in a local frame at its first cylinder's start, with the
    leaf area of its leaf triangles on the cylinders they grow on; None for a tree with no
    table.

    Examples
    --------
    >>> st = tree_structure(plot, 1)  # doctest: +SKIP
    >>> st.nb > 1  # doctest: +SKIP
    True
    """
    table = plot.tree_table(tree_id)
    if table is None:
        return None
    cyl = cylinders_from(table)
    origin = cyl.start[0].copy()
    cyl = cyl.shifted(origin)
    leaves = [q for q in plot.tree_parts(tree_id) if q.label == "leaf" and len(q.faces)]
    area = np.zeros(cyl.n)
    for q in leaves:
        v = np.asarray(q.vertices, dtype=np.float64) - origin
        ones = np.ones(len(v), dtype=bool)
        owner = assign_vertices(cyl, v, ones, ones)
        area += leaf_area_per_cylinder(owner, v, np.asarray(q.faces), cyl.n)
    return Structure(cyl, area)


def _stem(st: Structure) -> int:
    roots = np.flatnonzero(st.parent_b < 0)
    return int(roots[np.argmax(st.length_b[roots])])


def _displacements(model: SwayModel, branch: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(times, points) displacement magnitude (m) of axis points over the window."""
    times = np.arange(int(round(WINDOW_S / STEP_S))) * STEP_S
    out = np.empty((len(times), len(branch)))
    for k in range(0, len(times), 50):
        tips = model.tips_many(times[k : k + 50])
        base = model.bases(tips)
        d = base[:, branch] + phi[None, :, None] * tips[:, branch]
        out[k : k + 50] = np.linalg.norm(d, axis=2)
    return out


def _weighted_percentile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """The smallest value whose cumulative weight reaches ``q`` percent of the total."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    k = int(np.searchsorted(cum, q / 100.0 * cum[-1]))
    return float(values[order][min(k, len(values) - 1)])


def sway_figures(model: SwayModel, tolerance_m: float) -> dict[str, float]:
    """A tree's sway figures under ``model`` (see the module's notes), in metres.

    Parameters
    ----------
    model : SwayModel
    tolerance_m : float
        The coverage tolerance τ (``surface_within_tolerance``).

    Returns
    -------
    dict
        ``stem_sway_dbh_m``, ``crown_sway_p95_m``, ``crown_sway_max_m``,
        ``surface_within_tolerance``, ``stem_frequency_hz``.

    Examples
    --------
    >>> model = SwayModel.turbulent(st, Forcing(5.0))  # doctest: +SKIP
    >>> sway_figures(model, 0.02)["stem_sway_dbh_m"]  # doctest: +SKIP
    0.0004
    """
    st = model.structure
    stem = _stem(st)
    xi_dbh = min(1.3 / max(float(st.length_b[stem]), 1e-9), 1.0)
    branch = np.append(st.branch_of, stem)
    phi = mode_shape(np.append(st.xi_mid, xi_dbh))
    sway = np.percentile(_displacements(model, branch, phi), PERCENTILE, axis=0)
    cyl = st.cyl
    area = np.pi * (cyl.radius_m + cyl.end_radius_m) * cyl.length_m
    part, crown = sway[:-1], st.branch_of != stem
    return {
        "stem_sway_dbh_m": float(sway[-1]),
        "crown_sway_p95_m": (
            _weighted_percentile(part[crown], area[crown], PERCENTILE) if crown.any() else 0.0
        ),
        "crown_sway_max_m": float(part[crown].max()) if crown.any() else 0.0,
        "surface_within_tolerance": float(area[part <= tolerance_m].sum() / area.sum()),
        "stem_frequency_hz": float(model.frequency_hz[stem]),
    }


def _tree_entry(
    plot: Any, tree_id: int, params: Any, forcing: Forcing, coverage: float
) -> dict[str, Any]:
    st = tree_structure(plot, tree_id)
    if st is None:
        return {"tree_id": tree_id, "status": "unknown", "goals_at_risk": None}
    figs = sway_figures(SwayModel.turbulent(st, forcing), params.tolerance_m)
    risk = []
    if params.goal_coverage > 0 and coverage * figs["surface_within_tolerance"] < (
        params.goal_coverage
    ):
        risk.append("coverage")
    if params.dbh_arc_deg > 0 and figs["stem_sway_dbh_m"] > params.tolerance_m:
        risk.append("dbh_arc")
    return {"tree_id": tree_id, "status": "modelled", **figs, "goals_at_risk": risk}


def _cm(values: list[float]) -> str:
    lo, hi = min(values) * 100.0, max(values) * 100.0
    return f"{lo:.2g} cm" if f"{lo:.2g}" == f"{hi:.2g}" else f"{lo:.2g}-{hi:.2g} cm"


def _summary(speed: float, params: Any, trees: list[dict[str, Any]]) -> list[str]:
    known = [t for t in trees if t["status"] == "modelled"]
    tau = f"τ {params.tolerance_m * 100:g} cm"
    lines = []
    for goal, name, key, what in (
        ("coverage", "the coverage goal", "crown_sway_p95_m", "their crowns sway"),
        ("dbh_arc", "the DBH arc goal", "stem_sway_dbh_m", "their stems sway"),
    ):
        hit = [t for t in known if goal in t["goals_at_risk"]]
        if hit:
            tail = " (95th percentile)" if goal == "coverage" else " at 1.3 m"
            lines.append(
                f"at {speed:g} m/s {name} ({tau}) is at risk on {len(hit)} of {len(trees)} "
                f"trees: {what} {_cm([t[key] for t in hit])}{tail}"
            )
    if known and not lines:
        lines.append(
            f"at {speed:g} m/s no goal is at risk on the {len(known)} modelled trees: "
            f"crowns sway up to {max(t['crown_sway_p95_m'] for t in known) * 100:.2g} cm "
            f"(95th percentile), stems {max(t['stem_sway_dbh_m'] for t in known) * 100:.2g} "
            f"cm at 1.3 m ({tau})"
        )
    unknown = len(trees) - len(known)
    if unknown:
        lines.append(
            f"at {speed:g} m/s the risk is unknown for {unknown} of {len(trees)} trees: "
            "no cylinder table (a plain mesh cannot sway in the wind model)"
        )
    return lines


def wind_risk(
    plot: Any, params: Any, tree_ids: list[int], coverage: np.ndarray
) -> dict[str, Any] | None:
    """The ``wind`` block of ``plan.json``: per tree its sway figures and the goals the
    expected wind (``params.wind_speed_m_s``) puts at risk; None at 0 m/s.

    Parameters
    ----------
    plot : treesim.plot.Plot
    params : PlanParams
    tree_ids : list of int
    coverage : (trees,) float
        The plan's predicted coverage of each tree (in ``tree_ids``' order).

    Returns
    -------
    dict or None
        ``wind_speed_m_s``, ``seed``, the model's settings, ``trees`` and ``summary``
        (lines for the printout and the warnings).

    Examples
    --------
    >>> params = PlanParams(wind_speed_m_s=5.0)  # doctest: +SKIP
    >>> block = wind_risk(plot, params, [1], np.array([0.9]))  # doctest: +SKIP
    >>> block["trees"][0]["goals_at_risk"]  # doctest: +SKIP
    ['coverage']
    """
    speed = float(params.wind_speed_m_s)
    if speed <= 0:
        return None
    forcing = Forcing(speed, 0.0, TURBULENCE_INTENSITY, int(params.sample_seed))
    trees = [
        _tree_entry(plot, int(tid), params, forcing, float(c))
        for tid, c in zip(tree_ids, coverage, strict=True)
    ]
    return {
        "wind_speed_m_s": speed,
        "direction_deg": 0.0,
        "turbulence_intensity": TURBULENCE_INTENSITY,
        "seed": int(params.sample_seed),
        "window_s": WINDOW_S,
        "step_s": STEP_S,
        "sway": "95th percentile over time of each part's displacement from rest "
        "(treesim.scan.wind, first-mode cantilevers); crown: 95th percentile over the "
        "crown's cylinders by lateral area; stem: its axis 1.3 m from the base",
        "risk_rule": "coverage: predicted coverage × surface share swaying <= τ below the "
        "goal; dbh_arc: stem sway at 1.3 m > τ. The stations are chosen for a still tree",
        "trees": trees,
        "summary": _summary(speed, params, trees),
    }
