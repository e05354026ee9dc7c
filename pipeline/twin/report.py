"""The report of ``treesim plot from-cloud``: the map, the DBH and height distributions,
per-tree figures, what was left out and why (``report.html``, self-contained)."""

from __future__ import annotations

from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from ..report.figures import _new_figure, save_png

__all__ = ["write_twin_report"]


def write_map(path: Path, result: Any, dtm: Any) -> Path:
    """The DTM's contours, each tree at its stem (circles 5 × its slab DBH, numbered),
    the stems left out (red crosses) and the stations (triangles)."""
    fig = _new_figure(6.5, 6.0)
    ax = fig.subplots()
    xs, ys = dtm.centres()  # row 0 of z is the southern row
    z = np.asarray(dtm.z, dtype=float)
    if z.shape[0] > 1 and z.shape[1] > 1 and np.isfinite(z).any():
        cs = ax.contourf(xs, ys, z, levels=12, cmap="Greys", alpha=0.5)
        fig.colorbar(cs, ax=ax, label="ground height (m)", shrink=0.8)
    from matplotlib.patches import Circle

    for r in result.trees:
        ax.add_patch(Circle((r["x_m"], r["y_m"]), 2.5 * r["slab_dbh_m"], color="tab:green"))
        ax.annotate(str(r["tree_id"]), (r["x_m"], r["y_m"]), fontsize=6, ha="center")
    for r in result.left_out:
        ax.plot(r["x_m"], r["y_m"], "x", color="tab:red", ms=7)
    stations = result.figures.get("stations") or []
    for i, s in enumerate(stations):
        ax.plot(s[0], s[1], "^", color="tab:blue", ms=7)
        ax.annotate(f"S{i}", (s[0], s[1]), fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"{len(result.trees)} trees (green, circles 5 × DBH), "
        f"{len(result.left_out)} left out (red ×)",
        fontsize=9,
    )
    return save_png(fig, path)


def write_distributions(path: Path, result: Any) -> Path:
    """Histograms of the slab and QSM DBH, and of the heights."""
    fig = _new_figure(9.0, 3.4)
    a, b = fig.subplots(1, 2)
    slab = [r["slab_dbh_m"] * 100 for r in result.trees]
    qsm = [r["qsm_dbh_m"] * 100 for r in result.trees if r.get("qsm_dbh_m")]
    bins = np.histogram_bin_edges(slab + qsm or [0.0], bins=min(12, max(3, len(slab))))
    a.hist(slab, bins=bins, alpha=0.6, label="stem slab circle")
    a.hist(qsm, bins=bins, alpha=0.6, label="QSM")
    a.set_xlabel("DBH (cm)")
    a.set_ylabel("trees")
    a.legend(fontsize=7)
    b.hist(
        [r["height_m"] for r in result.trees if r["height_m"] is not None],
        bins=min(12, max(3, len(slab))),
        color="tab:green",
    )
    b.set_xlabel("height above ground (m)")
    b.set_ylabel("trees")
    return save_png(fig, path)


def _fmt(v: Any, scale: float = 1.0, digits: int = 1) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    return f"{v * scale:,.{digits}f}"


def _tree_rows(trees: list[dict[str, Any]]) -> str:
    out = []
    for r in trees:
        out.append(
            "<tr>"
            + "".join(
                f"<td>{c}</td>"
                for c in (
                    r["tree_id"],
                    _fmt(r["x_m"], digits=2),
                    _fmt(r["y_m"], digits=2),
                    _fmt(r["slab_dbh_m"], 100),
                    _fmt(r.get("qsm_dbh_m"), 100),
                    _fmt(r["height_m"]),
                    f"{r['points']:,}",
                    _fmt(r.get("volume_total_m3"), 1000, 0),
                    escape(str(r.get("qsm_warnings") or "")),
                )
            )
            + "</tr>"
        )
    return "\n".join(out)


_CSS = (
    "body{font-family:system-ui,sans-serif;margin:2em;max-width:70em}"
    "table{border-collapse:collapse;font-size:0.9em}td,th{border:1px solid #ccc;"
    "padding:2px 6px;text-align:right}th{background:#eee}img{max-width:100%}"
)


def write_twin_report(result: Any, dtm: Any) -> Path:
    """Draw ``map.png`` and ``dbh_height.png`` and write ``report.html`` beside them."""
    from ..atomic import write_text
    from ..report.html import _img
    from .result import TWIN_FILES

    out = Path(result.outdir)
    map_png = write_map(out / TWIN_FILES["map"], result, dtm)
    dist_png = write_distributions(out / TWIN_FILES["distributions"], result)
    f = result.figures
    g = f["ground"]
    left = "".join(
        f"<li>stem {r['tree_id']} at ({r['x_m']:.2f}, {r['y_m']:.2f}): {escape(r['reason'])}</li>"
        for r in result.left_out
    )
    warn = "".join(f"<li>{escape(w)}</li>" for w in result.warnings)
    head = (
        "<th>tree</th><th>x (m)</th><th>y (m)</th><th>slab DBH (cm)</th><th>QSM DBH (cm)"
        "</th><th>height (m)</th><th>points</th><th>wood (L)</th><th>QSM warnings</th>"
    )
    html = f"""<!doctype html><html><head><meta charset="utf-8">
<title>treesim twin of {escape(Path(f["input"]).name)}</title><style>{_CSS}</style></head><body>
<h1>Twin of {escape(Path(f["input"]).name)}</h1>
<p>{escape(result.summary_line())}. {g["points"]:,} points, {g["ground_points"]:,} ground;
DTM {g["dtm_shape"][1]} × {g["dtm_shape"][0]} cells of {g["dtm_cell_m"]} m
({g["dtm_coverage"]:.0%} of them with ground points). Units: {escape(f["units"])};
trees reconstructed with the {escape(f["params"]["preset"])} preset.</p>
<h2>Map</h2>{_img(map_png, "map", 110)}
<h2>DBH and height</h2>{_img(dist_png, "distributions", 110)}
<p>The slab DBH is a circle fitted to the stem's points 1.2-1.4 m above the DTM; the QSM
DBH is the reconstruction's. They are independent measures of one stem.</p>
<h2>Trees</h2><table><tr>{head}</tr>{_tree_rows(result.trees)}</table>
<h2>Left out</h2><ul>{left or "<li>none</li>"}</ul>
<h2>Warnings</h2><ul>{warn or "<li>none</li>"}</ul>
<p>Made in {f["time_total_s"]:.0f} s. Files: plot.toml (the twin), trees.csv, dtm.asc,
trees/ (each tree's field cloud and the twin's table of it), reconstruct/ (each
tree's QSM as reconstructed), plot_labelled.laz,
from_cloud.json.</p></body></html>
"""
    return write_text(out / TWIN_FILES["report"], html)
