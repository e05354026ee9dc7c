"""The run page: ``report.html`` of one ``treesim run``, presenting both comparisons."""

from __future__ import annotations

import html
from typing import Any

from . import assets
from .data import ReportData
from .html import comparison_sets, viewer_section, viewer_sets_payload
from .text import cell, length, lod_reasons, percent, trivially_exact

__all__ = ["PAGE_CSS", "STAGES", "run_page", "run_viewer_payload"]

#: Stages timed in ``run.json``'s ``timings_s`` (plus ``total``), in order.
STAGES = ("read", "reconstruct", "scan", "compare_mesh", "compare_field", "report")


def _len(v: Any) -> str:
    return length(v) if isinstance(v, (int, float)) else "–"


def _pct(v: Any) -> str:
    return percent(v) if isinstance(v, (int, float)) else "–"


PAGE_CSS = """
body{font:15px/1.45 system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222;padding:0 1em}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.6em 0}td,th{padding:.25em .8em;border-bottom:1px solid #eee;
text-align:right}th:first-child,td:first-child{text-align:left}.muted{color:#777}
.cards{display:flex;gap:1.5em;flex-wrap:wrap}.card{flex:1 1 420px}img{max-width:100%}
a{color:#0a58ca}code{background:#f4f4f4;padding:0 .2em}.lead{color:#777}
#page-errors{background:#fde8e8;color:#8a1c1c;padding:.6em 1em}
"""


def run_viewer_payload(
    vs_mesh: ReportData, vs_field: ReportData, *, max_points: int = 40_000, seed: int = 0
) -> dict[str, Any]:
    """The run page's 3D view: the simulated cloud coloured by its distance to the field
    cloud, the field cloud by its distance to the simulated one, and the mesh samples by
    their distance to the simulated cloud (where the scan did not see the model)."""
    (_, _, sim, d_sim, v_sim, _, _), (_, _, fld, d_fld, v_fld, _, tau) = comparison_sets(vs_field)
    mesh_set = comparison_sets(vs_mesh)[1]
    sets = [
        (
            "sim_vs_field",
            "Simulated → field",
            sim,
            d_sim,
            v_sim,
            "distance to the field cloud",
            None,
        ),
        (
            "field_vs_sim",
            "Field → simulated",
            fld,
            d_fld,
            v_fld,
            "distance to the simulated cloud",
            tau,
        ),
        (
            "mesh_vs_sim",
            "Mesh → simulated",
            *mesh_set[2:5],
            "distance to the simulated cloud",
            mesh_set[6],
        ),
    ]
    return viewer_sets_payload(sets, max_points=max_points, seed=seed)


#: Rows of the reconstruction-vs-reference table: (key, label, unit, scale).
_REFERENCE_ROWS = (
    ("dbh_m", "DBH", " cm", 100.0),
    ("height_m", "height", " m", 1.0),
    ("volume_total_m3", "wood volume", " L", 1000.0),
    ("volume_stem_m3", "stem volume", " L", 1000.0),
    ("volume_branch_m3", "branch volume", " L", 1000.0),
    ("n_cylinders", "cylinders", "", 1.0),
)


def reference_qsm_section(s: dict[str, Any]) -> str:
    """The reconstruction beside a reference QSM (``run.json``'s ``reference_qsm``):
    DBH, height, volumes; empty when the run had none."""
    ref = s.get("reference_qsm")
    if not ref:
        return ""
    rec = s["reconstruction"]
    rows = []
    for key, label, unit, scale in _REFERENCE_ROWS:
        d, r = ref["difference"].get(key), ref["relative"].get(key)
        if d is None:
            delta = "–"
        elif key == "n_cylinders":
            delta = f"{int(d):+,}"
        else:
            delta = f"{d * scale:+.3g}{unit}"
        if r is not None:
            delta += f" ({r * 100:+.1f} %)"
        rows.append(
            f"<tr><td>{label}</td><td>{cell(rec.get(key), unit, scale)}</td>"
            f"<td>{cell(ref['figures'].get(key), unit, scale)}</td><td>{delta}</td></tr>"
        )
    return (
        '<h2 id="reference-qsm">Reconstruction vs the reference QSM</h2>'
        f'<p class="muted">reference: <code>{html.escape(str(ref["path"]))}</code> '
        "(a QSM of the same tree made elsewhere); difference = reconstruction − reference</p>"
        "<table><tr><th>figure</th><th>reconstruction</th><th>reference QSM</th>"
        "<th>difference</th></tr>" + "".join(rows) + "</table>"
    )


def _per_m2(v: Any) -> str:
    return f"{v:,.0f}" if isinstance(v, (int, float)) else "–"


