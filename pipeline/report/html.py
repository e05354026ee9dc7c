"""The self-contained HTML page: summary, figures, tables, plots and a 3D view, offline."""

from __future__ import annotations

import base64
import json
from collections.abc import Callable
from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from . import assets, figures
from .data import ReportData
from .text import exactness_note, length, lod_reasons, mm, percent


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


#: Width (inches) of a full-width plot; narrower plots are shown at the same scale.
FULL_WIDTH_IN = 11.0


def _img(path: Path | None, alt: str, dpi: int, why: str = "report.plots = false") -> str:
    if path is None:
        return f'<p class="note">{escape(alt)}: not drawn ({escape(why)})</p>'
    raw = path.read_bytes()
    full = FULL_WIDTH_IN * dpi
    width_px = int.from_bytes(raw[16:20], "big") if raw[12:16] == b"IHDR" else full
    share = min(100.0, 100.0 * width_px / full)
    return (
        f'<img src="data:image/png;base64,{_b64(raw)}" alt="{escape(alt)}" '
        f'style="width: {share:.1f}%">'
    )


def _json_script(obj: Any) -> str:
    """JSON safe to place inside a ``<script>`` element."""
    text = json.dumps(obj, separators=(",", ":"), allow_nan=False)
    return text.replace("</", "<\\/").replace("<!--", "<\\!--")


#: The 3D viewer's colour table: :func:`figures.cmap` at 256 even steps, 8-bit RGB, written
#: out so that a run whose figures are drawn in another process does not import matplotlib
#: for it (tests/report check it against matplotlib's own).
VIEWER_LUT = bytes.fromhex(
    "44015444015444025645045745055946075a46085c460a5d460b5e470d60470e61471063471164471365"
    "47136548146748166848176948186a481a6c481b6d481c6e481d6f481f70482071482173482374482374"
    "482475482576482677482878482979472a7a472c7a472d7b472e7c472f7d46307e46327e46327e46337f"
    "463480453581453781453882443983443a83443b84433d84433e85423f85424086424086424186414287"
    "4144874045884046883f47883f48893e49893e4a893e4c8a3d4d8a3d4e8a3d4e8a3c4f8a3c508b3b518b"
    "3b528b3a538b3a548c39558c39568c38588c38598c375a8c375b8d375b8d365c8d365d8d355e8d355f8d"
    "34608d34618d33628d33638d32648e32658e31668e31678e31678e31688e30698e306a8e2f6b8e2f6c8e"
    "2e6d8e2e6e8e2e6f8e2d708e2d718e2c718e2c728e2c728e2c738e2b748e2b758e2a768e2a778e2a788e"
    "29798e297a8e297b8e287c8e287d8e277e8e277e8e277f8e27808e26818e26828e26828e25838e25848e"
    "25858e24868e24878e23888e23898e23898e238a8d228b8d228c8d228d8d218e8d218f8d21908d21918c"
    "20928c20928c20938c1f948c1f948c1f958b1f968b1f978b1f988b1f998a1f9a8a1e9b8a1e9c891e9d89"
    "1f9e891f9f881fa0881fa1881fa1881fa1871fa28720a38620a48621a58521a68522a78522a88423a983"
    "24aa8325ab8225ac8225ac8226ad8127ad8128ae8029af7f2ab07f2cb17e2db27d2eb37c2fb47c31b57b"
    "32b67a34b67934b67935b77937b87838b9773aba763bbb753dbc743fbc7340bd7242be7144bf7046c06f"
    "48c16e48c16e4ac16d4cc26c4ec36b50c46a52c56954c56856c66758c7655ac8645cc8635ec96260ca60"
    "60ca6063cb5f65cb5e67cc5c69cd5b6ccd5a6ece5870cf5773d05675d05477d1537ad1517cd2507cd250"
    "7fd34e81d34d84d44b86d54989d5488bd6468ed64590d74393d74195d84098d83e9bd93c9bd93c9dd93b"
    "a0da39a2da37a5db36a8db34aadc32addc30b0dd2fb2dd2db5de2bb8de29bade28bade28bddf26c0df25"
    "c2df23c5e021c8e020cae11f"
)


#: One data set of the 3D view: key, name, points (n, 3), distances (n,), top of the
#: colour scale (m), colour legend, τ (m) or None.
ViewerSet = tuple[str, str, np.ndarray, np.ndarray, float, str, "float | None"]


