"""The batch's index page: ``index.html`` listing every tree of a ``treesim batch``."""

from __future__ import annotations

import html
from collections.abc import Sequence
from typing import Any

from .text import cell

__all__ = ["batch_index_page"]


def batch_index_page(
    rows: list[dict[str, Any]],
    counts: dict[str, int],
    *,
    skipped_files: Sequence[tuple[Any, str]] = (),
    interrupted: bool = False,
    executor: str = "",
    elapsed_s: float = 0.0,
) -> str:
    """The batch's ``index.html``: one row per tree, linking each tree's run page.

    Parameters
    ----------
    rows : list of dict
        ``summary.json``'s tree rows (``id``, ``status``, ``reused``, figures, ...).
    counts : dict
        ``trees``, ``ok``, ``failed``, ``not_run``, ``reused``.
    skipped_files : sequence of (path, reason)
        Input files that were not trees.
    interrupted : bool
        Whether the batch stopped before every tree ran.
    executor : str
        Where the trees ran, in words.
    elapsed_s : float
        The batch's wall time.
    """
    esc = html.escape
    head = (
        "<tr><th>tree</th><th>status</th><th>DBH</th><th>height</th><th>wood volume</th>"
        "<th>scan points</th><th>coverage of the mesh</th><th>p95 to field cloud</th>"
        "<th>coverage of the field cloud</th><th>time</th></tr>"
    )
    body = []
    for r in rows:
        tid = esc(str(r["id"]) + (f" #{r['tree_id']}" if r.get("tree_id") is not None else ""))
        if r["status"] == "ok":
            name = f'<a href="{esc(str(r["report"]))}">{tid}</a>'
            status = "ok (unchanged)" if r["reused"] else "ok"
        elif r["status"] == "failed":
            err = esc(f"{r.get('error_class')}: {r.get('error')}")
            link = (
                f' (<a href="{esc(str(r["folder"]))}/error.json">error.json</a>)'
                if r.get("folder")
                else ""
            )
            name, status = tid, f'<span class="bad">failed</span>: {err}{link}'
        else:
            name, status = tid, esc(str(r["status"]))
        body.append(
            f"<tr><td>{name}</td><td class='l'>{status}</td>"
            f"<td>{cell(r.get('dbh_m'), ' cm', 100)}</td>"
            f"<td>{cell(r.get('height_m'), ' m')}</td>"
            f"<td>{cell(r.get('volume_total_m3'), ' L', 1000)}</td>"
            f"<td>{cell(r.get('scan_points'))}</td>"
            f"<td>{cell(r.get('vs_mesh_coverage'), ' %', 100)}</td>"
            f"<td>{cell(r.get('vs_field_accuracy_p95_m'), ' mm', 1000)}</td>"
            f"<td>{cell(r.get('vs_field_coverage'), ' %', 100)}</td>"
            f"<td>{cell(r.get('time_total_s'), ' s', digits=2)}</td></tr>"
        )
    skipped = ""
    if skipped_files:
        items = "".join(f"<li>{esc(str(p))}: {esc(why)}</li>" for p, why in skipped_files)
        skipped = f"<h2>Files skipped</h2><ul>{items}</ul>"
    note = " (interrupted: run the same command again to finish)" if interrupted else ""
    return f"""<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>treesim batch</title><style>
body{{font:15px/1.45 system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#222;
padding:0 1em}}
table{{border-collapse:collapse}}td,th{{padding:.25em .7em;border-bottom:1px solid #eee;
text-align:right}}td:first-child,th:first-child,.l{{text-align:left}}.bad{{color:#b00}}
a{{color:#0a58ca}}.muted{{color:#777}}</style></head><body>
<h1>treesim batch</h1>
<p>{counts["trees"]} trees: {counts["ok"]} ok ({counts["reused"]} unchanged from an earlier
run), {counts["failed"]} failed, {counts["not_run"]} not run{note}.
<span class="muted">{esc(executor)}; {elapsed_s:.1f} s.
Figures of every tree: <a href="summary.csv">summary.csv</a>,
<a href="summary.json">summary.json</a>.</span></p>
<table>{head}{"".join(body)}</table>{skipped}</body></html>
"""
