"""Drawing a run's reports beside its science: drawing processes of their own, or inline.

A run's figures are single-threaded matplotlib work that needs only what the run has
already computed. Where the run has idle cores (:func:`drawing_processes`),
:class:`BackgroundDrawer` starts one or two drawing processes when the run starts
(:class:`~treesim.report.child.DrawingProcess`: fresh interpreters, never forks, that
import matplotlib and load its fonts while the run reconstructs), then sends each piece as
soon as its inputs exist: the clouds side by side and the comparison with the mesh's
report while the run compares with the field cloud, that comparison's report when it is
done. The run's report stage then waits only for what is left.

The drawing processes run matplotlib and numpy only (never Open3D, whose thread pools do
not survive a fork), are sent the arrays they draw (pickled) and end with the run
(:func:`treesim._process.exit_with_parent`). Where none can start, or one dies before it
answers, its pieces are drawn in the run's process with the same result, and the
``treesim`` logger says so; an error raised by a piece's drawing is raised again in the
run's process (the drawing process's traceback as its cause). Without idle cores every
piece is drawn in the run's process, in the same order, with the same result: matplotlib
imported by a thread beside the science (:func:`preload_drawing`), the figures in the
report stage.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from .child import CHILD_ENV, ChildDied, DrawingProcess, draw_once

__all__ = ["PROCESSES_ENV", "BackgroundDrawer", "draw_once", "drawing_processes", "preload_drawing"]

#: Environment variable: how many drawing processes a run with full reports starts (``0``:
#: draw inline), instead of :func:`drawing_processes`' choice (benchmarks/bench_reports.py
#: compares them with ``--processes``).
PROCESSES_ENV = "TREESIM_DRAWING_PROCESSES"


def drawing_processes(cores: int | None = None, load: float | None = None) -> int:
    """How many drawing processes a run's reports are drawn by beside it: none inside a
    daemonic process or a drawing process, or without an idle core (the system's
    one-minute load average above ``cores - 1``); one with one to two idle cores; two with
    three or more.

    A drawing process costs its own start-up (an interpreter, numpy, scipy's k-d tree,
    matplotlib: about 0.45 s of CPU more than matplotlib's import in the run's process).
    On an idle core that is free; on a busy one the run pays it. Measured with
    ``benchmarks/bench_reports.py --processes 0,1,2`` on 2 cores (``treesim demo``,
    medians of 3, 2026-11-27): with the host otherwise idle (load 0.5-1.4, the
    benchmark's own runs), drawn inline the reports took 16 % of a 3.1 s run (4.6 s of
    CPU), with one drawing process 11 % of a 3.1 s run (5.0 s of CPU), with two 8 % of a
    3.3 s run (5.7 s); with another job on the cores (load 1.6-2.8, medians of 8), one
    drawing process made the run 0.3 s longer than drawing inline, two 1.1 s.

    Examples
    --------
    >>> drawing_processes(cores=1, load=0.0)
    0
    >>> drawing_processes(cores=2, load=0.3)
    1
    >>> drawing_processes(cores=2, load=1.6)
    0
    >>> drawing_processes(cores=16, load=2.0)
    2
    """
    from .._system import cpu_count

    n = cpu_count() if cores is None else int(cores)
    if load is None:
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # no load average here: assume busy
            load = float(n)
    if (
        n < 2
        or load > n - 1
        or os.environ.get(CHILD_ENV)
        or multiprocessing.current_process().daemon
    ):
        return 0
    return 2 if load <= n - 3 else 1


def preload_drawing() -> threading.Thread:
    """Import matplotlib and load its fonts in a background thread, so that a run that
    draws inline finds them loaded when its report stage begins: the import is mostly
    waiting on files and the run's stages mostly in numerical code, and the two overlap.
    Returns the (daemon) thread.

    Examples
    --------
    >>> preload_drawing().join()
    """

    def load() -> None:
        try:
            from matplotlib import font_manager
            from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
            from matplotlib.figure import Figure  # noqa: F401

            font_manager.get_font(font_manager.findfont("DejaVu Sans"))
        except Exception:  # noqa: BLE001 - the report stage imports it again, and says why
            pass

    thread = threading.Thread(target=load, name="treesim-preload-matplotlib", daemon=True)
    thread.start()
    return thread


def _timed(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float]:
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


class _Children:
    """A drawer's drawing processes, by pid (what :class:`BackgroundDrawer` sends to)."""

    def __init__(self, n: int, preload: Sequence[str] = ()) -> None:
        self._processes: dict[int, DrawingProcess] = {}
        try:
            for _ in range(n):
                child = DrawingProcess(preload=preload)
                self._processes[child.pid] = child
        except BaseException:
            self.close(kill=True)
            raise

    def least_busy(self) -> DrawingProcess | None:
        """The live child with the fewest pieces waiting (the first of equals)."""
        live = [c for c in self._processes.values() if c.proc.poll() is None]
        return min(live, key=lambda c: len(c.pending)) if live else None

    def close(self, *, kill: bool = False) -> None:
        for child in self._processes.values():
            child.close(kill=kill or bool(child.pending))