def viewer_sets_payload(
    sets: list[ViewerSet], *, max_points: int = 40_000, seed: int = 0
) -> dict[str, Any]:
    """The 3D viewer's data for any data sets in one coordinate system: subsampled points
    quantised to 16 bits per axis in their common bounding box, colour indices (0-255)
    into a 256-entry colour table, and legends."""
    picked = [figures._subsample(len(st[2]), max_points, seed + i) for i, st in enumerate(sets)]
    allp = np.concatenate([st[2][idx] for st, idx in zip(sets, picked, strict=True)])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    size = np.maximum(hi - lo, 1e-9)
    out = []
    for (key, name, pts, dist, vmax, clabel, tau), idx in zip(sets, picked, strict=True):
        q = np.round((pts[idx] - lo) / size * 65535).clip(0, 65535).astype("<u2")
        c = np.round(np.clip(dist[idx] / vmax, 0, 1) * 255).astype(np.uint8)
        unit, k = figures.unit_for(vmax)
        out.append(
            {
                "key": key,
                "name": name,
                "n": int(len(idx)),
                "pos": _b64(q.tobytes()),
                "col": _b64(c.tobytes()),
                "vmax": vmax * k,
                "unit": unit,
                "tau": None if tau is None else tau * k,
                "colour_label": f"{clabel} ({unit})",
                "caption": f"{len(idx):,} of {len(pts):,} points"
                + (" (random subsample)" if len(idx) < len(pts) else ""),
            }
        )
    return {"datasets": out, "lut": _b64(VIEWER_LUT), "bbox_size_m": size.tolist()}


def comparison_sets(data: ReportData, *, prefix: str = "") -> list[ViewerSet]:
    """A comparison's two data sets: the cloud coloured by accuracy, the reference
    coloured by completeness (with τ)."""
    s = data.summary
    ref_word = figures._ref_word(s)
    return [
        (
            f"{prefix}accuracy",
            f"Cloud → {ref_word}",
            data.cloud_points,
            data.cloud_distance_m,
            figures.accuracy_colour_limit(s),
            f"distance to the {ref_word}",
            None,
        ),
        (
            f"{prefix}completeness",
            f"{ref_word.capitalize()} → cloud",
            data.reference_points,
            data.reference_distance_m,
            figures.completeness_colour_limit(s),
            "distance to the cloud",
            float(s["tolerance_m"]),
        ),
    ]


def viewer_payload(data: ReportData, *, max_points: int = 40_000, seed: int = 0) -> dict[str, Any]:
    """The 3D viewer's data of one comparison (:func:`comparison_sets`)."""
    return viewer_sets_payload(comparison_sets(data), max_points=max_points, seed=seed)


def viewer_section(payload: dict[str, Any], lead: str = "") -> str:
    """The 3D view's ``<section id="viewer">``: canvas, controls and data (the page must
    carry :data:`assets.VIEWER_CSS` and, after it, :data:`assets.VIEWER_JS`)."""
    set_buttons = "".join(
        f'<button type="button" data-set="{i}" aria-pressed="{"true" if i == 0 else "false"}">'
        f"{escape(d['name'])}</button>"
        for i, d in enumerate(payload["datasets"])
    )
    return f"""<section class="panel" id="viewer">
  <h2>Interactive 3D view</h2>
  <p class="lead">{lead}Drag to rotate, shift-drag or right-drag to pan, scroll to zoom,
  double-click to reset. Colours as in the legend; darker points are farther away.</p>
  <div class="viewer">
    <canvas aria-label="3D view of the points coloured by distance"></canvas>
    <div class="controls">
      <div class="group"><div class="label">Points</div><div class="seg">{set_buttons}</div></div>
      <div class="group"><div class="label">View</div><div class="seg">
        <button type="button" data-view="home">Oblique</button>
        <button type="button" data-view="side">Side</button>
        <button type="button" data-view="top">Top</button></div></div>
      <div class="group"><div class="label">Point size</div>
        <input type="range" min="1" max="6" step="1" value="2" aria-label="point size"></div>
      <div class="group"><div class="label legend-title"></div>
        <div class="legend"><div class="bar"></div><div class="ticks"></div></div></div>
      <div class="hint count"></div>
    </div>
  </div>
  <script type="application/json" id="viewer-data">{_json_script(payload)}</script>
</section>"""


