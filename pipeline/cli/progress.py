"""Progress on stderr: one printer for a long step, one bar for a batch.

On a terminal both redraw one line; otherwise (a log file, a pipe, a job runner) they
write one plain line per stage, or per finished tree, so a long command is never silent.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:  # only named: scan, compare, reconstruct need not import the batch engine
    from ..batch import BatchProgress

__all__ = ["BatchProgressBar", "print_warnings", "progress_printer"]


def print_warnings(warnings: list[str]) -> None:
    """Each of a result's warnings (a stage ran, but maybe not as meant) as one line on
    stderr, ``treesim: warning: ...``; the result's JSON keeps them too."""
    for w in warnings:
        print(f"treesim: warning: {w}", file=sys.stderr)


def progress_printer(
    enabled: bool | None = None, *, label: str | None = None
) -> Callable[[float, str], None] | None:
    """A ``progress(fraction, message)`` callback for stderr.

    On a terminal (or with ``enabled`` true) it redraws one line, at most five times a
    second. Otherwise it writes one plain line per stage, when the message changes:
    ``treesim scan: station 2/3 (1.4 s)``, and ``treesim scan: done in 3.2 s`` at the end
    (``label`` names the command). ``enabled`` false: ``None``, no output.
    """
    if enabled is False:
        return None
    if enabled is None and not sys.stderr.isatty():
        return _stage_lines(label)
    last = [0.0]

    def show(fraction: float, message: str) -> None:
        now = time.monotonic()
        if now - last[0] < 0.2 and fraction < 1.0:
            return
        last[0] = now
        sys.stderr.write(f"\r  {message}: {100 * fraction:5.1f} %")
        if fraction >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def _stage_lines(label: str | None) -> Callable[[float, str], None]:
    """One line on stderr per stage (a new message); a finished stage's "done" only at
    the end of the whole command (fraction 1)."""
    prefix = f"treesim {label}:" if label else "treesim:"
    start = time.monotonic()
    last: list[str | None] = [None]

    def show(fraction: float, message: str) -> None:
        elapsed = time.monotonic() - start
        if message == "done":
            if fraction >= 1.0:
                sys.stderr.write(f"{prefix} done in {elapsed:.1f} s\n")
                sys.stderr.flush()
            return
        if message != last[0]:
            last[0] = message
            sys.stderr.write(f"{prefix} {message} ({elapsed:.1f} s)\n")
            sys.stderr.flush()

    return show


def _clock(seconds: float | None) -> str:
    if seconds is None:
        return "?"
    s = int(round(seconds))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class BatchProgressBar:
    """A progress line on ``stream`` (stderr): a redrawn bar on a terminal, one plain line
    per finished tree otherwise.

    Parameters
    ----------
    stream : text stream, optional
        Default ``sys.stderr``.
    tty : bool, optional
        Force the terminal (``True``) or plain (``False``) form; default detect.
    width : int
        Characters of the bar.
    name, noun : str
        What runs and what it counts, plural (``treesim sweep``: ``"sweep"``, ``"points"``).
    """

    def __init__(
        self,
        stream: TextIO | None = None,
        *,
        tty: bool | None = None,
        width: int = 24,
        name: str = "batch",
        noun: str = "trees",
    ):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.width = width
        self.name = name
        self.noun = noun
        self._last_draw = 0.0
        self._drawn = False
        self._started = False
        self._unit = noun

    def __call__(self, p: BatchProgress) -> None:
        if not self._started:
            self._started = True
            # a plot input gives a row per tree: count the inputs, not the trees
            self._unit = "inputs" if p.plots else self.noun
            if not self.tty:  # a log says at once what the batch will do
                noun = self._unit if p.total != 1 else self._unit.removesuffix("s")
                plots = f" ({p.plots} plot{'s' if p.plots != 1 else ''})" if p.plots else ""
                self.stream.write(
                    f"{self.name}: {p.total} {noun}{plots}, {p.reused} unchanged "
                    f"(not run again), {p.total - p.reused} to run\n"
                )
        left = "estimating" if p.eta_s is None else f"~{_clock(p.eta_s)} left"
        if p.finished == p.total and p.running == 0:
            left = "done"
        counts = f"{p.finished}/{p.total} {self._unit} · {p.failed} failed"
        if p.reused:
            counts += f" · {p.reused} unchanged"
        if self.tty:
            now = time.monotonic()
            if p.last is None and now - self._last_draw < 0.5:
                return
            self._last_draw = now
            filled = int(self.width * p.finished / max(p.total, 1))
            bar = "█" * filled + "░" * (self.width - filled)
            line = f"\r[{bar}] {counts} · {p.running} running · {_clock(p.elapsed_s)} · {left}"
            self.stream.write(line.ljust(100)[:120])
            self._drawn = True
            if p.finished == p.total and p.running == 0:
                self.stream.write("\n")
                self._drawn = False
        elif p.last is not None:
            r = p.last
            what = (
                f"failed: {r.get('error_class')}: {r.get('error')}"
                if r["status"] == "failed"
                else ("unchanged, not run again" if r.get("reused") else "ok")
            )
            took = r.get("time_total_s")
            took_s = f" in {took:.1f} s" if isinstance(took, float) and not r.get("reused") else ""
            self.stream.write(f"{self.name}: {counts}; {r['id']} {what}{took_s}; {left}\n")
        self.stream.flush()

    def close(self) -> None:
        """End a half-drawn bar line."""
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False
