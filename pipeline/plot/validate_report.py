"""The report of ``treesim validate``: ``validation.json``, the figures (density by height
and by range per station, coverage by tree, the occlusion profile, distances both ways) and
a self-contained ``validation.html``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..report.figures import save_png
from .validate import VALIDATION_FILES, ValidationResult

__all__ = ["write_validation"]

REAL_COLOUR = "#2c6e9b"
SIM_COLOUR = "#c2612d"


def _panels(n: int, w: float = 3.2, h: float = 3.4) -> tuple[Any, list[Any]]:
    from ..report.figures import _new_figure

    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig = _new_figure(w * cols + 0.6, h * rows)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, list(axes[:n])


def _title(g: str) -> str:
    return "all stations" if g == "all" else f"station {g}"


def plot_density_by_height(result: ValidationResult, path: Path) -> Path:
    """One panel per station: points per height bin, real and simulated."""
    prof = result.density_by_height
    e = np.asarray(prof["edges_m"])
    mid = 0.5 * (e[1:] + e[:-1])
    fig, axes = _panels(len(result.groups))
    for ax, g in zip(axes, result.groups, strict=True):
        p = prof["per_station"][g]
        ax.plot(p["real"], mid, "-o", ms=3, color=REAL_COLOUR, label="field scan")
        ax.plot(p["simulated"], mid, "-s", ms=3, color=SIM_COLOUR, label="simulated")
        r = result.density["per_station"][g]["density_ratio"]
        ax.set_title(_title(g) + ("" if r is None else f" (ratio {r:.2f})"))
        ax.set_xlabel("points per bin")
        ax.set_ylabel("height above terrain (m)")
        ax.set_xscale("symlog", linthresh=10)
    axes[0].legend(fontsize=8)
    return save_png(fig, path)


def plot_density_by_range(result: ValidationResult, path: Path) -> Path:
    """One panel per station: points per range bin from the station, real and simulated."""
    prof = result.density_by_range
    assert prof is not None
    e = np.asarray(prof["edges_m"])
    mid = 0.5 * (e[1:] + e[:-1])
    fig, axes = _panels(len(result.groups), h=3.0)
    for ax, g in zip(axes, result.groups, strict=True):
        p = prof["per_station"][g]
        ax.plot(mid, p["real"], "-o", ms=3, color=REAL_COLOUR, label="field scan")
        ax.plot(mid, p["simulated"], "-s", ms=3, color=SIM_COLOUR, label="simulated")
        diff = result.density["per_station"][g]["range_profile_difference"]
        ax.set_title(_title(g) + ("" if diff is None else f" (difference {diff:.2f})"))
        ax.set_xlabel("range from the station (m)")
        ax.set_ylabel("points per bin")
        ax.set_yscale("symlog", linthresh=10)
    axes[0].legend(fontsize=8)
    return save_png(fig, path)


def _pct(part: dict[str, Any] | None, key: str) -> float:
    v = None if part is None else part[key]
    return math.nan if v is None else 100.0 * v


def _coverage_bars(ax: Any, rows: list[dict[str, Any]], part: str | None, tau_m: float) -> None:
    """Real and simulated coverage per tree: of the whole tree (``part`` None) or of its
    ``stem`` or ``crown`` (no bar for a tree without a table)."""
    x = np.arange(len(rows))
    cr = [_pct(t if part is None else t[part], "coverage_real") for t in rows]
    cs = [_pct(t if part is None else t[part], "coverage_simulated") for t in rows]
    ax.bar(x - 0.2, np.nan_to_num(cr), 0.4, color=REAL_COLOUR, label="field scan")
    ax.bar(x + 0.2, np.nan_to_num(cs), 0.4, color=SIM_COLOUR, label="simulated")
    ax.set_xticks(x, [str(t["tree_id"]) for t in rows])
    ax.set_ylim(0, 100)
    what = "tree" if part is None else part
    ax.set_ylabel(f"{what} within τ = {tau_m * 1e3:g} mm (%)")


def plot_coverage_by_tree(result: ValidationResult, path: Path) -> Path:
    """Each twin tree's coverage at τ, real and simulated: the whole tree, and (trees with
    a cylinder table) its stem and its crown in panels below."""
    from ..report.figures import _new_figure

    rows = result.trees or []
    parts = [p for p in ("stem", "crown") if any(t[p] for t in rows)]
    fig = _new_figure(min(11.0, 2.0 + 0.45 * len(rows)), 3.0 * (1 + len(parts)) + 0.4)
    axes = fig.subplots(1 + len(parts), 1, squeeze=False).ravel()
    tau = result.parameters["tau_m"]
    for ax, part in zip(axes, [None, *parts], strict=True):
        _coverage_bars(ax, rows, part, tau)
    axes[-1].set_xlabel("tree")
    axes[0].legend(fontsize=8)
    return save_png(fig, path)


def plot_occlusion_profile(result: ValidationResult, path: Path) -> Path:
    """The twin trees' coverage by height band, real and simulated: of the whole trees,
    and (trees with a table) of their stems and their crowns beside."""
    from ..report.figures import _new_figure

    prof = result.occlusion_profile
    assert prof is not None
    e = np.asarray(prof["edges_m"])
    mid = 0.5 * (e[1:] + e[:-1])
    panels = [("whole trees", prof)] + [
        (f"{p}s", prof[p]) for p in ("stem", "crown") if prof.get(p) is not None
    ]
    fig = _new_figure(4.2 * len(panels) + 0.6, 4.2)
    axes = fig.subplots(1, len(panels), squeeze=False, sharey=True).ravel()
    for ax, (title, band) in zip(axes, panels, strict=True):
        for key, colour, label in (
            ("coverage_real", REAL_COLOUR, "field scan"),
            ("coverage_simulated", SIM_COLOUR, "simulated"),
        ):
            v = np.array([np.nan if c is None else 100 * c for c in band[key]])
            ax.plot(v, mid, "-o", ms=3, color=colour, label=label)
        ax.set_xlim(0, 100)
        ax.set_title(title)
        ax.set_xlabel(f"surface within τ = {prof['tau_m'] * 1e3:g} mm (%)")
    axes[0].set_ylabel("height above terrain (m)")
    axes[0].legend(fontsize=8)
    return save_png(fig, path)


def plot_distances(result: ValidationResult, path: Path) -> Path:
    """Histograms of the two directions' distances, and each station's p95."""
    from ..report.figures import _new_figure

    d = result.distances
    h = d["histogram"]
    e = np.asarray(h["edges_m"]) * 1e3
    fig = _new_figure(10.0, 3.4)
    a, b = fig.subplots(1, 2)
    for key, colour, label in (
        ("real_to_simulated", REAL_COLOUR, "field → simulated"),
        ("simulated_to_real", SIM_COLOUR, "simulated → field"),
    ):
        a.stairs(h[key], e, color=colour, label=label, linewidth=1.5)
    a.set_xlabel("nearest-neighbour distance (mm; the last bin holds the farthest 1 %)")
    a.set_ylabel("points")
    a.legend(fontsize=8)
    per = d["by_station"] or {"all": d}
    x = np.arange(len(per))
    for off, key, colour in (
        (-0.2, "real_to_simulated", REAL_COLOUR),
        (0.2, "simulated_to_real", SIM_COLOUR),
    ):
        vals = [1e3 * (v[key]["p95_m"] or 0.0) for v in per.values()]
        b.bar(x + off, vals, 0.4, color=colour)
    b.set_xticks(x, [_title(g) for g in per])
    b.set_ylabel("p95 distance (mm)")
    return save_png(fig, path)


def _fmt(v: Any, scale: float = 1.0, digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, int):
        return f"{v:,}"
    return f"{v * scale:,.{digits}f}"


def _table(head: list[str], rows: list[list[str]]) -> str:
    from html import escape

    th = "".join(f"<th>{escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _station_rows(result: ValidationResult) -> list[list[str]]:
    rows = []
    offsets = result.stations["offset_m"] or [None] * len(result.groups)
    for g, off in zip(result.groups, offsets, strict=False):
        v = result.density["per_station"][g]
        dist = result.distances["by_station"].get(g, result.distances)
        rows.append(
            [
                _title(g),
                _fmt(v["points_real"]),
                _fmt(v["points_simulated"]),
                _fmt(v["density_ratio"]),
                _fmt(v["height_profile_difference"]),
                _fmt(v["range_profile_difference"]),
                _fmt(dist["real_to_simulated"]["p95_m"], 1e3, 1),
                _fmt(dist["simulated_to_real"]["p95_m"], 1e3, 1),
                _fmt(off),
            ]
        )
    return rows


def _tree_rows(result: ValidationResult) -> list[list[str]]:
    rows = []
    for t in result.trees or []:
        row = [
            str(t["tree_id"]),
            _fmt(t["points_real"]),
            _fmt(t["points_simulated"]),
            _fmt(t["coverage_real"], 100, 1),
            _fmt(t["coverage_simulated"], 100, 1),
            _fmt(t["coverage_difference_points"], 1, 1),
        ]
        for part in ("stem", "crown"):
            p = t[part] or {}
            row += [
                _fmt(p.get("coverage_real"), 100, 1),
                _fmt(p.get("coverage_simulated"), 100, 1),
                _fmt(p.get("coverage_difference_points"), 1, 1),
            ]
        rows.append(row)
    return rows


def _verdict_html(result: ValidationResult) -> str:
    """The criteria of the verdict: each one's worst value, its bound, met or not."""
    from html import escape

    v = result.verdict
    rows = []
    for name, c in v.get("criteria", {}).items():
        value, bound = c["value"], c["bound"]
        show = (
            "–"
            if value is None
            else "–".join(_fmt(float(x)) for x in value)
            if isinstance(value, list)
            else _fmt(float(value))
        )
        limit = "–".join(f"{b:g}" for b in bound) if isinstance(bound, list) else f"{bound:g}"
        met = {True: "met", False: "<strong>not met</strong>", None: "does not apply"}
        rows.append([escape(name), show, limit, met[c["passed"]]])
    parts = f"<p>{escape(v['parts'])}</p>" if v.get("parts") else ""
    return parts + _table(["criterion", "worst value", "bound", ""], rows)


