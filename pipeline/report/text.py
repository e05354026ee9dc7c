"""Numbers as words: length formatting and the report's plain-language summary."""

from __future__ import annotations

import html
import math
from typing import Any


def lod_reasons(lod: Any) -> list[tuple[str, str]]:
    """(what, why) lines of a scan's level-of-detail account (``ScanResult.lod``): which
    models ran, where, and why; empty for older scans that have none."""
    if not isinstance(lod, dict):
        return []
    out = []
    for key in ("rays", "geometry", "beam", "facets"):
        entry = lod.get(key)
        if isinstance(entry, dict) and isinstance(entry.get("why"), str):
            out.append((key, f"{entry['why']} (lod {lod.get('mode', '?')})"))
    return out


def length(x: float | None) -> str:
    """A distance in metres as short text: ``"4.2 mm"``, ``"0.283 m"``, ``"< 0.001 mm"``."""
    if x is None or not math.isfinite(x):
        return "n/a"
    if x < 1e-6:
        return "< 0.001 mm"
    if x < 0.1:
        return f"{x * 1e3:.3g} mm"
    return f"{x:.3g} m"


def mm(x: float | None, decimals: int = 3) -> str:
    """A distance in metres as millimetres with fixed decimals (for tables)."""
    return "–" if x is None else f"{x * 1e3:,.{decimals}f}"


def cell(v: Any, unit: str = "", scale: float = 1.0, digits: int = 3) -> str:
    """A value as an HTML table cell's text: ``–`` when missing, ``yes``/``no``, integers
    with thousands separators, floats × ``scale`` to ``digits`` significant digits."""
    if v is None or v == "":
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return f"{v:,}{unit}"
    if isinstance(v, float):
        return f"{v * scale:.{digits}g}{unit}"
    return html.escape(str(v))


def percent(f: float | None, decimals: int = 1) -> str:
    """A fraction 0-1 as a percentage (``"62.4 %"``)."""
    return "n/a" if f is None else f"{100 * f:.{decimals}f} %"


def _ref_words(summary: dict[str, Any]) -> tuple[str, str]:
    kind = summary.get("reference", {}).get("kind", "mesh")
    if kind == "mesh":
        return "the mesh", "of the mesh surface"
    return "the reference cloud", "of the reference cloud"


#: Distances below this (m) are float rounding, not measurement: a p99 accuracy under it
#: makes a comparison trivially exact.
FLOAT_NOISE_M = 1e-6


def trivially_exact(summary: dict[str, Any]) -> bool:
    """Whether the cloud lies on the reference to float rounding (accuracy p99 under
    :data:`FLOAT_NOISE_M`)."""
    p99 = summary["accuracy"].get("p99_m")
    return p99 is not None and p99 < FLOAT_NOISE_M


def exactness_note(summary: dict[str, Any]) -> str | None:
    """A note for a trivially exact comparison (:func:`trivially_exact`): what its
    accuracy does and does not say; ``None`` otherwise."""
    if not trivially_exact(summary):
        return None
    acc = summary["accuracy"]
    scan = (summary.get("inputs") or {}).get("scan") or {}
    noise = [m for m in scan.get("models_active") or [] if "noise" in m or "jitter" in m]
    if scan and not noise and summary.get("reference", {}).get("kind") == "mesh":
        what = (
            "a scan without noise models against the mesh it was scanned from: every "
            "point is a ray's hit on that mesh, so it lies on it by construction"
        )
    else:
        what = "the cloud lies on the reference to float rounding"
    return (
        f"This comparison is trivially exact ({what}). Its accuracy (p99 "
        f"{_tiny(acc['p99_m'])}, farthest {_tiny(acc['max_m'])}) is float rounding, not a "
        "measurement, and says nothing about the scanner; the accuracy plots are drawn on "
        "the scale of τ for that reason. What this comparison measures is completeness: "
        "the coverage, and where the surface was not seen."
    )


def _tiny(x: float | None) -> str:
    """A distance that may be nanometres: ``"0.42 nm"``, ``"3.1 µm"`` or :func:`length`."""
    if x is None or not math.isfinite(x):
        return "n/a"
    if x < 1e-6:
        return f"{x * 1e9:.2g} nm"
    if x < 1e-4:
        return f"{x * 1e6:.2g} µm"
    return length(x)


def hidden_sentence(summary: dict[str, Any]) -> str:
    """What a mesh comparison left out as hidden surface, and why ("" when nothing)."""
    ref = summary.get("reference", {})
    hid = ref.get("hidden_surface")
    if not isinstance(hid, dict) or not hid.get("samples_dropped"):
        return ""
    return (
        f"{hid['area_m2']:.3g} m² ({percent(hid.get('area_share'))}) of the mesh's "
        f"{ref.get('area_m2', 0.0):.3g} m² lies inside other closed parts of it (buried "
        f"end caps, branch bases inside their parents), where no scanner can see; it is "
        f"left out of completeness and coverage."
    )


def summary_paragraph(summary: dict[str, Any]) -> str:
    """One plain-language paragraph from a comparison's figures (no markup)."""
    acc = summary["accuracy"]
    comp = summary["completeness"]
    cov = summary["coverage"]
    tau = summary["tolerance_m"]
    ref, ref_surface = _ref_words(summary)
    n = summary.get("cloud", {}).get("points", acc["n"])
    stations = summary.get("by_station", {})
    who = f"The cloud ({n:,} points"
    who += f" from {len(stations)} stations)" if len(stations) > 1 else ")"
    parts: list[str] = []
    if acc["p95_m"] is not None and acc["p95_m"] < 1e-6:
        parts.append(
            f"{who} lies on {ref} to numerical precision: 95 % of its points are within "
            f"0.001 mm, the farthest {length(acc['max_m'])} away."
        )
    else:
        parts.append(
            f"{who} lies within {length(acc['p95_m'])} of {ref} for 95 % of its points "
            f"(median {length(acc['median_m'])}, farthest {length(acc['max_m'])})."
        )
    if cov >= 0.995:
        parts.append(
            f"It covers practically all {ref_surface} ({percent(cov)}) within τ = {length(tau)}."
        )
    else:
        parts.append(
            f"It covers {percent(cov)} {ref_surface} within τ = {length(tau)}; the other "
            f"{percent(1 - cov)} lies farther than τ from every point (occluded, or outside "
            f"the scanners' view), the farthest part {length(comp['max_m'])} away."
        )
    hidden = hidden_sentence(summary)
    if hidden:
        parts.append(hidden)
    labels = {
        k: v
        for k, v in summary.get("by_label", {}).items()
        if v.get("coverage") is not None and k in ("wood", "leaf", "ground")
    }
    if len(labels) > 1:
        bits = [f"{k} {percent(v['coverage'], 0)}" for k, v in labels.items()]
        parts.append("Coverage by part: " + ", ".join(bits) + ".")
    if len(stations) > 1:
        best_k, best = max(stations.items(), key=lambda kv: kv[1]["coverage"])
        parts.append(
            f"Station {best_k} alone covers the most ({percent(best['coverage'], 0)}); "
            f"{'both' if len(stations) == 2 else f'all {len(stations)}'} together cover "
            f"{percent(cov, 0)}."
        )
    parts.append(
        f"The symmetric Hausdorff distance is {length(summary['hausdorff_m'])} and the "
        f"Chamfer distance (mean of both directions' mean distances) "
        f"{length(summary['chamfer_m'])}."
    )
    return " ".join(parts)