class BackgroundDrawer:
    """Draws pieces of a run's reports in drawing processes, or inline.

    Parameters
    ----------
    workers : int
        Drawing processes (0: draw inline, in the caller), started now
        (:class:`~treesim.report.child.DrawingProcess`). Where one cannot start, or dies
        before it answers, its pieces are drawn in the caller instead: a report is never
        lost to a drawing process (the ``treesim`` logger says so, and :attr:`fallback`).
    preload : sequence of str
        Modules the drawing processes import while they start (those of the functions
        that will be submitted, beyond the report's own).

    Examples
    --------
    >>> drawer = BackgroundDrawer.start(workers=0)
    >>> drawer.submit("sum", sum, [1, 2])
    >>> drawer.results()["sum"]
    3
    >>> drawer.close()
    """

    def __init__(self, workers: int = 0, preload: Sequence[str] = ()) -> None:
        self._pool: _Children | None = None
        self._jobs: dict[str, tuple[Callable[..., Any], tuple[Any, ...], dict[str, Any]]] = {}
        self._left: list[str] = []  # pieces no drawing process took: drawn when waited for
        self._done: dict[str, Any] = {}
        #: Seconds each piece took where it was drawn (its own process's clock); a
        #: drawing process's start-up (imports, one figure drawn) as ``warm_up_<i>``.
        self.seconds: dict[str, float] = {}
        #: Why pieces meant for a drawing process were drawn here instead (empty: none).
        self.fallback: list[str] = []
        self._gone: set[int] = set()  # drawing processes whose death is in fallback
        if workers > 0:
            try:
                self._pool = _Children(workers, preload)
            except OSError as e:  # no interpreter to start: draw inline
                self._fall_back(f"no drawing process could start ({e}); drawing here")

    @classmethod
    def start(cls, workers: int | None = None, preload: Sequence[str] = ()) -> BackgroundDrawer:
        """A drawer with ``workers`` processes (default: the environment variable
        :data:`PROCESSES_ENV` where set, else :func:`drawing_processes`)."""
        if workers is None:
            chosen = os.environ.get(PROCESSES_ENV, "").strip()
            if chosen.isdigit():
                workers = int(chosen)
            else:
                if chosen:
                    logging.getLogger("treesim").warning(
                        "report drawing: %s=%r is not a whole number of drawing processes "
                        "(0 draws in the run's process); choosing by the idle cores",
                        PROCESSES_ENV,
                        chosen,
                    )
                workers = drawing_processes()
        return cls(workers, preload)

    @property
    def apart(self) -> bool:
        """Whether pieces are drawn in other processes."""
        return self._pool is not None

    @property
    def processes(self) -> int:
        """How many drawing processes were started (0: every piece drawn here)."""
        return 0 if self._pool is None else len(self._pool._processes)

    def _fall_back(self, why: str) -> None:
        self.fallback.append(why)
        logging.getLogger("treesim").warning("report drawing: %s", why)

    def submit(self, key: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Draw ``fn(*args, **kwargs)`` (a module-level function; its arguments are
        pickled) in the least busy drawing process, or now when there is none."""
        if self._pool is None:
            self._done[key], self.seconds[key] = _timed(fn, *args, **kwargs)
            return
        self._jobs[key] = (fn, args, kwargs)
        child = self._pool.least_busy()
        if child is None:
            self._left.append(key)
            self._fall_back(f"no drawing process is left; drawing {key} here")
        else:
            child.send(key, fn, args, kwargs)

    def results(self) -> dict[str, Any]:
        """Wait for every piece; their results by key. A piece that failed raises its
        error here (the drawing processes are stopped first); one whose process died is
        drawn again here."""
        try:
            for i, child in enumerate((self._pool._processes if self._pool else {}).values()):
                self._collect(child)
                if child.warm_up_s is not None:
                    self.seconds[f"warm_up_{i}"] = child.warm_up_s
            for key in self._left:
                fn, args, kwargs = self._jobs[key]
                self._done[key], self.seconds[key] = _timed(fn, *args, **kwargs)
        except BaseException:
            self.close()
            raise
        self._left.clear()
        return {k: self._done[k] for k in self._done}

    def _collect(self, child: DrawingProcess) -> None:
        """Every answer ``child`` owes; after its death, what it had not drawn is drawn
        here (in the order it was sent)."""
        while child.pending:
            try:
                key, result, seconds = child.answer()
                self._done[key], self.seconds[key] = result, seconds
            except ChildDied as e:
                self._gone.add(child.pid)
                self._fall_back(f"{e}; drawing {', '.join(child.pending)} here")
                self._left.extend(child.pending)
                child.pending.clear()
        if child.pid not in self._gone and child.proc.poll() is not None:
            self._gone.add(child.pid)  # died owing nothing: its pieces went elsewhere
            self._fall_back(f"{child._death()}, owing no piece")

    def __enter__(self) -> BackgroundDrawer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the drawing processes (one still drawing is killed: pieces not waited
        for are dropped)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None
