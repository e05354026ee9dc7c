"""Reports of a comparison: ``report.json``, PNG plots and one offline HTML page.

``build_report(source, outdir)`` takes a :class:`~treesim.compare.Comparison` or the
folder (or ``comparison.json``) that ``treesim compare`` wrote, and writes:

* ``report.json``: the figures, the parameters, the plain-language summary and the
  software versions;
* ``histograms.png``, ``cumulative.png``: the distance distributions of both directions;
* ``views_accuracy.png``, ``views_completeness.png``: side and top views of the cloud and
  of the reference samples coloured by distance;
* ``coverage.png``: coverage by station (and by hit label);
* ``occlusion.png``: the occlusion profile, coverage and point density by height slice,
  per station and all together (:mod:`treesim.report.profile`; its numbers in
  ``report.json``'s ``occlusion_profile``);
* ``report.html``: all of it in one self-contained page (images and data inline, no
  external resources), with an interactive 3D view of a subsample.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from pathlib import Path
from typing import Any

from ..atomic import write_text
from ..compare import COMPARISON_FIGURES, Comparison
from ..errors import InvalidParameterError
from ..jsonio import write_json
from ..params import ReportParams
from . import figures
from .data import ReportData, report_software
from .html import build_html
from .profile import occlusion_profile
from .text import exactness_note, summary_paragraph, trivially_exact

__all__ = [
    "PNG_FILES",
    "ReportData",
    "ReportParams",
    "build_report",
    "draw_report",
    "remove_report",
    "summary_paragraph",
]

#: The PNG files a report writes, by key.
PNG_FILES = {
    "histograms": "histograms.png",
    "cumulative": "cumulative.png",
    "views_accuracy": "views_accuracy.png",
    "views_completeness": "views_completeness.png",
    "coverage": "coverage.png",
    "occlusion": "occlusion.png",
}


def build_report(
    source: Comparison | ReportData | str | Path,
    outdir: str | Path | None = None,
    *,
    params: ReportParams | None = None,
    inputs: dict[str, Any] | None = None,
) -> dict[str, Path]:
    """Write ``report.json``, the PNG plots and ``report.html``.

    Parameters
    ----------
    source : Comparison, ReportData, or path
        A comparison in memory, or the folder / ``comparison.json`` written by
        ``treesim compare`` (its distance clouds must sit beside it).
    outdir : str or Path, optional
        Where to write; default the folder of ``comparison.json`` (required for an
        in-memory comparison).
    params : ReportParams, optional
    inputs : dict, optional
        For an in-memory comparison: input facts to show (``cloud``, ``reference`` paths).

    Returns
    -------
    dict of str -> Path
        ``report_json``, ``report_html`` and one entry per PNG (see :data:`PNG_FILES`).

    Examples
    --------
    >>> import treesim as ts
    >>> comparison = ts.compare(ts.read_cloud("scan.laz"), "tree.ply")  # doctest: +SKIP
    >>> ts.build_report(comparison, "out/report")["html"]  # doctest: +SKIP
    """
    params = params or ReportParams()
    if isinstance(source, Comparison):
        data = ReportData.from_comparison(source, inputs=inputs)
    elif isinstance(source, ReportData):
        data = source
    else:
        data = ReportData.from_file(source)
    if outdir is None:
        if data.source_dir is None:
            raise InvalidParameterError("give outdir for a comparison held in memory")
        outdir = data.source_dir
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    s = data.summary
    s["report_software"] = {"matplotlib": report_software("matplotlib")["matplotlib"]}

    pngs = {key: out / name for key, name in PNG_FILES.items()}
    not_drawn = {}
    if params.plots and trivially_exact(s):
        # every point coloured 0: a view that shows nothing the histogram does not say
        not_drawn["views_accuracy"] = "every distance is float rounding, nothing to colour"
    for key in not_drawn if params.plots else list(pngs):
        pngs.pop(key).unlink(missing_ok=True)  # and no plot of an earlier report stays
    # the occlusion profile's numbers (k-d tree queries, which release the GIL) computed
    # by a thread while the figures that do not need them are drawn
    with ThreadPoolExecutor(1, thread_name_prefix="treesim-profile") as pool:
        profile_job = pool.submit(occlusion_profile, data, bin_m=params.profile_bin_m)
        if pngs:
            # each PNG encoded while the next figure is drawn; no garbage collection between
            with figures.gc_paused(), figures.writing_behind():
                _draw(data, pngs, params, profile_job.result)
        profile = profile_job.result()

    paragraph = summary_paragraph(s)
    generated = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    page = build_html(
        data,
        pngs,
        paragraph,
        generated=generated,
        max_view_points=params.max_view_points,
        seed=params.seed,
        dpi=params.dpi,
        profile=profile,
        not_drawn=not_drawn,
    )
    html_path = out / "report.html"
    write_text(html_path, page)

    report = {
        "kind": "treesim.report",
        "generated": generated,
        "summary": paragraph,
        "notes": [n for n in (exactness_note(s),) if n],
        "not_drawn": not_drawn,
        "figures": {k: s[k] for k in COMPARISON_FIGURES if k in s},
        "occlusion_profile": profile,
        "parameters": {**s.get("parameters", {}), "report": asdict(params)},
        "inputs": s.get("inputs", {}),
        "definitions": s.get("definitions", {}),
        "software": {**s.get("software", {}), **s["report_software"]},
        "files": {"report_html": html_path.name, **{k: p.name for k, p in pngs.items()}},
    }
    json_path = out / "report.json"
    write_json(json_path, report)
    return {"report_json": json_path, "report_html": html_path, **pngs}


def remove_report(folder: str | Path) -> list[Path]:
    """Remove a report that :func:`build_report` wrote into ``folder`` (``report.json``,
    ``report.html``, the PNG plots), so that no stale report stays beside a comparison
    that a run chose not to report (``report.level = "none"``). Returns what it removed.

    Examples
    --------
    >>> import treesim as ts
    >>> ts.report.remove_report("out/run/vs_mesh")  # doctest: +SKIP
    []
    """
    gone = []
    for name in ("report.json", "report.html", *PNG_FILES.values()):
        p = Path(folder) / name
        if p.is_file():
            p.unlink()
            gone.append(p)
    return gone


def _draw(
    data: ReportData,
    pngs: dict[str, Path],
    params: ReportParams,
    profile: Callable[[], dict[str, Any]],
) -> None:
    """The PNG plots of one report (``profile()``: the occlusion profile's numbers, asked
    for last)."""
    s = data.summary
    figures.histograms(data, pngs["histograms"], dpi=params.dpi)
    figures.cumulative(data, pngs["cumulative"], dpi=params.dpi)
    ref_word = figures._ref_word(s)
    stations = [
        (int(st["index"]), st["position_m"])
        for st in ((s.get("inputs") or {}).get("scan") or {}).get("stations", []) or []
        if "index" in st and "position_m" in st
    ]
    if "views_accuracy" in pngs:
        figures.views(
            data.cloud_points,
            data.cloud_distance_m,
            figures.accuracy_colour_limit(s),
            pngs["views_accuracy"],
            title=f"Cloud coloured by distance to the {ref_word} (accuracy)",
            colour_label=f"distance to the {ref_word}",
            origin=data.origin,
            max_points=params.max_plot_points,
            seed=params.seed,
            dpi=params.dpi,
        )
    figures.views(
        data.reference_points,
        data.reference_distance_m,
        figures.completeness_colour_limit(s),
        pngs["views_completeness"],
        title=f"{ref_word.capitalize()} coloured by distance to the cloud (completeness)",
        colour_label="distance to the cloud",
        origin=data.origin,
        stations=stations or None,
        tau_m=float(s["tolerance_m"]),
        max_points=params.max_plot_points,
        seed=params.seed + 1,
        dpi=params.dpi,
    )
    figures.coverage_bars(data, pngs["coverage"], dpi=params.dpi)
    figures.occlusion_profile(profile(), pngs["occlusion"], ref_word=ref_word, dpi=params.dpi)


def draw_report(
    folder: Path, params: ReportParams, data: ReportData | None = None
) -> dict[str, Path]:
    """:func:`build_report` of a comparison folder, as one job a drawing process takes
    (:class:`treesim.report.background.BackgroundDrawer`: module-level and picklable);
    ``data``, where given, is what the folder holds (:meth:`ReportData.from_written`:
    a run that has the comparison in memory need not read its clouds again).

    Examples
    --------
    >>> draw_report(Path("out/vs_field"), ReportParams())  # doctest: +SKIP
    {'html': PosixPath('out/vs_field/report.html'), ...}
    """
    return build_report(folder if data is None else data, folder, params=params)