def _stats_rows(s: dict[str, Any], ref_word: str) -> str:
    rows = []
    for key, cls, title in (
        ("accuracy", "acc", f"Accuracy (cloud → {ref_word})"),
        ("completeness", "comp", f"Completeness ({ref_word} → cloud)"),
    ):
        st = s[key]
        cells = "".join(
            f'<td class="n">{mm(st[f])}</td>'
            for f in ("mean_m", "rms_m", "median_m", "p95_m", "p99_m", "max_m")
        )
        rows.append(
            f'<tr><td><span class="dot {cls}"></span>{escape(title)}</td>'
            f'<td class="n">{st["n"]:,}</td>{cells}</tr>'
        )
    return "\n".join(rows)


_STATS_HEAD = (
    '<tr><th>direction</th><th class="n">n</th><th class="n">mean</th><th class="n">RMS</th>'
    '<th class="n">median</th><th class="n">p95</th><th class="n">p99</th>'
    '<th class="n">max</th></tr>'
)


def _label_table(s: dict[str, Any]) -> str:
    by = s.get("by_label") or {}
    if not by:
        return ""
    rows = []
    for name, e in by.items():
        acc = e.get("accuracy")
        comp = e.get("completeness")
        cells = [
            f"{acc['n']:,}" if acc else "–",
            mm(acc["mean_m"]) if acc else "–",
            mm(acc["p95_m"]) if acc else "–",
            mm(acc["max_m"]) if acc else "–",
            f"{comp['n']:,}" if comp else "–",
            mm(comp["mean_m"]) if comp else "–",
            percent(e.get("coverage")) if comp else "–",
        ]
        rows.append(
            f"<tr><td>{escape(name)}</td>"
            + "".join(f'<td class="n">{c}</td>' for c in cells)
            + "</tr>"
        )
    return (
        "<h3>By hit label</h3>"
        '<p class="lead">Accuracy of the cloud points with each label; completeness and '
        "coverage of the reference samples with that label (to the whole cloud). "
        "Distances in mm.</p>"
        '<div class="scroll"><table><thead><tr><th>label</th><th class="n">points</th>'
        '<th class="n">acc. mean</th><th class="n">acc. p95</th><th class="n">acc. max</th>'
        '<th class="n">ref. samples</th><th class="n">compl. mean</th>'
        '<th class="n">coverage</th></tr></thead><tbody>' + "".join(rows) + "</tbody></table></div>"
    )


def _station_table(s: dict[str, Any], stations_pos: dict[str, list[float]]) -> str:
    by = s.get("by_station") or {}
    if not by:
        return ""
    rows = []
    for key, e in by.items():
        acc = e["accuracy"]
        pos = stations_pos.get(str(key))
        where = ", ".join(f"{c:.2f}" for c in pos) if pos else "–"
        rows.append(
            f'<tr><td>S{escape(str(key))}</td><td class="n">{where}</td>'
            f'<td class="n">{e["points"]:,}</td><td class="n">{mm(acc["mean_m"])}</td>'
            f'<td class="n">{mm(acc["p95_m"])}</td><td class="n">{mm(acc["max_m"])}</td>'
            f'<td class="n">{percent(e["coverage"])}</td></tr>'
        )
    return (
        "<h3>By station</h3>"
        '<p class="lead">Accuracy of each station\'s points; coverage of the whole reference '
        "by that station alone (the stations together give the overall coverage). "
        "Distances in mm.</p>"
        '<div class="scroll"><table><thead><tr><th>station</th><th class="n">position (m)</th>'
        '<th class="n">points</th><th class="n">acc. mean</th><th class="n">acc. p95</th>'
        '<th class="n">acc. max</th><th class="n">coverage alone</th></tr></thead><tbody>'
        + "".join(rows)
        + "</tbody></table></div>"
    )


