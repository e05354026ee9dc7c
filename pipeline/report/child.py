"""A drawing process: a fresh interpreter that draws a run's report pieces it is sent.

A run's figures are single-threaded matplotlib work. Drawn in the run's own process, they
and matplotlib's import (a second or so of Python, loaded by a thread beside the science)
take turns with the science for the interpreter's lock; drawn in a process of their own,
they take only a core. :class:`DrawingProcess` starts one when a run starts: it imports
matplotlib and draws once (fonts, text layout) while the run reconstructs, then draws each
piece it is sent, in order, and answers with the piece's result.

The child is started as ``python -c`` (what ``multiprocessing``'s spawn does, without
re-running the caller's main module, which recurses in a script without an
``if __name__ == "__main__":`` guard; and never a fork: Open3D's thread pools deadlock in
a forked child). Pieces go down its stdin and results come back on its stdout as pickled
messages (a piece's arrays are pickled, not written to files); whatever the drawing code
prints goes to its stderr, kept in a temporary file and quoted when the child dies. The
child ends when its stdin closes (:meth:`DrawingProcess.close`) and, if the run dies
first, by itself (:func:`treesim._process.exit_with_parent`).
"""

from __future__ import annotations

import gc
import os
import pickle
import queue
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

__all__ = ["CHILD_ENV", "ChildDied", "DrawingProcess", "RemoteTraceback", "draw_once"]

#: Set (to ``"1"``) in a drawing process's environment: a run there draws inline.
CHILD_ENV = "TREESIM_DRAWING_PROCESS"

#: What the child interpreter runs: this module's :func:`_child_main`, the parent's pid on
#: its command line.
_CHILD_COMMAND = (
    "import sys; from treesim.report.child import _child_main; "
    "sys.exit(_child_main(int(sys.argv[1])))"
)

#: The folder holding the installed ``treesim`` package, first on the child's
#: ``PYTHONPATH`` (the parent may have found it through a path set by hand).
_PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])

_HEADER = struct.Struct("<Q")


class ChildDied(RuntimeError):
    """The drawing process ended before it answered (killed, crashed, or never started)."""