def clouds_section(s: dict[str, Any]) -> str:
    """The field and simulated clouds side by side: one table, the same views."""
    c = s.get("clouds")
    if not c:
        return ""
    f, m = c["field"], c["simulated"]

    def ratio(a: Any, b: Any) -> str:
        ok = isinstance(a, (int, float)) and isinstance(b, (int, float)) and b
        return f"{a / b:.3g} ×" if ok else "–"

    rows = [
        ("points", cell(f["points"]), cell(m["points"]), ratio(m["points"], f["points"])),
        (
            "median point spacing",
            _len(f["point_spacing_m"]),
            _len(m["point_spacing_m"]),
            ratio(m["point_spacing_m"], f["point_spacing_m"]),
        ),
        (
            "points per m² of the mesh surface",
            _per_m2(f["points_per_m2"]),
            _per_m2(m["points_per_m2"]),
            ratio(m["points_per_m2"], f["points_per_m2"]),
        ),
        ("height", cell(f["height_m"], " m"), cell(m["height_m"], " m"), "–"),
    ]
    body = "".join(
        f"<tr><td>{a}</td><td>{b}</td><td>{d}</td><td>{r}</td></tr>" for a, b, d, r in rows
    )
    area = c.get("mesh_area_m2")
    return (
        '<h2 id="clouds">Field and simulated clouds</h2>'
        '<p class="muted">Both clouds in the same views on the same axes; densities over the '
        f"reconstructed mesh's surface ({cell(area, ' m²')})."
        + (
            " The occlusion profile of "
            '<a href="vs_field/report.html#occlusion">the comparison with the field cloud</a> '
            "sets their densities side by side by height."
            if report_level(s) != "none"
            else ""
        )
        + "</p>"
        "<table><tr><th></th><th>field cloud</th><th>simulated cloud</th>"
        f"<th>simulated / field</th></tr>{body}</table>"
        + (
            f'<img src="{html.escape(c["figure"])}" alt="field and simulated clouds, same views">'
            if c.get("figure")
            else f'<p class="note">views not drawn ({_level_note(s)})</p>'
        )
    )


def plausibility_note(rec: dict[str, Any]) -> str:
    """The reconstruction's plausibility warnings (``tree.json``'s ``warnings``), one item
    each, in a note; a muted line when there are none, nothing for older runs."""
    if "warnings" not in rec:
        return ""
    warns = rec.get("warnings") or []
    if not warns:
        return '<p class="muted">plausibility checks: no warning</p>'
    items = "".join(f"<li>{html.escape(str(w.get('message', w)))}</li>" for w in warns)
    return (
        f'<div class="note" id="plausibility"><b>Implausible for a real tree '
        f"({len(warns)} warning{'s' if len(warns) > 1 else ''})</b><ul>{items}</ul></div>"
    )


def _tree_rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    """The reconstruction's figures."""
    esc = html.escape
    rec = s["reconstruction"]
    return [
        ("method", esc(str(s["parameters"]["reconstruct"]["method"]))),
        ("DBH", cell(rec.get("dbh_m"), " cm", 100)),
        ("height", cell(rec.get("height_m"), " m")),
        ("wood volume", cell(rec.get("volume_total_m3"), " L", 1000)),
        (
            "stem / branch volume",
            f"{cell(rec.get('volume_stem_m3'), ' L', 1000)} / "
            f"{cell(rec.get('volume_branch_m3'), ' L', 1000)}",
        ),
        ("stem form factor", cell((rec.get("plausibility") or {}).get("stem_form_factor"))),
        ("cylinders", cell(rec.get("n_cylinders"))),
        ("triangles", cell(rec.get("n_triangles"))),
        ("watertight", cell(rec.get("watertight"))),
        (
            "field points (used)",
            f"{cell(rec.get('points_input'))} ({cell(rec.get('points_used'))})",
        ),
    ]


def _scan_rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    """The virtual scan's design and yield, and the coverage tolerance."""
    esc = html.escape
    sc = s["scan"]
    rule = sc["station_rule"]
    spec = s["parameters"]["scan"]["scanner"]
    rows_scan = [
        (
            "stations",
            f"{rule['n_stations']} on a ring, {rule['distance_m']:.2f} m out "
            f"({esc(rule['rule'])}), {rule['height_above_base_m']:g} m high",
        ),
        (
            "angular step",
            f"{spec['horizontal_resolution_deg']:g}° × {spec['vertical_resolution_deg']:g}°",
        ),
        ("rays cast", cell(sc["rays_cast"])),
        ("simulated points", cell(sc["points"])),
        ("models", esc(", ".join(sc["models_active"]) or "geometry only")),
        *((f"level of detail: {what}", esc(why)) for what, why in lod_reasons(sc.get("lod"))),
    ]
    tol = s.get("tolerance") or {}
    if tol:
        rows_scan.append(
            ("coverage tolerance τ", f"{_len(tol.get('tolerance_m'))}: {esc(str(tol.get('rule')))}")
        )
    return rows_scan


def _cmp_rows(c: dict[str, Any]) -> str:
    """One comparison's figures as table rows."""
    a, m = c["accuracy"], c["completeness"]
    rows = [
        (
            "accuracy: mean / p95 / max",
            f"{_len(a['mean_m'])} / {_len(a['p95_m'])} / {_len(a['max_m'])}",
        ),
        (
            "completeness: mean / p95 / max",
            f"{_len(m['mean_m'])} / {_len(m['p95_m'])} / {_len(m['max_m'])}",
        ),
        ("coverage within τ", f"{_pct(c['coverage'])} (τ = {_len(c['tolerance_m'])})"),
        ("Hausdorff", _len(c["hausdorff_m"])),
        ("Chamfer", _len(c["chamfer_m"])),
    ]
    return "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows)