def _profile_table(p: dict[str, Any] | None, ref_word: str) -> str:
    """The occlusion profile's numbers, highest slice first."""
    if not p:
        return ""
    edges = p["edges_m"]
    names = ["all", *p["stations"]]
    dens = p.get("density_per_m2")
    head = (
        f'<th>height (m)</th><th class="n">{escape(ref_word)} samples</th>'
        + "".join(f'<th class="n">coverage {escape(n)}</th>' for n in names)
        + (
            '<th class="n">points / m² (all)</th>'
            if dens is not None
            else f'<th class="n">cloud points</th><th class="n">{escape(ref_word)} points</th>'
        )
    )
    rows = []
    for i in reversed(range(len(edges) - 1)):
        cells = [f"{p['reference_points'][i]:,}"]
        cells += [
            percent(p["coverage"][n][i]) if p["coverage"][n][i] is not None else "–" for n in names
        ]
        if dens is not None:
            d = dens["all"][i]
            cells.append("–" if d is None else f"{d:,.0f}")
        else:
            cells += [f"{p['cloud_points']['all'][i]:,}", f"{p['reference_points'][i]:,}"]
        rows.append(
            f"<tr><td>{edges[i]:.2f}–{edges[i + 1]:.2f}</td>"
            + "".join(f'<td class="n">{c}</td>' for c in cells)
            + "</tr>"
        )
    return (
        '<div class="scroll"><table><thead><tr>'
        + head
        + "</tr></thead><tbody>"
        + "".join(rows)
        + "</tbody></table></div>"
    )


def _note_html(note: str | None) -> str:
    if not note:
        return ""
    return f'<section class="panel note" id="exact-note"><p>{escape(note)}</p></section>'


def _kv_table(rows: list[tuple[str, str]]) -> str:
    body = "".join(f"<tr><td>{escape(k)}</td><td>{v}</td></tr>" for k, v in rows)
    return f'<table class="kv"><tbody>{body}</tbody></table>'


def _parameter_rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    p = s.get("parameters", {})
    ref = s.get("reference", {})
    inputs = s.get("inputs", {})
    rows: list[tuple[str, str]] = []
    if inputs.get("cloud"):
        rows.append(("cloud", f"<code>{escape(str(inputs['cloud']))}</code>"))
    rows.append(("cloud points", f"{s.get('cloud', {}).get('points', s['accuracy']['n']):,}"))
    if inputs.get("reference"):
        rows.append(("reference", f"<code>{escape(str(inputs['reference']))}</code>"))
    if ref.get("kind") == "mesh":
        rows.append(
            (
                "reference mesh",
                f"{ref.get('triangles', 0):,} triangles, {ref.get('area_m2', 0):.4g} m² "
                f"({ref.get('degenerate_triangles_dropped', 0)} degenerate dropped)",
            )
        )
        hid = ref.get("hidden_surface")
        if isinstance(hid, dict):
            rows.append(
                (
                    "hidden surface dropped",
                    f"{hid.get('area_m2', 0.0):.4g} m² ± {hid.get('area_se_m2', 0.0):.2g} "
                    f"({percent(hid.get('area_share'))}; {hid.get('samples_dropped', 0):,} of "
                    f"{hid.get('samples_drawn', 0):,} samples): "
                    f"{escape(str(hid.get('why', '')))} "
                    f"({hid.get('closed_parts', 0):,} closed parts of "
                    f"{hid.get('parts', 0):,})",
                )
            )
        rows.append(
            (
                "surface samples",
                f"{ref.get('samples', 0):,}, one per ({length(p.get('sample_spacing_m'))})² "
                f"of surface (spacing: {escape(str(p.get('sample_spacing_rule')))}); "
                f"seed {p.get('seed')}",
            )
        )
    else:
        rows.append(("reference cloud", f"{ref.get('points', 0):,} points"))
    rows.append(
        ("cloud point spacing", f"{length(s.get('point_spacing_m'))} (median nearest neighbour)")
    )
    rows.append(
        ("tolerance τ", f"{length(s['tolerance_m'])} ({escape(str(p.get('tolerance_rule')))})")
    )
    origin = p.get("frame_origin_m")
    if origin:
        rows.append(
            ("local frame origin", ", ".join(f"{c:,.3f}" for c in origin) + " m (float64 shift)")
        )
    scan = inputs.get("scan") or {}
    spec = scan.get("scanner") or {}
    if spec:
        res = (spec.get("horizontal_resolution_deg"), spec.get("vertical_resolution_deg"))
        rows.append(("scanner resolution", f"{res[0]}° × {res[1]}° (horizontal × vertical)"))
        models = scan.get("models_active")
        rows.append(("scanner models", escape(", ".join(models) if models else "geometry only")))
        for what, why in lod_reasons(scan.get("lod")):
            rows.append((f"level of detail: {what}", escape(why)))
    if scan.get("stations"):
        rows.append(("stations", str(len(scan["stations"]))))
    return rows


