"""The sweep's page: ``sweep.html`` of a ``treesim sweep``, one self-contained file.

Built from ``sweep.json``'s content alone (so it can be redrawn from a committed sweep):
accuracy against time for each tree with the Pareto front drawn, the effect of each
parameter alone (a small multiple per parameter: a figure against the parameter's value,
the other parameters varied), timing noise from ``--repeat``, the fronts listed, and the
table of every point. Plots are PNGs drawn with matplotlib's object API and inlined as
``data:`` URIs; the page loads nothing from anywhere.
"""

from __future__ import annotations

import base64
import html
import io
import math
import statistics
from typing import Any

from .figures import _RC, _new_figure
from .text import cell

__all__ = ["sweep_page"]

#: Colours of the trees, in order.
TREE_COLOURS = ("#2c6e9b", "#c2612d", "#2f7d4f", "#7b5ea7", "#b83232", "#8c8170")
FRONT_COLOUR = "#d1495b"
DPI = 90

#: Figures drawn against time, with the word for each tree's reference: ``ref`` stands for
#: ``vs_truth`` where the tree has a truth mesh, else ``vs_field``.
FRONT_ROWS = (
    "ref_accuracy_mean_m",
    "ref_accuracy_p95_m",
    "ref_completeness_mean_m",
    "ref_completeness_p95_m",
    "ref_coverage",
    "vs_mesh_coverage",
    "dbh_error_m",
    "height_error_m",
    "volume_error_rel",
)
#: What each parameter's small multiple shows, with its panel's title.
EFFECT_COLUMNS = {
    "time_total_s": "time of the loop",
    "peak_rss_mib": "peak memory",
    "points": "simulated points",
    "ref_accuracy_p95_m": "accuracy p95",
    "ref_completeness_p95_m": "completeness p95",
    "ref_coverage": "coverage within τ",
    "dbh_error_m": "|DBH error|",
    "volume_error_rel": "|volume error|",
}

PAGE_CSS = """
body{font:15px/1.45 system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em}
h2{font-size:1.2em;margin-top:1.8em;border-bottom:1px solid #ddd}
h3{font-size:1em;margin:1.2em 0 .3em}
table{border-collapse:collapse;margin:.6em 0;font-size:13px}td,th{padding:.2em .6em;
border-bottom:1px solid #eee;text-align:right;white-space:nowrap}th{background:#fafbfc;
position:sticky;top:0}td.l,th.l{text-align:left}.muted{color:#666}.bad{color:#b00}
.scroll{overflow-x:auto;max-height:80vh}img{max-width:100%;display:block;margin:.4em 0}
a{color:#0a58ca}code{background:#f4f4f4;padding:0 .2em}tr.front td{background:#fff4f5}
details{margin:.6em 0}summary{cursor:pointer}
"""