def _table(rows: list[tuple[str, str]]) -> str:
    return "<table>" + "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows) + "</table>"


def _comparison_cards(s: dict[str, Any]) -> str:
    """Both comparisons side by side: summary, figures, links and a view each."""
    esc = html.escape
    level = report_level(s)
    cards = []
    for key, title, what, view in (
        (
            "vs_mesh",
            "Simulated scan vs the tree mesh",
            "how well the scan design samples the model",
            "views_completeness.png",  # where the mesh was not seen
        ),
        (
            "vs_field",
            "Simulated scan vs the field cloud",
            "how close the simulation comes to the real scan",
            "views_accuracy.png",  # where the simulation departs from the field cloud
        ),
    ):
        exact = view == "views_accuracy.png" and trivially_exact(s[key])  # nothing drawn
        cards.append(
            f'<div class="card"><h2>{title}</h2><p class="muted">{what}</p>'
            f"<p>{esc(s['summary_text'].get(key, ''))}</p>"
            + (
                '<p class="muted"><b>Trivially exact:</b> a scan without noise lies on the '
                "mesh it was scanned from; its accuracy is float rounding, its coverage is "
                "what this comparison measures.</p>"
                if trivially_exact(s[key])
                else ""
            )
            + f"<table>{_cmp_rows(s[key])}</table><p>"
            + (f'<a href="{key}/report.html">full report</a> · ' if level != "none" else "")
            + f'<a href="{key}/comparison.json">comparison.json</a></p>'
            + (
                f'<a href="{key}/report.html"><img src="{key}/{view}" alt="distances ({key})"></a>'
                if level == "full" and not exact
                else f'<p class="note">views not drawn ({_level_note(s)})</p>'
                if not exact
                else ""
            )
            + "</div>"
        )
    return "".join(cards)


def report_level(s: dict[str, Any]) -> str:
    """The reports a run drew (``run.json``'s ``report_level``; an older run.json says
    only whether it drew plots)."""
    if "report_level" in s:
        return str(s["report_level"])
    return "full" if s["parameters"]["report"].get("plots", True) else "summary"


def _level_note(s: dict[str, Any]) -> str:
    level = report_level(s)
    if level == "full":  # plots = false under an older run.json
        return "report.plots = false"
    return f"--report {level}"


def run_page(s: dict[str, Any], version: str, viewer: dict[str, Any] | None = None) -> str:
    """A small self-contained page: the tree, the scan, both comparisons, links.

    Parameters
    ----------
    s : dict
        ``run.json``'s content (:func:`treesim.run.run_tree` builds it).
    version : str
        treesim's version, shown in the page's byline.
    viewer : dict, optional
        The 3D view's data (:func:`run_viewer_payload`); no 3D view without it.
    """
    esc = html.escape
    t = s["timings_s"]
    rows_time = [(k.replace("_", " "), f"{t[k]:.2f} s") for k in (*STAGES, "total") if k in t]
    files = "".join(
        f'<li><a href="{esc(v)}">{esc(v)}</a></li>' for v in dict.fromkeys(s["files"].values())
    )
    viewer_html = (
        viewer_section(
            viewer,
            "The simulated and field clouds and the mesh's surface samples, each coloured by "
            "its distance to the other cloud: bright where they differ, or where the scan "
            "did not see the model. ",
        )
        if viewer
        else ""
    )
    viewer_js = f"<script>{assets.VIEWER_JS}</script>" if viewer else ""
    return f"""<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>treesim run: {esc(s["name"])}</title><script>{assets.ERROR_HOOK_JS}</script>
<style>{PAGE_CSS}{assets.VIEWER_VARS}{assets.VIEWER_CSS if viewer else ""}</style></head><body>
<h1>treesim run: {esc(s["name"])}</h1><div id="page-errors" hidden></div>
<p class="muted">field cloud {esc(str(s["inputs"].get("cloud") or "in memory"))} ·
preset {esc(str(s["parameters"].get("preset") or "custom"))} · treesim {esc(version)}</p>
<div class="cards"><div class="card"><h2>Reconstruction</h2>{_table(_tree_rows(s))}
{plausibility_note(s["reconstruction"])}</div>
<div class="card"><h2>Virtual scan</h2>{_table(_scan_rows(s))}</div></div>
{reference_qsm_section(s)}
{clouds_section(s)}
<div class="cards">{_comparison_cards(s)}</div>
{viewer_html}
<h2>Time per stage</h2>{_table(rows_time)}
<h2>Files</h2><ul>{files}<li><a href="run.json">run.json</a> (parameters, versions,
timings, every figure)</li></ul>{viewer_js}</body></html>
"""