#: Draws one plot's ``<img>`` (or says it was not drawn): key, alt text.
ImageTag = Callable[[str, str], str]


def _header_meta(s: dict[str, Any], generated: str) -> str:
    """The line under the title: points, the reference's size, when."""
    acc = s["accuracy"]
    ref = s.get("reference", {})
    meta = f"{s.get('cloud', {}).get('points', acc['n']):,} points"
    if ref.get("kind") == "mesh":
        meta += f" · mesh of {ref.get('triangles', 0):,} triangles, {ref.get('area_m2', 0):.3g} m²"
    else:
        meta += f" · reference cloud of {ref.get('points', 0):,} points"
    meta += f" · generated {escape(generated)}"
    return meta


def _page_head(cloud_name: str, ref_name: str, meta: str) -> str:
    """From the doctype to the page's header."""
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>treesim comparison: {escape(cloud_name)} vs {escape(ref_name)}</title>
<script>{assets.ERROR_HOOK_JS}</script>
<style>{assets.CSS}</style>
</head>
<body>
<header class="top"><div class="wrap">
  <div class="eyebrow">treesim · AVOHD comparison report</div>
  <h1>{escape(cloud_name)}<span class="vs">vs</span>{escape(ref_name)}</h1>
  <p class="meta">{meta}</p>
</div></header>"""


def _cards_html(s: dict[str, Any], ref_word: str) -> str:
    """The headline figures as cards."""
    acc = s["accuracy"]
    cards = [
        (
            "acc",
            "Accuracy p95",
            length(acc["p95_m"]),
            f"95 % of points closer; median {length(acc['median_m'])}",
        ),
        ("comp", "Coverage", percent(s["coverage"]), f"of the {ref_word} within τ"),
        (
            "tau",
            "Tolerance τ",
            length(s["tolerance_m"]),
            escape(str(s.get("parameters", {}).get("tolerance_rule", ""))),
        ),
        ("", "Hausdorff", length(s["hausdorff_m"]), "symmetric maximum"),
        ("", "Chamfer", length(s["chamfer_m"]), "mean of both directions' means"),
    ]
    return "".join(
        f'<div class="card {c}"><div class="k">{escape(k)}</div><div class="v">{v}</div>'
        f'<div class="s">{sub}</div></div>'
        for c, k, v, sub in cards
    )


def _distances_section(s: dict[str, Any], ref_word: str) -> str:
    """Both directions' statistics, by hit label and by station."""
    stations_pos = {}
    for st in (s.get("inputs", {}).get("scan") or {}).get("stations", []) or []:
        if "index" in st and "position_m" in st:
            stations_pos[str(st["index"])] = st["position_m"]
    return f"""<section class="panel">
  <h2>Distances</h2>
  <p class="lead">Absolute distances in millimetres. Accuracy: every cloud point to the
  {ref_word}. Completeness: every {ref_word} sample to the nearest cloud point; it shows what
  the cloud misses, which accuracy alone can never show.</p>
  <div class="scroll"><table><thead>{_STATS_HEAD}</thead><tbody>
  {_stats_rows(s, ref_word)}
  </tbody></table></div>
  {_label_table(s)}
  {_station_table(s, stations_pos)}
</section>"""


def _plot_sections(img: ImageTag, s: dict[str, Any], ref_word: str, tau_txt: str) -> str:
    """The distributions, where the differences are, and coverage by station."""
    return f"""<section class="panel">
  <h2>Distributions</h2>
  <p class="lead">How far the points are, as shares of each direction's points.
  The red line is the coverage tolerance τ = {tau_txt}.</p>
  <figure>{img("histograms", "Histograms of the accuracy and completeness distances")}
    <figcaption>Histograms up to the 99th percentile; the dotted and dashed lines are the
    median and the 95th percentile.</figcaption></figure>
  <figure>{img("cumulative", "Cumulative distributions of both directions")}
    <figcaption>Share of points within a distance. Where the completeness curve crosses τ
    is the coverage ({percent(s["coverage"])}).</figcaption></figure>
</section>

<section class="panel">
  <h2>Where the differences are</h2>
  <figure>{img("views_accuracy", "Cloud coloured by distance to the reference")}
    <figcaption>The cloud, coloured by its distance to the {ref_word} (accuracy).
    </figcaption></figure>
  <figure>{img("views_completeness", "Reference coloured by distance to the cloud")}
    <figcaption>The {ref_word} samples, coloured by their distance to the cloud
    (completeness): bright areas were not seen. Triangles mark the stations.</figcaption>
  </figure>
</section>

<section class="panel">
  <h2>Coverage</h2>
  <figure>{img("coverage", "Coverage of the reference by station")}
    <figcaption>Share of the {ref_word} within τ = {tau_txt} of the cloud, by all stations
    together and by each station alone.</figcaption></figure>
</section>"""