def _html(result: ValidationResult, images: dict[str, Path], names: tuple[str, str]) -> str:
    from html import escape

    from ..report import assets
    from ..report.html import _img, _kv_table

    def fig(key: str, alt: str) -> str:
        return _img(images[key], alt, 110) if key in images else ""

    p = result.parameters
    kv = _kv_table(
        [
            ("field scan", escape(f"{names[0]} ({p['points_real']:,} points)")),
            ("simulated scan", escape(f"{names[1]} ({p['points_simulated']:,} points)")),
            ("compared region", escape(p["region"])),
            ("points compared", f"{p['points_in_region_real']:,} field, "
             f"{p['points_in_region_simulated']:,} simulated"),
            ("stations from", escape(result.stations["source"])),
            ("τ", f"{p['tau_m'] * 1e3:g} mm"),
        ]
    )  # fmt: skip
    notes = "".join(f"<li>{escape(n)}</li>" for n in result.notes + result.warnings)
    verdict = _verdict_html(result)
    station_head = [
        "station", "field points", "simulated points", "ratio", "height-profile diff.",
        "range-profile diff.", "p95 field→sim (mm)", "p95 sim→field (mm)", "offset (m)",
    ]  # fmt: skip
    tree_head = ["tree", "field points", "simulated points", "field coverage (%)",
                 "simulated coverage (%)", "difference (points)", "stem: field (%)",
                 "stem: simulated (%)", "stem: difference", "crown: field (%)",
                 "crown: simulated (%)", "crown: difference"]  # fmt: skip
    trees = (
        _table(tree_head, _tree_rows(result))
        if result.trees is not None
        else '<p class="note">no twin given: the tree coverage needs the plot.toml</p>'
    )
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>treesim validation: {escape(names[1])} vs {escape(names[0])}</title>
<script>{assets.ERROR_HOOK_JS}</script><style>{assets.CSS}</style></head><body>
<header class="top"><div class="wrap"><div class="eyebrow">treesim · scan validation</div>
<h1>{escape(names[1])}<span class="vs">vs</span>{escape(names[0])}</h1>
<p class="meta">{escape(result.summary)}</p></div></header>
<main class="wrap">
<section class="panel"><h2>Inputs</h2>{kv}<ul>{notes}</ul></section>
<section class="panel"><h2>Verdict</h2>{verdict}</section>
<section class="panel"><h2>Stations</h2>{_table(station_head, _station_rows(result))}</section>
<section class="panel"><h2>Density by height</h2>{fig("density_by_height", "density by height")}
</section>
<section class="panel"><h2>Density by range</h2>{
        fig("density_by_range", "density by range")
        or '<p class="note">no station positions known</p>'
    }</section>
