"""Where a batch's trees run: ``inline``, ``local`` (a process pool) or ``dask``.

All three are :class:`concurrent.futures.Executor` objects, so :func:`treesim.run_batch`
drives them the same way:

* ``inline``: every task runs in the calling process when it is submitted (tests,
  debugging, one core);
* ``local``: a :class:`~concurrent.futures.ProcessPoolExecutor` whose workers are started
  with the ``spawn`` method (Open3D deadlocks in a child created by ``fork``). Each worker
  gets an explicit thread count for Open3D and the neighbour searches, the same for every
  task it runs (Open3D's TBB pool keeps the first count a process uses), chosen so that
  ``workers × threads <= cores``. Workers ignore Ctrl-C (the batch stops them) and exit
  by themselves when the batch process dies;
* ``dask``: ``distributed.Client(address).get_executor()`` on a running cluster
  (``scheduler="tcp://host:8786"``), or a ``LocalCluster(processes=True,
  threads_per_worker=1)`` started for the batch when no address is given. On a cluster
  the trees' files must be readable, and the output folder writable, at the same paths on
  every worker (a shared file system); each task uses ``cores // worker threads`` threads
  of the machine it lands on unless a thread count is given.

:func:`detect_available` lists the executors installed, as laspy lists its LAZ backends.
"""

from __future__ import annotations

import concurrent.futures as cf
import importlib.util
import logging
import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from enum import Enum
from typing import Any

from ._process import exit_with_parent
from ._system import cpu_count
from .errors import InvalidParameterError

__all__ = [
    "Executor",
    "ExecutorPlan",
    "InlineExecutor",
    "detect_available",
    "open_executor",
    "plan_executor",
    "slots",
    "stop_now",
    "task_threads",
]


class Executor(str, Enum):
    """The kinds of executor."""

    INLINE = "inline"
    LOCAL = "local"
    DASK = "dask"

    def is_available(self) -> bool:
        """Whether this executor can run here (``dask`` needs ``distributed``)."""
        if self is Executor.DASK:
            return importlib.util.find_spec("distributed") is not None
        return True


def detect_available() -> list[Executor]:
    """The executors that can run in this environment, cheapest first."""
    return [e for e in Executor if e.is_available()]


def _kind(kind: str | Executor) -> Executor:
    try:
        e = Executor(kind)
    except ValueError:
        raise InvalidParameterError(
            f"unknown executor {kind!r}; choose one of {', '.join(e.value for e in Executor)}"
        ) from None
    if not e.is_available():
        raise InvalidParameterError(
            "the dask executor needs dask.distributed: pip install 'treesim[dask]' "
            "(or 'dask[distributed]')"
        )
    return e


@dataclass(frozen=True, kw_only=True)
class ExecutorPlan:
    """How a batch is spread over processes and threads.

    Attributes
    ----------
    kind : Executor
    workers : int
        Worker processes (``inline``: 1; a remote dask cluster: as reported at start).
    threads : int
        Threads each task uses; 0 means "decide on the worker" (remote dask clusters:
        ``cores // worker threads`` of the machine the task lands on).
    scheduler : str, optional
        Address of a running dask scheduler.
    """

    kind: Executor
    workers: int
    threads: int
    scheduler: str | None = None

    def describe(self) -> str:
        """One line for messages and ``summary.json``."""
        t = f"{self.threads} thread{'s' if self.threads != 1 else ''}" if self.threads else "auto"
        if self.kind is Executor.INLINE:
            return f"inline (this process, {t})"
        if self.kind is Executor.LOCAL:
            return f"local: {self.workers} worker process{'es' if self.workers != 1 else ''} × {t}"
        where = self.scheduler or f"a local cluster of {self.workers} worker processes"
        return f"dask: {where}, {t} per task"

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind.value,
            "workers": self.workers,
            "threads": self.threads,
            "scheduler": self.scheduler,
            "description": self.describe(),
        }