def _occlusion_section(
    img: ImageTag, profile: dict[str, Any] | None, ref_word: str, tau_txt: str
) -> str:
    """Coverage and point density by height slice: the plot and its numbers."""
    return f"""<section class="panel" id="occlusion">
  <h2>Occlusion by height</h2>
  <p class="lead">The {ref_word} cut into {length(profile["bin_m"]) if profile else ""} slices
  from its lowest point up: the share of each slice within τ = {tau_txt} of the cloud, for
  every station alone and all together, and how densely the cloud samples it. Where the
  stations together fall short, no station saw that part of the tree.</p>
  <figure>{img("occlusion", "Coverage and point density by height")}
    <figcaption>Left: coverage by height slice; right: cloud points per slice
    {
        "per m² of surface"
        if profile and profile.get("density_per_m2")
        else "beside the reference's"
    }.</figcaption></figure>
  {_profile_table(profile, ref_word)}
</section>"""


def _about_section(s: dict[str, Any]) -> str:
    """The parameters that produced the figures, and the figures' definitions."""
    defs = s.get("definitions", {})
    defs_html = "".join(f"<dt>{escape(k)}</dt><dd>{escape(v)}</dd>" for k, v in defs.items())
    return f"""<section class="two">
  <div class="panel"><h2>Parameters</h2>
    <p class="lead">What produced these figures.</p>
    {_kv_table(_parameter_rows(s))}</div>
  <div class="panel"><h2>Definitions</h2>
    <p class="lead">The figures' names as in <code>comparison.json</code>.</p>
    <dl class="defs">{defs_html}</dl></div>
</section>"""


def build_html(
    data: ReportData,
    pngs: dict[str, Path],
    paragraph: str,
    *,
    generated: str,
    max_view_points: int = 40_000,
    seed: int = 0,
    dpi: int = 130,
    profile: dict[str, Any] | None = None,
    not_drawn: dict[str, str] | None = None,
) -> str:
    """The page as one string (every image and the viewer's data inline); a plot missing
    from ``pngs`` is said, not drawn, and why (``not_drawn``, by key; default
    ``report.plots = false``)."""

    def img(key: str, alt: str) -> str:
        return _img(pngs.get(key), alt, dpi, (not_drawn or {}).get(key, "report.plots = false"))

    s = data.summary
    ref_word = figures._ref_word(s)
    inputs = s.get("inputs", {})
    cloud_name = Path(str(inputs.get("cloud", "cloud"))).name
    ref_name = Path(str(inputs.get("reference", ref_word))).name
    payload = viewer_payload(data, max_points=max_view_points, seed=seed)
    versions = {**s.get("software", {}), **s.get("report_software", {})}
    versions_html = "".join(
        f"<span>{escape(k)} <b>{escape(str(v))}</b></span>" for k, v in versions.items()
    )
    tau_txt = length(s["tolerance_m"])

    return f"""{_page_head(cloud_name, ref_name, _header_meta(s, generated))}
<main class="wrap">
<div id="page-errors" hidden></div>
<section class="panel summary"><p>{escape(paragraph)}</p></section>
{_note_html(exactness_note(s))}

<section class="cards">{_cards_html(s, ref_word)}</section>

{_distances_section(s, ref_word)}

{viewer_section(payload)}

{_plot_sections(img, s, ref_word, tau_txt)}

{_occlusion_section(img, profile, ref_word, tau_txt)}

{_about_section(s)}
</main>
<footer class="wrap"><div class="versions">{versions_html}</div></footer>
<script>{assets.VIEWER_JS}</script>
</body>
</html>
"""