# -- figures and their words -------------------------------------------------------------------
def _fig_meta(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {f["key"]: f for f in doc.get("figures", [])}


def _has_truth(doc: dict[str, Any]) -> dict[str, bool]:
    return {t["id"]: bool(t.get("truth")) for t in doc.get("trees", [])}


def _resolve(key: str, tree: str, truth: dict[str, bool]) -> str:
    """``ref_*`` → ``vs_truth_*`` for a tree with a truth mesh, else ``vs_field_*``."""
    if key.startswith("ref_"):
        return ("vs_truth_" if truth.get(tree) else "vs_field_") + key[4:]
    return key


def _label(key: str, meta: dict[str, dict[str, Any]]) -> str:
    if key.startswith("ref_"):
        base = meta.get("vs_truth_" + key[4:], {}).get("label", key)
        return base.replace("truth mesh", "reference")
    extra = {
        "time_total_s": "time of the loop (s)",
        "peak_rss_mib": "peak memory (MiB)",
        "points": "simulated points",
    }
    return extra.get(key) or meta.get(key, {}).get("label", key)


def _scale(key: str) -> tuple[float, str]:
    """Display factor and unit of a column."""
    if key.endswith("coverage"):
        return 100.0, "%"
    if key == "volume_error_rel":
        return 100.0, "%"
    if key.endswith("_m"):
        return 1000.0, "mm"
    if key.endswith("_s"):
        return 1.0, "s"
    if key.endswith("_mib"):
        return 1.0, "MiB"
    return 1.0, ""


def _value(row: dict[str, Any], key: str, meta: dict[str, dict[str, Any]]) -> float | None:
    v = row.get(key)
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
        return None
    if meta.get(key, {}).get("absolute"):
        v = abs(v)
    return float(v) * _scale(key)[0]


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(b64: str, alt: str) -> str:
    return f'<img src="data:image/png;base64,{b64}" alt="{html.escape(alt)}">'


def _colours(trees: list[str]) -> dict[str, str]:
    return {t: TREE_COLOURS[i % len(TREE_COLOURS)] for i, t in enumerate(trees)}


# -- accuracy against time -------------------------------------------------------------------
#: The x axis of the fronts by the sweep's time key (``sweep.json``'s ``time``).
TIME_LABELS = {
    "time_science_s": "time of the loop without reports (s)",
    "time_total_s": "time of the loop (s)",
}


def _time_key(doc: dict[str, Any]) -> str:
    """The time the sweep's fronts are drawn against: its ``time`` (the loop without
    drawing reports since treesim 0.2; an older sweep's whole loop)."""
    key = doc.get("time", "time_total_s")
    rows = [r for r in doc.get("rows", []) if r.get("status") == "ok"]
    if key not in TIME_LABELS or any(r.get(key) is None for r in rows):
        return "time_total_s"
    return key


def _front_row_png(
    doc: dict[str, Any], key: str, ok: list[dict[str, Any]], trees: list[str]
) -> str | None:
    import matplotlib

    meta = _fig_meta(doc)
    truth = _has_truth(doc)
    fronts = doc.get("fronts", {})
    panels = []
    for t in trees:
        real = _resolve(key, t, truth)
        mine = [r for r in ok if r["tree"] == t and _value(r, real, meta) is not None]
        if mine:
            panels.append((t, real, mine, set(fronts.get(real, {}).get(t, []))))
    if not panels:
        return None
    colours = _colours(trees)
    scale, unit = _scale(key)
    with matplotlib.rc_context(_RC):
        fig = _new_figure(3.7 * max(len(panels), 2), 2.9)
        axes = fig.subplots(1, max(len(panels), 2), squeeze=False)[0]
        for ax in axes[len(panels) :]:
            ax.set_visible(False)
        tk = _time_key(doc)
        for ax, (t, real, mine, front) in zip(axes, panels, strict=False):
            x = [r[tk] for r in mine]
            y = [_value(r, real, meta) for r in mine]
            # the repeats' spread of the whole loop, about the point's mean
            lo = [
                r["time_total_s"] - (r.get("time_total_min_s") or r["time_total_s"]) for r in mine
            ]
            hi = [
                (r.get("time_total_max_s") or r["time_total_s"]) - r["time_total_s"] for r in mine
            ]
            if any(a > 0 or b > 0 for a, b in zip(lo, hi, strict=True)):
                ax.errorbar(x, y, xerr=[lo, hi], fmt="none", ecolor="#b8c2cc", lw=0.8, zorder=1)
            ax.scatter(x, y, s=16, color=colours[t], alpha=0.55, lw=0, zorder=2, label="points")
            fr = sorted(
                ((r[tk], _value(r, real, meta)) for r in mine if r["id"] in front),
                key=lambda p: p[0],
            )
            if fr:
                fx, fy = zip(*fr, strict=True)
                ax.step(fx, fy, where="post", color=FRONT_COLOUR, lw=1.3, zorder=3)
                ax.scatter(
                    fx,
                    fy,
                    s=30,
                    facecolor="none",
                    edgecolor=FRONT_COLOUR,
                    lw=1.3,
                    zorder=4,
                    label="Pareto front",
                )
            for r in mine:
                if r.get("label"):
                    ax.annotate(
                        r["label"],
                        (r[tk], _value(r, real, meta)),
                        xytext=(4, 4),
                        textcoords="offset points",
                        fontsize=8,
                        color="#333b45",
                    )
            word = (
                "truth mesh"
                if real.startswith("vs_truth")
                else ("field cloud" if real.startswith("vs_field") else "")
            )
            ax.set_title(f"{t}" + (f" (vs {word})" if key.startswith("ref_") else ""))
            ax.set_xlabel(TIME_LABELS[tk])
            ax.set_ylabel(f"{unit}" if unit else "")
        axes[0].legend(loc="best", fontsize=8)
        fig.suptitle(
            _label(key, meta) + (f" ({unit})" if unit else ""),
            x=0.01,
            ha="left",
            fontsize=10.5,
            fontweight="bold",
        )
        return _png(fig)


# -- each parameter alone ----------------------------------------------------------------------
def _axis(values: list[Any]) -> tuple[list[float], list[str] | None, bool]:
    """Positions of parameter values: numbers as they are (log when they span ≥ 4×),
    anything else (text, none, booleans, lists) as categories in sorted order."""
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    if numeric:
        pos = [float(v) for v in values]
        log = min(pos) > 0 and max(pos) / min(pos) >= 4
        return pos, None, log
    names = sorted({_text(v) for v in values})
    return [float(names.index(_text(v))) for v in values], names, False


def _text(v: Any) -> str:
    if v is None:
        return "none"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def _effect_png(doc: dict[str, Any], name: str, ok: list[dict[str, Any]], trees: list[str]) -> str:
    import matplotlib

    meta = _fig_meta(doc)
    truth = _has_truth(doc)
    colours = _colours(trees)
    cols = [
        k
        for k in EFFECT_COLUMNS
        if any(_value(r, _resolve(k, r["tree"], truth), meta) is not None for r in ok)
    ]
    pos, cats, log = _axis([r.get(name) for r in ok])
    ncol = min(len(cols), 4)
    nrow = -(-len(cols) // ncol)
    with matplotlib.rc_context(_RC):
        fig = _new_figure(2.75 * ncol, 2.35 * nrow)
        axes = list(fig.subplots(nrow, ncol, squeeze=False).ravel())
        for ax in axes[len(cols) :]:
            ax.set_visible(False)
        for ax, key in zip(axes, cols, strict=False):
            for t in trees:
                pts = [
                    (p, _value(r, _resolve(key, t, truth), meta))
                    for p, r in zip(pos, ok, strict=True)
                    if r["tree"] == t
                ]
                pts = [(p, v) for p, v in pts if v is not None]
                if not pts:
                    continue
                ax.scatter(*zip(*pts, strict=True), s=10, color=colours[t], alpha=0.45, lw=0)
                xs = sorted({p for p, _ in pts})
                med = [statistics.median(v for p, v in pts if p == x) for x in xs]
                ax.plot(xs, med, color=colours[t], lw=1.4, marker="o", ms=3, label=t)
            if log:
                ax.set_xscale("log")
                ticks = sorted(set(pos))
                ax.set_xticks(ticks)
                ax.set_xticklabels([f"{v:g}" for v in ticks], rotation=0)
                ax.minorticks_off()
            elif cats is not None:
                ax.set_xticks(range(len(cats)))
                ax.set_xticklabels(cats, rotation=30 if len(cats) > 3 else 0)
            ax.set_title(EFFECT_COLUMNS[key], fontsize=9)
            ax.set_ylabel(_scale(key)[1])
            ax.set_xlabel(name if len(name) < 30 else "…" + name[-28:], fontsize=8.5)
        axes[0].legend(fontsize=7.5)
        return _png(fig)


# -- timing noise ------------------------------------------------------------------------------
def _noise(doc: dict[str, Any], ok: list[dict[str, Any]], trees: list[str]) -> str:
    n = doc.get("repeat", 1)
    timed = [r for r in ok if (r.get("repeats") or 0) > 1 and r.get("time_total_s")]
    if not timed:
        return (
            f"<p>One timing per point ({'--repeat 1' if n == 1 else f'repeat {n}'}): timing "
            "noise is not measured. Run the same command with <code>--repeat 3</code> to time "
            "each finished point twice more (its figures are kept).</p>"
        )
    rel_sd = [r["time_total_sd_s"] / r["time_total_s"] for r in timed if r.get("time_total_sd_s")]
    spread = [(r["time_total_max_s"] - r["time_total_min_s"]) / r["time_total_s"] for r in timed]
    rep = sorted({r["repeats"] for r in timed})
    same = [r.get("repeatable") for r in timed]
    import matplotlib

    colours = _colours(trees)
    with matplotlib.rc_context(_RC):
        fig = _new_figure(7.0, 2.8)
        ax = fig.subplots()
        for t in trees:
            pts = [
                (r["time_total_s"], 100 * (r.get("time_total_sd_s") or 0) / r["time_total_s"])
                for r in timed
                if r["tree"] == t
            ]
            if pts:
                ax.scatter(*zip(*pts, strict=True), s=14, color=colours[t], label=t, alpha=0.7)
        ax.set_xlabel("mean time of the loop (s)")
        ax.set_ylabel("sd / mean (%)")
        ax.set_title("Timing noise: standard deviation of the repeats, per point")
        ax.legend(fontsize=8)
        png = _png(fig)
    text = (
        (
            f"<p>{len(timed)} points timed {', '.join(map(str, rep))} times each, every run in a "
            f"fresh process. Standard deviation of a point's time: median "
            f"{100 * statistics.median(rel_sd):.1f} % of its mean, at most "
            f"{100 * max(rel_sd):.1f} %; the spread (max − min) is median "
            f"{100 * statistics.median(spread):.1f} %, at most {100 * max(spread):.1f} %. "
            "Differences in time smaller than that are noise; the error bars of the plots "
            "above span min to max. "
        )
        if rel_sd
        else f"<p>{len(timed)} points timed more than once. "
    )
    if all(s is True for s in same):
        text += "Every repeat gave the same figures as the first run.</p>"
    else:
        bad = sum(1 for s in same if s is False)
        text += (
            f"{bad} points gave different figures on a repeat (see <code>repeatable</code>).</p>"
        )
    return text + _img(png, "timing noise per point")


# -- tables ------------------------------------------------------------------------------------
def _fmt(v: Any, key: str) -> str:
    if v is None or v == "":
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    scale, unit = _scale(key)
    if isinstance(v, float):
        if key.endswith("_s"):
            return f"{v:.2f}"
        if key.endswith("_mib"):
            return f"{v:.0f}"
        if "error" in key:
            return f"{v * scale:+.3g}"
        return f"{v * scale:.3g}"
    return cell(v)


def _table(doc: dict[str, Any], rows: list[dict[str, Any]], front_ids: set[str]) -> str:
    esc = html.escape
    params = [p["name"] for p in doc.get("parameters", [])]
    truth = _has_truth(doc)
    cols: list[tuple[str, str]] = [
        ("time_total_s", "time s"),
        ("time_total_sd_s", "sd s"),
        ("time_science_s", "no reports s"),
        ("time_report_s", "reports s"),
        ("peak_rss_mib", "peak MiB"),
        ("points", "points"),
        ("rays", "rays"),
        ("ref_accuracy_mean_m", "acc. mean mm"),
        ("ref_accuracy_p95_m", "acc. p95 mm"),
        ("ref_completeness_mean_m", "compl. mean mm"),
        ("ref_completeness_p95_m", "compl. p95 mm"),
        ("ref_coverage", "coverage %"),
        ("vs_mesh_coverage", "cov. of scanned mesh %"),
        ("dbh_error_m", "DBH err mm"),
        ("height_error_m", "height err mm"),
        ("volume_error_rel", "volume err %"),
        ("on_fronts", "on fronts"),
    ]
    head = (
        "<tr><th class='l'>point</th><th class='l'>tree</th><th class='l'>label</th>"
        + "".join(f"<th>{esc(p)}</th>" for p in params)
        + "".join(f"<th>{esc(h)}</th>" for _, h in cols)
        + "<th class='l'>status</th></tr>"
    )
    body = []
    for r in rows:
        pid = esc(str(r["id"]))
        name = f'<a href="{esc(str(r["report"]))}">{pid}</a>' if r.get("report") else pid
        status = esc(str(r["status"])) + (" (unchanged)" if r.get("reused") else "")
        if r.get("error"):
            why = f"{r.get('error_class') or ''} {r['error']}".strip()
            status += f': <span class="bad">{esc(why)}</span>'
        cells = "".join(f"<td>{esc(_text(r.get(p)))}</td>" for p in params)
        cells += "".join(
            f"<td>{_fmt(r.get(_resolve(k, r['tree'], truth)), k)}</td>" for k, _ in cols
        )
        cls = ' class="front"' if r["id"] in front_ids else ""
        body.append(
            f"<tr{cls}><td class='l'>{name}</td><td class='l'>{esc(str(r['tree']))}</td>"
            f"<td class='l'>{esc(str(r.get('label') or ''))}</td>{cells}"
            f"<td class='l'>{status}</td></tr>"
        )
    return f"<div class='scroll'><table>{head}{''.join(body)}</table></div>"


def _fronts_list(doc: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    esc = html.escape
    meta = _fig_meta(doc)
    by_id = {r["id"]: r for r in rows}
    params = [p["name"] for p in doc.get("parameters", [])]
    out = []
    for key, per in doc.get("fronts", {}).items():
        items = []
        for t, ids in per.items():
            pts = []
            for i in ids:
                r = by_id.get(i, {})
                vals = ", ".join(f"{p}={_text(r.get(p))}" for p in params)
                lab = f" [{r['label']}]" if r.get("label") else ""
                v = _value(r, key, meta)
                unit = _scale(key)[1]
                pts.append(
                    f"{_fmt(r.get('time_total_s'), 'time_total_s')} s → "
                    f"{'–' if v is None else f'{v:.3g}'} {unit}: {esc(vals)}{esc(lab)}"
                )
            items.append(f"<li><b>{esc(t)}</b>: " + "; ".join(pts) + "</li>")
        out.append(f"<h3>{esc(meta.get(key, {}).get('label', key))}</h3><ul>{''.join(items)}</ul>")
    return "".join(out)


# -- the page ----------------------------------------------------------------------------------
def sweep_page(doc: dict[str, Any]) -> str:
    """The page of a sweep, from ``sweep.json``'s content.

    Parameters
    ----------
    doc : dict
        ``sweep.json`` (:func:`treesim.sweep.engine.sweep_document`): ``rows``,
        ``fronts``, ``figures``, ``parameters``, ``trees``, ``tolerance``, ...

    Returns
    -------
    str
        A self-contained HTML page (no scripts, no external resources).
    """
    esc = html.escape
    rows = doc.get("rows", [])
    ok = [r for r in rows if r.get("status") == "ok" and r.get("time_total_s") is not None]
    trees = [t["id"] for t in doc.get("trees", [])] or list(dict.fromkeys(r["tree"] for r in rows))
    c = doc.get("counts", {})
    tol = doc.get("tolerance", {})
    m = doc.get("machine", {})
    ex = doc.get("executor", {})
    params = doc.get("parameters", [])

    tree_items = "".join(
        f"<li><b>{esc(t['id'])}</b>: {esc(t['source'])}; field cloud {t['field_points']:,} "
        f"points (median spacing {t['point_spacing_m'] * 1000:.3g} mm)"
        + (
            f"; truth: DBH {t['truth']['dbh_m'] * 100:.2f} cm, height "
            f"{t['truth']['height_m']:.2f} m, wood {t['truth']['volume_total_m3'] * 1000:.2f} L"
            if t.get("truth") and t["truth"].get("dbh_m")
            else "; no truth"
        )
        + "</li>"
        for t in doc.get("trees", [])
    )
    param_items = "".join(
        f"<li><code>{esc(p['name'])}</code> ({esc(', '.join(p['paths']))}"
        f"{'; ' + esc(p['unit']) if p.get('unit') else ''}): {esc(p['help'])}; values "
        + esc(", ".join(sorted({_text(r.get(p["name"])) for r in rows})))
        + "</li>"
        for p in params
    )
    note = " (interrupted: run the same command again to finish)" if doc.get("interrupted") else ""
    base = doc.get("base") or {}
    base_text = (
        " with " + esc(", ".join(f"{k} = {_text(v)}" for k, v in base.items())) if base else ""
    )
    head = f"""<h1>treesim sweep: {esc(str(doc.get("name", "sweep")))}</h1>
<p class="muted">{esc(str(doc.get("description") or ""))}</p>
<p>{c.get("points", len(rows))} points ({len(trees)} trees × {len(doc.get("designs", []))}
designs): {c.get("ok", 0)} ok ({c.get("reused", 0)} unchanged from an earlier run),
{c.get("failed", 0)} failed, {c.get("not_run", 0)} not run{note}. Coverage at one
τ = {float(tol.get("tolerance_m", float("nan"))) * 1000:.3g} mm for every point
({esc(str(tol.get("rule", "")))}). Figures: <a href="sweep.csv">sweep.csv</a>,
<a href="sweep.json">sweep.json</a>.</p>
<p class="muted">{esc(str(ex.get("description", "")))}; {doc.get("repeat", 1)} timing(s) per
point, each run in a fresh process; {esc(str(m.get("cpu", "")))}, {m.get("cores", "?")} cores,
Python {esc(str(m.get("python", "")))}; finished {esc(str(doc.get("finished", "")))}, wall
time of the run that finished it {float(doc.get("elapsed_s") or 0):.0f} s (earlier runs, whose
points it kept or timed again, not counted); treesim {esc(str(doc.get("treesim", "")))}.</p>
<h2>Trees</h2><ul>{tree_items}</ul>
<h2>Parameters</h2><p>Every design starts from the <code>{esc(str(doc.get("preset", "")))}</code>
preset{base_text};
the sweep varies:</p><ul>{param_items}</ul>"""

    if not ok:
        body = "<p>No point finished: there is nothing to plot. The table says why.</p>"
    else:
        fronts_html = []
        for key in FRONT_ROWS:
            png = _front_row_png(doc, key, ok, trees)
            if png:
                fronts_html.append(_img(png, _label(key, _fig_meta(doc))))
        effects = "".join(
            f"<h3><code>{esc(p['name'])}</code></h3>"
            + _img(_effect_png(doc, p["name"], ok, trees), p["name"])
            for p in params
        )
        body = f"""<h2>Accuracy against time</h2>
<p>Each dot is a point (one tree, one design); time is the whole loop (reconstruct, scan,
compare, reports; imports excluded), the mean of its repeats. The red staircase is the
Pareto front: the points no other point beats in both time and the figure. For trees with
a truth (procedural species) the reference is the truth mesh, otherwise the field cloud;
DBH, height and volume errors need a truth. Labelled points are named designs (presets).</p>
{"".join(fronts_html)}
<h2>Each parameter alone</h2>
<p>For each parameter: a figure against its value, every other parameter varied; dots
are points, lines the median per value, one colour per tree. Accuracy, completeness and
coverage are against each tree's reference (truth mesh, else field cloud); errors are of
the reconstruction against the truth.</p>
{effects}"""
    front_ids = {i for per in doc.get("fronts", {}).values() for ids in per.values() for i in ids}
    noise = _noise(doc, ok, trees) if ok else ""
    return f"""<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>treesim sweep: {esc(str(doc.get("name", "sweep")))}</title><style>{PAGE_CSS}</style></head>
<body>{head}{body}
<h2>Timing noise</h2>{noise or "<p>No point finished.</p>"}
<h2>Every point</h2><p class="muted">Rows on at least one Pareto front are tinted; figures
against each tree's reference (truth mesh, else field cloud); errors are reconstruction −
truth.</p>{_table(doc, rows, front_ids)}
<h2>The fronts</h2><details><summary>Every figure's Pareto front, per tree (time → figure:
the design)</summary>{_fronts_list(doc, rows)}</details>
</body></html>
"""
