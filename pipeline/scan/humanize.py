"""Durations and sizes as short text, for a scan's estimate and its refusals."""

from __future__ import annotations

__all__ = ["human_bytes", "human_time"]


def human_time(seconds: float) -> str:
    """A duration as short text: ``"12 s"``, ``"7 min"``, ``"3.2 h"``, ``"2.1 days"``."""
    if seconds < 120:
        return f"{seconds:.0f} s" if seconds >= 1 else f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    if seconds < 172800:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def human_bytes(n: float) -> str:
    """A size as short text: ``"880 B"``, ``"1.2 MB"``, ``"35 GB"`` (powers of 1000)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} TB"  # pragma: no cover - the loop returns