class RemoteTraceback(Exception):
    """The traceback of an error raised in a drawing process (the ``__cause__`` of the
    error raised again in the run's process)."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return f'\n"""\n{self.text}"""'


# --------------------------------------------------------------------------- messages


def _send(stream: IO[bytes], payload: bytes) -> None:
    stream.write(_HEADER.pack(len(payload)))
    stream.write(payload)
    stream.flush()


def _receive(stream: IO[bytes]) -> bytes | None:
    """One message, or None at the end of the stream (the other side has gone)."""
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    n = _HEADER.unpack(head)[0]
    payload = stream.read(n)
    return payload if len(payload) == n else None


# --------------------------------------------------------------------------- child side


def draw_once() -> None:
    """Draw one small figure and throw it away: matplotlib's font cache and text layout
    loaded, so that the next figure costs its own drawing only.

    Examples
    --------
    >>> draw_once()
    """
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 2), dpi=50)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1])
    ax.set_title("warm-up")
    fig.savefig(io.BytesIO(), format="png")


def _warm_up(preload: Sequence[str] = ()) -> None:
    """A drawing process's start-up, before its first piece: the report's modules,
    scipy's k-d tree (the occlusion profile's), the software versions a report records,
    the modules ``preload`` names (those of the pieces' functions), and one figure drawn
    (matplotlib's font cache and text layout)."""
    import importlib

    from ..geometry.spacing import kdtree
    from . import figures, html, profile  # noqa: F401 - the report's modules, once
    from .data import report_software

    kdtree(np.zeros((2, 3)))
    report_software("matplotlib")
    for name in preload:
        importlib.import_module(name)
    draw_once()


def _child_main(parent_pid: int) -> int:
    """The drawing process: set up, warm up, then answer each piece until stdin closes."""
    from .._process import exit_with_parent

    exit_with_parent(parent_pid)
    inbox, outbox = sys.stdin.buffer, os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # what the drawing code prints goes to stderr, not into the answers
    first = _receive(inbox)
    if first is None:
        return 0
    sys.path[:], preload = pickle.loads(first)  # the parent's: its pieces' functions import
    t0 = time.perf_counter()
    _warm_up(preload)
    # what the start-up made lives as long as the process: out of the collector's sight,
    # a collection during a piece does not walk matplotlib's (a third of a first figure)
    gc.collect()
    gc.freeze()
    _send(outbox, pickle.dumps(("warm_up", True, None, time.perf_counter() - t0), 5))
    while (message := _receive(inbox)) is not None:
        key, fn, args, kwargs = pickle.loads(message)
        t0 = time.perf_counter()
        try:
            answer = (key, True, fn(*args, **kwargs), time.perf_counter() - t0)
        except BaseException as e:  # noqa: BLE001 - every error goes back to the run
            answer = (key, False, (_picklable(e), traceback.format_exc()), 0.0)
        _send(outbox, pickle.dumps(answer, 5))
    return 0


def _picklable(e: BaseException) -> BaseException | None:
    """``e`` where it survives pickling, else None (its traceback's text says what it was)."""
    try:
        pickle.loads(pickle.dumps(e))
    except Exception:  # noqa: BLE001 - any error that does not pickle
        return None
    return e


# --------------------------------------------------------------------------- parent side


class DrawingProcess:
    """One drawing process, started at once; pieces sent to it are drawn in order.

    Parameters
    ----------
    parent_pid : int, optional
        The process it ends with (default this one).
    preload : sequence of str
        Modules it imports while it starts (those of the functions it will be sent: a
        piece then costs its own drawing only).

    Raises
    ------
    OSError
        The interpreter could not be started.

    Examples
    --------
    >>> child = DrawingProcess()
    >>> child.send("sum", sum, ([1, 2],), {})
    >>> key, result, seconds = child.answer()
    >>> key, result
    ('sum', 3)
    >>> child.close()
    """

    def __init__(self, parent_pid: int | None = None, preload: Sequence[str] = ()) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (_PACKAGE_ROOT, env.get("PYTHONPATH", "")) if p
        )
        env[CHILD_ENV] = "1"
        self._log = tempfile.TemporaryFile(prefix="treesim-drawing-")
        pid = os.getpid() if parent_pid is None else parent_pid
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _CHILD_COMMAND, str(pid)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._log,
            env=env,
        )
        #: Keys sent and not answered yet, in order.
        self.pending: list[str] = []
        #: Seconds the warm-up took in the child (None until it answered).
        self.warm_up_s: float | None = None
        self._outbox: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._writer = threading.Thread(
            target=self._write, name="treesim-drawing-writer", daemon=True
        )
        self._writer.start()
        self._outbox.put(pickle.dumps((list(sys.path), list(preload)), 5))

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self.proc.pid

    def _write(self) -> None:
        """Write what is sent, in order (a thread: a piece's arrays may fill the pipe
        while the child draws the piece before; the run does not wait for that)."""
        while (payload := self._outbox.get()) is not None:
            try:
                _send(self.proc.stdin, payload)  # type: ignore[arg-type]
            except (OSError, ValueError):  # the child has gone: answer() says so
                return
        try:
            self.proc.stdin.close()  # type: ignore[union-attr]
        except OSError:
            pass

    def send(
        self, key: str, fn: Callable[..., Any], args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> None:
        """Send the piece ``fn(*args, **kwargs)`` (pickled now: ``fn`` a module-level
        function)."""
        self._outbox.put(pickle.dumps((key, fn, args, kwargs), 5))
        self.pending.append(key)

    def answer(self) -> tuple[str, Any, float]:
        """The next piece's ``(key, result, seconds)``; an error raised by the piece is
        raised again here (its traceback in the child as its ``__cause__``).

        Raises
        ------
        ChildDied
            The child ended before it answered.
        """
        while True:
            payload = _receive(self.proc.stdout)  # type: ignore[arg-type]
            if payload is None:
                raise ChildDied(self._death())
            key, ok, result, seconds = pickle.loads(payload)
            if key == "warm_up":
                self.warm_up_s = seconds
                continue
            self.pending.remove(key)
            if ok:
                return key, result, seconds
            error, text = result
            cause = RemoteTraceback(text)
            if error is None:
                raise RuntimeError(f"drawing {key!r} failed in a drawing process") from cause
            raise error from cause

    def _death(self) -> str:
        """What is known of the child's end: its exit status and its last output."""
        try:
            code = self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            code = None
        self._log.seek(0)
        tail = self._log.read()[-2000:].decode("utf-8", "replace").strip()
        how = "still runs" if code is None else f"exit status {code}"
        return f"the drawing process {self.pid} ended ({how})" + (
            f"; its last output: {tail}" if tail else ""
        )

    def close(self, *, kill: bool = False) -> None:
        """End the child: its stdin closed (it leaves after the piece it draws), or
        ``kill``-ed; waited for either way."""
        self._outbox.put(None)
        if kill:
            self.proc.kill()
        try:
            self.proc.wait(timeout=None if kill else 30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._writer.join(timeout=5)
        for stream in (self.proc.stdin, self.proc.stdout, self._log):
            if stream is not None:
                try:
                    stream.close()
                except OSError:  # a pipe the writer could not flush: the child has gone
                    pass
