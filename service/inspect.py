"""Opening and checking uploaded files away from the API's process.

An upload is opened with treesim's own readers (:func:`treesim.io.inspect_file`; a zip
archive is a plot, :func:`treesim.service.plots.inspect_plot_archive`) before it is accepted. That
runs in a small pool of ``spawn``-ed processes: a huge cloud's memory, a
slow parse or a native reader that crashes stay out of the server, and a crash fails only
that upload (the pool is rebuilt). A plot archive is unpacked beside the upload, in the data
folder's ``tmp`` (never the system's temp folder), streamed and stopped at ``max_unpacked``
bytes.
"""

from __future__ import annotations

import asyncio
import concurrent.futures as cf
import errno
import multiprocessing
import os
import threading
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from treesim.errors import InputFormatError

__all__ = ["Inspector"]


def _inspect(path: str, filename: str | None, max_unpacked: int | None = None) -> dict[str, Any]:
    from .problems import is_disk_full

    try:
        return _inspect_any(path, filename, max_unpacked)
    except Exception as exc:
        # an error's cause does not cross the process boundary: a full disk, however a
        # reader wrapped it, goes back as the OSError it is (the API answers 507)
        if is_disk_full(exc):
            raise OSError(errno.ENOSPC, "No space left on device") from None
        raise


def _inspect_any(path: str, filename: str | None, max_unpacked: int | None) -> dict[str, Any]:
    from treesim.io import inspect_file

    from .plots import inspect_plot_archive, is_zip

    if is_zip(path):  # a plot: plot.toml, its trees CSV and the trees' files, zipped
        return inspect_plot_archive(path, filename, max_bytes=max_unpacked)
    try:
        return inspect_file(path, filename=filename).to_dict()
    except InputFormatError:
        # text that is no cloud: a QSM cylinder table (TreeQSM, SimpleForest, treesim)?
        cylinders = _inspect_cylinders(path)
        if cylinders is None:
            raise
        return cylinders


def _inspect_cylinders(path: str) -> dict[str, Any] | None:
    """A QSM cylinder table's facts (kind ``cylinders``), or None when it is not one."""
    import numpy as np

    from treesim.errors import TreesimError
    from treesim.models import read_cylinders

    try:
        table = read_cylinders(path)  # validated
    except TreesimError:
        return None
    ends = np.concatenate([table.start, table.end])
    return {
        "format": "cylinders",
        "kind": "cylinders",
        "suffix": ".csv",
        "n_points": int(table.n_cylinders),
        "n_triangles": None,
        "bounds": [ends.min(axis=0).tolist(), ends.max(axis=0).tolist()],
        "fields": [],
    }


def _watch_parent(parent_pid: int) -> None:
    """A pool process's initializer: end with the API's process, however it ends (kill -9
    leaves no one to shut the pool down; the process and multiprocessing's resource
    tracker would outlive it)."""
    from treesim._process import exit_with_parent

    exit_with_parent(parent_pid, interval_s=0.5)


def _warm() -> bool:
    import treesim.io  # noqa: F401 - import the readers once, before the first upload

    return True


class Inspector:
    """``await inspector.inspect(path, filename)`` → the file's facts (see
    :class:`treesim.io.FileInfo`), or treesim's error for a bad file."""

    def __init__(self, workers: int = 1) -> None:
        self.workers = workers
        self._pool: cf.ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def _get(self) -> cf.ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = cf.ProcessPoolExecutor(
                    max_workers=self.workers,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=_watch_parent,
                    initargs=(os.getpid(),),
                )
            return self._pool

    def warm(self) -> None:
        """Start the pool's processes now rather than at the first upload."""
        self._get().submit(_warm)

    async def inspect(
        self, path: Path, filename: str | None, max_unpacked: int | None = None
    ) -> dict[str, Any]:
        """The file's facts; a zip archive is a plot (``max_unpacked``: the most bytes it
        may unpack to)."""
        pool = self._get()
        loop = asyncio.get_running_loop()
        try:
            return await loop.run_in_executor(pool, _inspect, str(path), filename, max_unpacked)
        except BrokenProcessPool:
            with self._lock:
                if self._pool is pool:
                    self._pool = None
            pool.shutdown(wait=False, cancel_futures=True)
            raise InputFormatError(
                f"{filename or 'the upload'}: the reader crashed on this file; it is corrupt "
                "or not what its format says"
            ) from None

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:  # an inspection in progress is of no use now: end it
                if p.is_alive():
                    p.terminate()
