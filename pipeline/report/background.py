"""Drawing a run's reports beside its science: a small pool of forked processes.

A run's figures are single-threaded matplotlib work that needs only what the run has
already written. :class:`BackgroundDrawer` forks its drawing processes when a run starts
(they import matplotlib and load its fonts while the run reconstructs), then draws each
piece as soon as its inputs exist: the clouds side by side after the scan, a comparison's
report after that comparison is written, while the run goes on comparing. The run's
report stage then waits only for what is left.

The drawing processes run matplotlib and numpy only, never Open3D (whose thread pools
do not survive a fork: the scanner's and the comparisons' processes are spawned), and
each ends with the run that forked it (:func:`treesim._process.exit_with_parent`).

It pays where the run has idle cores to spare (:func:`parallel_pays`) and processes can
be forked (Linux: a forked child needs no re-import of the caller's script, which a
spawned one would run again). Elsewhere, in a daemonic process (a pool's worker, which may not
have children) or when the pool cannot start, nothing is forked and every piece is drawn
in the calling process, in the same order, with the same result.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

__all__ = ["BackgroundDrawer", "parallel_pays", "preload_drawing"]


def parallel_pays(cores: int | None = None, load: float | None = None) -> bool:
    """Whether a run's reports are drawn by forked processes beside it: on Linux, outside
    a daemonic process, with at least two cores for this process of which at least two
    are idle (the system's one-minute load average at most ``cores - 2``). On a machine
    whose cores are busy with other work, drawing processes only take turns with the
    run's own threads: measured on 2 shared cores (load 4-6), the report stage took as
    long forked as inline.

    Examples
    --------
    >>> parallel_pays(cores=1, load=0.0)
    False
    >>> parallel_pays(cores=16, load=20.0)
    False
    """
    from .._system import cpu_count

    n = cpu_count() if cores is None else int(cores)
    if load is None:
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # no load average here: assume busy
            load = float(n)
    return (
        n >= 2
        and load <= n - 2
        and sys.platform.startswith("linux")
        and not multiprocessing.current_process().daemon
    )


def draw_once() -> None:
    """Draw one small figure and throw it away: matplotlib's font cache and text layout
    loaded, so that the next figure costs its own drawing only."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 2), dpi=50)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1])
    ax.set_title("warm-up")
    fig.savefig(io.BytesIO(), format="png")


def _warm_up() -> float:
    """Import matplotlib and draw once (font cache, text layout), in a drawing process."""
    t0 = time.perf_counter()
    from . import data, figures, html, profile  # noqa: F401 - the report's modules, once

    draw_once()
    return time.perf_counter() - t0


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


class BackgroundDrawer:
    """Draws pieces of a run's reports in forked processes, or inline.

    Parameters
    ----------
    workers : int
        Drawing processes (0: draw inline, in the caller).

    Examples
    --------
    >>> drawer = BackgroundDrawer.start(workers=0)
    >>> drawer.submit("sum", sum, [1, 2])
    >>> drawer.results()["sum"]
    3
    >>> drawer.close()
    """

    def __init__(self, workers: int = 0) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._futures: dict[str, Future[tuple[Any, float]]] = {}
        self._jobs: dict[str, tuple[Callable[..., Any], tuple[Any, ...], dict[str, Any]]] = {}
        self._done: dict[str, Any] = {}
        #: Seconds each piece took where it was drawn (its own process's clock).
        self.seconds: dict[str, float] = {}
        if workers > 0 and sys.platform != "win32":  # Windows cannot fork: draw inline
            try:
                from .._process import exit_with_parent

                # each drawing process ends with the run (a forked child holds the ends of
                # its own queue's pipes, so it would never see the run's end on its own)
                self._pool = ProcessPoolExecutor(
                    max_workers=workers,
                    mp_context=multiprocessing.get_context("fork"),
                    initializer=exit_with_parent,
                    initargs=(os.getpid(),),
                )
                for i in range(workers):  # fork them all now, before the run's threads
                    self._futures[f"warm_up_{i}"] = self._pool.submit(_timed, _warm_up)
            except (OSError, ValueError, RuntimeError):  # cannot fork here: draw inline
                self._pool = None
                self._futures.clear()

    @classmethod
    def start(cls, workers: int | None = None) -> BackgroundDrawer:
        """A drawer with ``workers`` processes (default: two where :func:`parallel_pays`,
        else none)."""
        if workers is None:
            workers = 2 if parallel_pays() else 0
        return cls(workers)

    @property
    def forked(self) -> bool:
        """Whether pieces are drawn in other processes."""
        return self._pool is not None

    def submit(self, key: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Draw ``fn(*args, **kwargs)`` (a module-level function; its arguments are
        pickled) in a drawing process, or now when there is none."""
        if self._pool is None:
            self._done[key], self.seconds[key] = _timed(fn, *args, **kwargs)
            return
        self._jobs[key] = (fn, args, kwargs)
        self._futures[key] = self._pool.submit(_timed, fn, *args, **kwargs)

    def results(self) -> dict[str, Any]:
        """Wait for every piece; their results by key. A piece that failed raises its
        error here (the pool is closed first); one whose process died is drawn again
        here."""
        try:
            for key, fut in self._futures.items():
                try:
                    self._done[key], self.seconds[key] = fut.result()
                except BrokenProcessPool:  # a drawing process died (killed, out of memory)
                    if key.startswith("warm_up_"):
                        continue
                    fn, args, kwargs = self._jobs[key]  # drawn again here
                    self._done[key], self.seconds[key] = _timed(fn, *args, **kwargs)
        except BaseException:
            self.close()
            raise
        self._futures.clear()
        return {k: v for k, v in self._done.items() if not k.startswith("warm_up_")}

    def __enter__(self) -> BackgroundDrawer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the drawing processes (pieces not started are dropped)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