<section class="panel"><h2>Trees</h2>{trees}{fig("coverage_by_tree", "coverage by tree")}
{fig("occlusion_profile", "occlusion profile")}</section>
<section class="panel"><h2>Distances</h2>{fig("distances", "distances")}</section>
</main></body></html>
"""


def write_validation(
    result: ValidationResult, outdir: str | Path, *, names: tuple[str, str] = ("field", "simulated")
) -> list[Path]:
    """Write ``validation.json``, the figures and ``validation.html`` into ``outdir``.

    The coverage figures are drawn only with a twin, the density by range only with
    station positions. ``names`` are the field and simulated scans' names for the page.
    Returns the written paths.

    Examples
    --------
    >>> from treesim.plot.validate import validate_scans
    >>> from treesim.plot.validate_report import write_validation
    >>> paths = write_validation(validate_scans(real, sim), "validation/")  # doctest: +SKIP
    """
    from ..atomic import write_text
    from ..jsonio import write_json

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    f = VALIDATION_FILES
    written = [write_json(out / f["json"], result.to_dict())]
    draw = {"density_by_height": plot_density_by_height, "distances": plot_distances}
    if result.density_by_range is not None:
        draw["density_by_range"] = plot_density_by_range
    if result.trees is not None:
        draw["coverage_by_tree"] = plot_coverage_by_tree
        draw["occlusion_profile"] = plot_occlusion_profile
    images = {key: fn(result, out / f[key]) for key, fn in draw.items()}
    written += list(images.values())
    written.append(write_text(out / f["html"], _html(result, images, names)))
    return written
