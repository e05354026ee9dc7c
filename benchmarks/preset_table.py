"""The preset table, generated from the committed sweep (never typed in).

Reads ``benchmarks/sweeps/presets/sweep.json`` (written by ``benchmarks/bench_sweep.py``)
and writes, with the sweep's date and machine:

* the manual's preset table (``docs/validation.md``), between ``<!-- preset-table:begin -->`` and
  ``<!-- preset-table:end -->``;
* ``pipeline/data/preset_measurements.txt``, the text ``treesim run --help`` prints.

Each preset (``draft``, ``standard``, ``fine``) is a point of the sweep (a ``[[point]]``
with ``preset = ...``); its row shows the figures measured there, and on how many of the
tree's Pareto fronts (time against each accuracy figure) it lies. It also prints, for each
preset and tree, the points of the sweep that beat it (no slower and better in the key
figures), so that a poor choice shows.

Usage: ``python benchmarks/preset_table.py [--sweep PATH] [--check]``; ``--check`` exits 1
when the page or the text file differs from what the sweep gives (nothing written).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import docs_part  # noqa: E402

SWEEP = ROOT / "benchmarks" / "sweeps" / "presets" / "sweep.json"
PAGE = docs_part.VALIDATION
MEASUREMENTS = ROOT / "pipeline" / "data" / "preset_measurements.txt"
PART = "preset-table"  # the part of docs/validation.md between <!-- preset-table:begin/end -->
PRESETS = ("draft", "standard", "fine")


def _ref(tree: dict[str, Any]) -> str:
    return "vs_truth" if tree.get("truth") else "vs_field"


def preset_rows(doc: dict[str, Any]) -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
    """(preset, tree, row) for every preset point of the sweep, by preset then tree."""
    trees = {t["id"]: t for t in doc["trees"]}
    out = []
    for name in PRESETS:
        for tid, tree in trees.items():
            rows = [
                r
                for r in doc["rows"]
                if r["tree"] == tid and name in [s.strip() for s in (r["label"] or "").split(",")]
            ]
            if not rows:
                raise SystemExit(f"{SWEEP.name}: no point of preset {name} on tree {tid}")
            out.append((name, tree, rows[0]))
    return out


def fronts_total(doc: dict[str, Any], tree: str) -> int:
    return sum(1 for per in doc["fronts"].values() if tree in per)


def beaten_by(doc: dict[str, Any], tree: dict[str, Any], row: dict[str, Any]) -> list[str]:
    """Points no slower than ``row`` beyond timing noise (their slowest repeat no slower
    than its fastest) and at least as good in every key figure of the tree, better in
    one: what would make the preset a poor choice."""
    ref = _ref(tree)
    keys = [f"{ref}_accuracy_p95_m", f"{ref}_completeness_p95_m", f"-{ref}_coverage"]
    if tree.get("truth"):
        keys += ["|dbh_error_m", "|volume_error_rel"]

    def val(r: dict[str, Any], k: str) -> float:
        v = r.get(k.lstrip("-|"))
        if v is None:
            return math.inf
        return -v if k.startswith("-") else (abs(v) if k.startswith("|") else v)

    out = []
    for r in doc["rows"]:
        if r["tree"] != tree["id"] or r["status"] != "ok" or r["id"] == row["id"]:
            continue
        a = [r["time_total_max_s"], *(val(r, k) for k in keys)]
        b = [row["time_total_min_s"], *(val(row, k) for k in keys)]
        if all(x <= y for x, y in zip(a, b, strict=True)) and any(
            x < y for x, y in zip(a, b, strict=True)
        ):
            out.append(r["id"])
    return out


def _mm(v: float | None) -> str:
    return "–" if v is None else f"{v * 1000:.1f} mm"


def _pct(v: float | None, signed: bool = False) -> str:
    if v is None:
        return "–"
    return f"{v * 100:+.1f} %" if signed else f"{v * 100:.1f} %"


def _minus(text: str) -> str:
    return text.replace("-", "−")


def _when(doc: dict[str, Any]) -> str:
    m = doc["machine"]
    o3d = doc.get("software", {}).get("open3d", "?")
    return (
        f"{doc['finished'][:10]}, {m['cpu']} ({m['arch']}), {m['cores']} cores, "
        f"Python {m['python']}, open3d {o3d}"
    )


def settings_of(doc: dict[str, Any], name: str) -> dict[str, Any]:
    """What preset ``name`` set where the sweep measured it (its design's settings as
    ``sweep.json`` records them, not the presets of the code as it is now)."""
    designs = [d for d in doc["designs"] if name in d["labels"]]
    if not designs:
        raise SystemExit(f"{SWEEP.name}: no design of preset {name}")
    p = designs[0]["parameters"]
    n = p["reconstruct"]["facets"]
    return {
        "step": p["scan"]["scanner"]["horizontal_resolution_deg"],
        "facets": n,
        "prism": (n / (2 * math.pi)) * math.sin(2 * math.pi / n) - 1,
        "voxel_mm": p["reconstruct"]["prepare"]["voxel_size_m"] * 1000,
        "samples": p["compare"]["max_samples"],
    }


def markdown(doc: dict[str, Any]) -> str:
    """The manual's table, with its heading."""
    tol = doc["tolerance"]["tolerance_m"]
    lines = [
        f"Measured by `benchmarks/bench_sweep.py` ({_when(doc)}; one point at a time, each in "
        "a fresh process; time of the whole loop with its reports, imports excluded; "
        f"coverage at τ = {tol * 1000:.3g} mm) and written here by "
        "`benchmarks/preset_table.py`: each preset is a point of the committed sweep "
        f"`benchmarks/sweeps/presets.toml` ({len(doc['rows'])} points, "
        f"{len(doc['trees'])} trees). Accuracy p95 and coverage are against the truth mesh "
        "for the procedural trees, against the field cloud for the coffee tree; errors are "
        "the reconstruction's against the truth.",
        "",
        "| preset | scan step | facets | voxel | tree | time | peak memory | simulated "
        "points | accuracy p95 | coverage | DBH error | volume error | on Pareto fronts |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, tree, r in preset_rows(doc):
        s = settings_of(doc, name)
        ref = _ref(tree)
        dbh = r["dbh_error_m"]
        dbh_text = "–" if dbh is None else f"{dbh * 1000:+.1f} mm"
        cells = [
            f"`{name}`",
            f"{s['step']:g}°",
            str(s["facets"]),
            f"{s['voxel_mm']:g} mm",
            tree["id"],
            f"{r['time_total_s']:.1f} s",
            f"{r['peak_rss_mib']:.0f} MiB",
            f"{r['points']:,}",
            _mm(r[f"{ref}_accuracy_p95_m"]),
            _pct(r[f"{ref}_coverage"]),
            _minus(dbh_text),
            _minus(_pct(r["volume_error_rel"], signed=True)),
            f"{r['on_fronts']} of {fronts_total(doc, tree['id'])}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def text(doc: dict[str, Any]) -> str:
    """``pipeline/data/preset_measurements.txt``: the same, for ``treesim run --help``."""
    tol = doc["tolerance"]["tolerance_m"]
    lines = [
        "Presets: what they set, and their cost and accuracy as measured by",
        f"benchmarks/bench_sweep.py ({_when(doc)};",
        "one point at a time, each in a fresh process; time of the whole loop with its",
        "reports, imports excluded; accuracy p95 and coverage (within "
        f"{tol * 1000:.3g} mm) against",
        "the truth mesh of the procedural trees, the field cloud of the coffee tree):",
        "",
        "  preset    scan step  facets  mesh volume vs cylinders  voxel  mesh samples",
    ]
    for name in PRESETS:
        s = settings_of(doc, name)
        n = s["samples"]
        samples = f"{n // 1_000_000}M" if n >= 1_000_000 else f"{n // 1000}k"
        prism = f"{s['prism'] * 100:.2g} %"
        lines.append(
            f"  {name:9} {s['step']:.2f} deg   {s['facets']:<7} {prism:<25} "
            f"{s['voxel_mm']:>2.0f} mm  <= {samples}"
        )
    for tree in doc["trees"]:
        truth = tree.get("truth")
        what = (
            f"truth: DBH {truth['dbh_m'] * 100:.2f} cm, {truth['volume_total_m3'] * 1000:.1f} L"
            if truth
            else "no truth"
        )
        lines += [
            "",
            f"  {tree['id']} ({tree['field_points']:,} field points; {what}):",
            "  preset    time    peak mem    points  acc. p95  coverage"
            + ("  DBH error  volume error" if truth else ""),
        ]
        for name, t, r in preset_rows(doc):
            if t["id"] != tree["id"]:
                continue
            ref = _ref(t)
            row = (
                f"  {name:9} {r['time_total_s']:4.1f} s  {r['peak_rss_mib']:4.0f} MiB  "
                f"{r['points']:>8,}  {r[f'{ref}_accuracy_p95_m'] * 1000:5.1f} mm  "
                f"{r[f'{ref}_coverage'] * 100:5.1f} %"
            )
            if truth:
                row += (
                    f"  {r['dbh_error_m'] * 1000:+6.1f} mm  {r['volume_error_rel'] * 100:+9.1f} %"
                )
            lines.append(row)
    lines.append("")
    return "\n".join(lines)


def replace_between(doc_text: str, body: str) -> str:
    """``doc_text`` with the preset table's part replaced by ``body``."""
    return docs_part.replace_between(doc_text, PART, body, str(PAGE))


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--sweep", default=str(SWEEP), help="the sweep.json to read")
    ap.add_argument("--check", action="store_true", help="compare, write nothing")
    args = ap.parse_args()
    doc = json.loads(Path(args.sweep).read_text(encoding="utf-8"))
    page = replace_between(PAGE.read_text(encoding="utf-8"), markdown(doc))
    txt = text(doc)
    if args.check:
        stale = [
            p.name
            for p, new in ((PAGE, page), (MEASUREMENTS, txt))
            if p.read_text(encoding="utf-8") != new
        ]
        if stale:
            print(f"out of date: {', '.join(stale)}; run python benchmarks/preset_table.py")
            return 1
        print(f"{PAGE.name} and preset_measurements.txt match the sweep")
        return 0
    PAGE.write_text(page, encoding="utf-8")
    MEASUREMENTS.write_text(txt, encoding="utf-8")
    print(markdown(doc))
    print()
    print(txt)
    for name, tree, r in preset_rows(doc):
        better = beaten_by(doc, tree, r)
        if better:
            by = ", ".join(better)
            print(f"{name} on {tree['id']}: beaten (no slower, no worse, better in one) by {by}")
        else:
            print(f"{name} on {tree['id']}: no point of the sweep beats it")
    where = f"{PAGE.relative_to(ROOT)} (between the markers), {MEASUREMENTS.relative_to(ROOT)}"
    print(f"wrote {where}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