def plan_executor(
    kind: str | Executor = "inline",
    *,
    workers: int | None = None,
    threads: int | None = None,
    scheduler: str | None = None,
    n_tasks: int | None = None,
) -> ExecutorPlan:
    """Choose workers and threads so that ``workers × threads <= cores``.

    Parameters
    ----------
    kind : {"inline", "local", "dask"}
    workers : int, optional
        Worker processes (``local`` and a local dask cluster); default one per core, but
        no more than ``n_tasks``.
    threads : int, optional
        Threads per task; default ``max(1, cores // workers)`` (``inline``: all cores).
    scheduler : str, optional
        A running dask scheduler's address (``dask`` only).
    n_tasks : int, optional
        How many tasks there are (caps the default worker count).
    """
    e = _kind(kind)
    cores = cpu_count()
    for name, v in (("workers", workers), ("threads", threads)):
        if v is not None and (isinstance(v, bool) or int(v) != v or v < 1):
            raise InvalidParameterError(f"{name} must be a positive integer, got {v!r}")
    if scheduler is not None and e is not Executor.DASK:
        raise InvalidParameterError("--scheduler is for the dask executor (--executor dask)")
    if e is Executor.INLINE:
        if workers not in (None, 1):
            raise InvalidParameterError("the inline executor runs one tree at a time (workers 1)")
        return ExecutorPlan(kind=e, workers=1, threads=int(threads or cores))
    if e is Executor.DASK and scheduler:
        if workers is not None:
            raise InvalidParameterError(
                "--workers sets the size of a local cluster; a running scheduler has its own"
            )
        return ExecutorPlan(kind=e, workers=0, threads=int(threads or 0), scheduler=scheduler)
    w = int(workers or max(1, min(cores, n_tasks or cores)))
    t = int(threads or max(1, cores // w))
    if w * t > cores:
        logging.getLogger("treesim").warning(
            "%d workers × %d threads exceeds the %d cores; expect them to compete", w, t, cores
        )
    return ExecutorPlan(kind=e, workers=w, threads=t)


def task_threads(threads: int) -> int:
    """The thread count a task should use: ``threads`` when > 0; on a dask worker
    ``cores // its threads``; else all cores."""
    if threads > 0:
        return int(threads)
    try:
        from distributed import get_worker

        w = get_worker()
        n = int(getattr(w, "nthreads", None) or w.state.nthreads)
        return max(1, cpu_count() // max(1, n))
    except (ImportError, ValueError, AttributeError):
        return cpu_count()


# -- inline -------------------------------------------------------------------------------
class InlineExecutor(cf.Executor):
    """Runs each task in the calling thread when it is submitted.

    Exceptions become the future's exception; ``KeyboardInterrupt`` and ``SystemExit``
    propagate (so Ctrl-C stops at once).
    """

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        f: cf.Future = cf.Future()
        f.set_running_or_notify_cancel()
        try:
            f.set_result(fn(*args, **kwargs))
        except Exception as exc:
            f.set_exception(exc)
        return f


# -- local --------------------------------------------------------------------------------
def _init_local_worker(parent_pid: int) -> None:
    """Runs once in each local worker: ignore Ctrl-C (the batch stops its workers), die
    with the parent. (The thread count reaches each task with the task.)"""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent(parent_pid, interval_s=1.0)  # exit status 70: nothing reads our result


@contextmanager
def open_executor(plan: ExecutorPlan) -> Iterator[cf.Executor]:
    """Start the executor of ``plan`` and shut it down on exit.

    On an exception (Ctrl-C included) the local pool's workers are terminated and a local
    dask cluster is closed, so no tree keeps running after the batch stops.
    """
    if plan.kind is Executor.INLINE:
        yield InlineExecutor()
        return
    if plan.kind is Executor.LOCAL:
        pool = cf.ProcessPoolExecutor(
            max_workers=plan.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_local_worker,
            initargs=(os.getpid(),),
        )
        try:
            yield pool
        except BaseException:
            stop_now(pool)
            raise
        else:
            pool.shutdown(wait=True)
        return
    yield from _dask(plan)


def stop_now(executor: cf.Executor) -> None:
    """Cancel pending tasks and terminate a process pool's workers (best effort)."""
    try:
        executor.shutdown(wait=False, cancel_futures=True)
    except Exception:  # noqa: BLE001 - stopping anyway
        pass
    if isinstance(executor, cf.ProcessPoolExecutor):
        terminate = getattr(executor, "terminate_workers", None)  # Python >= 3.14
        if terminate is not None:
            terminate()
            return
        procs = list((getattr(executor, "_processes", None) or {}).values())
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)


def _dask(plan: ExecutorPlan) -> Iterator[cf.Executor]:
    from distributed import Client, LocalCluster

    cluster = None
    if plan.scheduler:
        try:
            client = Client(plan.scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise InvalidParameterError(
                f"could not reach the dask scheduler at {plan.scheduler}: {exc}"
            ) from None
    else:
        cluster = LocalCluster(
            n_workers=plan.workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        client = Client(cluster)
    try:
        yield client.get_executor(pure=False)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def slots(plan: ExecutorPlan, executor: cf.Executor) -> int:
    """How many tasks may run at once on ``executor`` (a dask cluster: its worker threads
    now, from the client's cached view of the scheduler)."""
    if plan.kind is Executor.DASK:
        client = getattr(executor, "_client", None)
        if client is not None:
            try:
                info = client.scheduler_info()
                return max(1, sum(int(w.get("nthreads", 1)) for w in info["workers"].values()))
            except Exception:  # noqa: BLE001 - fall back to the plan
                pass
    return max(1, plan.workers)
