"""The worker: claims jobs from the store and runs each in its own process.

A :class:`Worker` has ``settings.workers`` slots, each a thread that claims a job
(:meth:`Store.claim`), starts its process (a ``spawn``-ed child locally, so a crash, an
out-of-memory kill or a pymeshlab segfault fails that attempt and nothing else; or a task on
a Dask cluster), and every ``poll_interval_s`` renews the lease with the job's progress. A
write that matches no row means the lease is lost (dismissed by the user, or expired and
taken by another worker): the process is stopped and its files removed. A job past its time
limit is stopped and failed.

Files, under the data folder::

    jobs/<id>/attempt-<n>-<token>/       the attempt's outputs while it runs
    jobs/<id>/attempt-<n>-<token>.ctl/   progress.json, result.json, job.log
    jobs/<id>/results/                   the outputs of the attempt that succeeded

An attempt's folder becomes ``results/`` by one rename, after the worker has checked that it
still holds the lease and before it marks the job successful: never half a result, never
two. One housekeeping thread beats the worker's heartbeat, hands expired leases back
(:meth:`Store.expire_leases`) and sweeps folders no job owns any more.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import shutil
import signal
import socket
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from ..problems import problem
from ..settings import Settings
from .runner import JobSpec, child_main, read_json
from .store import Claim, Store

__all__ = ["LeaseExpirer", "Worker", "list_results", "run_worker"]

log = logging.getLogger("treesim.worker")

_SIGNALS = {int(s): s.name for s in signal.Signals}


def done_message(summary: dict[str, Any]) -> str:
    """A successful job's message: ``done``, or ``done, N warnings: ...`` with each of the
    result's warnings (a reconstruction's plausibility warnings, a plot scan's notes),
    which the summary keeps in full."""
    warns = summary.get("warnings") or (summary.get("reconstruction") or {}).get("warnings")
    texts = [str(w.get("message", w)) if isinstance(w, dict) else str(w) for w in warns or []]
    if not texts:
        return "done"
    return f"done, {len(texts)} warning{'s' if len(texts) > 1 else ''}: " + " | ".join(texts)


@dataclass(frozen=True)
class Outcome:
    ok: bool
    summary: dict[str, Any] | None = None
    problem: dict[str, Any] | None = None
    crashed: bool = False


class Handle(Protocol):
    def wait(self, timeout: float) -> bool: ...
    def stop(self) -> None: ...
    def outcome(self) -> Outcome: ...


class LocalHandle:
    """A job in a spawned child process of this worker."""

    def __init__(self, spec: JobSpec) -> None:
        self.spec = spec
        ctx = multiprocessing.get_context("spawn")  # Open3D deadlocks after fork
        self.proc = ctx.Process(
            target=child_main,
            args=(spec.to_dict(), os.getpid()),
            name=f"treesim-job-{spec.job_id[:8]}",
            daemon=False,
        )
        self.proc.start()

    def wait(self, timeout: float) -> bool:
        self.proc.join(timeout)
        return not self.proc.is_alive()

    def stop(self) -> None:
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(5)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)

    def outcome(self) -> Outcome:
        result = read_json(self.spec.result_path)
        if isinstance(result, dict) and "ok" in result:
            if result["ok"]:
                return Outcome(True, summary=result.get("summary") or {})
            return Outcome(False, problem=result.get("problem"))
        code = self.proc.exitcode
        if code is not None and code < 0:
            name = _SIGNALS.get(-code, f"signal {-code}")
            hint = " (the out-of-memory killer sends it)" if -code == signal.SIGKILL else ""
            why = f"the job's process was killed by {name}{hint}"
        else:
            why = f"the job's process exited with status {code} without a result"
        return Outcome(False, problem=problem("job-crashed", why), crashed=True)


class DaskHandle:
    """A job run as a task on a Dask cluster (cancellation is cooperative there: a running
    task finishes, but its result is thrown away)."""

    def __init__(self, client: Any, spec: JobSpec) -> None:
        from .runner import dask_main

        self.spec = spec
        self.future = client.submit(
            dask_main, spec.to_dict(), pure=False, key=f"treesim-{spec.job_id}-{spec.attempt}"
        )

    def wait(self, timeout: float) -> bool:
        from distributed import wait

        try:
            wait([self.future], timeout=timeout)
        except TimeoutError:
            pass
        return self.future.done()

    def stop(self) -> None:
        self.future.cancel()

    def outcome(self) -> Outcome:
        try:
            result = self.future.result(timeout=0)
        except Exception as exc:  # noqa: BLE001 - the task or its worker died
            why = f"the Dask task failed: {type(exc).__name__}: {exc}"
            return Outcome(False, problem=problem("job-crashed", why), crashed=True)
        if result.get("ok"):
            return Outcome(True, summary=result.get("summary") or {})
        return Outcome(False, problem=result.get("problem"))


_MEDIA = {
    ".laz": "application/vnd.laszip",
    ".las": "application/vnd.las",
    ".ply": "application/octet-stream",
    ".obj": "model/obj",
    ".stl": "model/stl",
    ".json": "application/json",
    ".html": "text/html",
    ".png": "image/png",
    ".csv": "text/csv",
    ".xyz": "text/plain",
    ".txt": "text/plain",
}


def media_type(name: str) -> str:
    """The media type of a result file, by suffix."""
    return _MEDIA.get(Path(name).suffix.lower(), "application/octet-stream")


def list_results(folder: Path) -> list[dict[str, Any]]:
    """The files of a results folder: ``name`` (relative, ``/``-separated), ``size_bytes``,
    ``media_type``."""
    out = []
    for p in sorted(folder.rglob("*")):
        if p.is_file() and not p.name.startswith("."):
            name = p.relative_to(folder).as_posix()
            out.append(
                {"name": name, "size_bytes": p.stat().st_size, "media_type": media_type(name)}
            )
    return out


#: The most of a failed job's log kept with it (its end: where the traceback is).
LOG_TAIL_BYTES = 64 * 1024


def log_tail(path: Path, limit: int = LOG_TAIL_BYTES) -> str:
    """The last ``limit`` bytes of a job's log (from a line's start where one is near),
    or "" when there is none.

    Examples
    --------
    >>> log_tail(Path("/nonexistent/job.log"))
    ''
    """
    try:
        with open(path, "rb") as fh:
            size = fh.seek(0, os.SEEK_END)
            fh.seek(max(0, size - limit))
            data = fh.read(limit)
    except OSError:
        return ""
    if size > limit:
        cut = data.find(b"\n")
        data = b"[... the log's start is cut ...]\n" + (
            data[cut + 1 :] if 0 <= cut < 4096 else data
        )
    return data.decode("utf-8", "replace")


def with_log(outcome: Outcome, path: Path) -> Outcome:
    """A failed outcome whose problem carries the job log's end as ``log`` (a treesim
    extension member the job's status shows)."""
    tail = log_tail(path)
    if not tail.strip():
        return outcome
    base = outcome.problem or problem("internal-error", "no result")
    return Outcome(False, problem={**base, "log": tail}, crashed=outcome.crashed)


def _rmtree(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


class Worker:
    """``settings.workers`` job slots over one store. :meth:`start` runs them in threads
    (the API's embedded worker); :func:`run_worker` is ``treesim worker``."""

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings = settings
        self.store = store
        self.data_dir = settings.data_dir
        self.id = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._client: Any = None
        self.running: dict[str, Claim] = {}
        self._running_lock = threading.Lock()

    # -- life cycle -------------------------------------------------------------------------
    def start(self) -> None:
        (self.data_dir / "jobs").mkdir(parents=True, exist_ok=True)
        if self.settings.executor == "dask":
            from distributed import Client

            self._client = Client(self.settings.scheduler, timeout="20s")
        self.store.register_worker(
            self.id, executor=self.settings.executor, slots=self.settings.workers
        )
        self._sweep()
        house = threading.Thread(target=self._housekeeping, name="treesim-house", daemon=True)
        self._threads = [house] + [
            threading.Thread(target=self._slot, args=(i,), name=f"treesim-slot-{i}", daemon=True)
            for i in range(self.settings.workers)
        ]
        for t in self._threads:
            t.start()
        log.info(
            "worker %s: %d slot(s), executor %s, %d thread(s) per job, data in %s",
            self.id,
            self.settings.workers,
            self.settings.executor,
            self.settings.threads_per_job,
            self.data_dir,
        )

    def request_stop(self) -> None:
        self._stop.set()

    def stop(self, timeout: float = 30.0) -> None:
        """Stop claiming; stop running jobs and hand them back (they do not count as
        attempts); mark the worker stopped."""
        self._stop.set()
        deadline = time.monotonic() + timeout
        for t in self._threads:
            t.join(max(0.1, deadline - time.monotonic()))
        try:
            self.store.worker_stopped(self.id)
        except Exception:  # noqa: BLE001 - the store may be gone at shutdown
            log.warning("could not mark worker %s stopped", self.id)
        if self._client is not None:
            self._client.close()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    # -- the slots --------------------------------------------------------------------------
    def _slot(self, index: int) -> None:
        while not self._stop.is_set():
            try:
                claim = self.store.claim(self.id, self.settings.lease_s)
            except Exception:  # noqa: BLE001 - the database may be restarting
                log.exception("claim failed; retrying")
                self._stop.wait(self.settings.poll_interval_s * 5)
                continue
            if claim is None:
                self._stop.wait(self.settings.poll_interval_s)
                continue
            with self._running_lock:
                self.running[claim.id] = claim
            try:
                self._run(claim)
            except Exception:  # noqa: BLE001 - never let one job stop the slot
                log.exception("job %s attempt %d: worker error", claim.id, claim.attempt)
                try:
                    self.store.fail(
                        claim,
                        problem("internal-error", "the worker failed while running the job"),
                        retry=True,
                    )
                except Exception:  # noqa: BLE001
                    log.exception("could not record the failure of job %s", claim.id)
            finally:
                with self._running_lock:
                    self.running.pop(claim.id, None)

    def _spec(self, claim: Claim, work: Path, ctl: Path) -> JobSpec | dict[str, Any]:
        inputs: dict[str, str] = {}
        name = ""
        for key, ref in claim.inputs.items():
            path = self.data_dir / ref["path"]
            if not path.is_file():
                what = (
                    f"upload {ref['upload']}"
                    if "upload" in ref
                    else (f"result {ref.get('result')} of job {ref.get('job')}")
                )
                return problem(
                    "bad-input-file",
                    f"input {key!r} ({what}) is gone from the data folder",
                    field=f"inputs.{key}",
                )
            inputs[key] = str(path)
            if not name and ref.get("filename"):
                name = Path(str(ref["filename"])).stem
        return JobSpec(
            job_id=claim.id,
            attempt=claim.attempt,
            process=claim.process,
            inputs=inputs,
            parameters=claim.parameters,
            outdir=str(work),
            control_dir=str(ctl),
            threads=self.settings.threads_per_job,
            name=name,
        )

    def _start(self, spec: JobSpec) -> Handle:
        if self._client is not None:
            return DaskHandle(self._client, spec)
        return LocalHandle(spec)

    def _run(self, claim: Claim) -> None:
        s = self.settings
        jobdir = self.data_dir / "jobs" / claim.id
        self._clean_attempts(jobdir)
        token = uuid.uuid4().hex[:8]
        work = jobdir / f"attempt-{claim.attempt}-{token}"
        ctl = jobdir / f"attempt-{claim.attempt}-{token}.ctl"
        work.mkdir(parents=True)
        ctl.mkdir()
        try:
            spec = self._spec(claim, work, ctl)
            if isinstance(spec, dict):  # an input is gone: the job cannot run
                self.store.fail(claim, spec, retry=False)
                return
            log.info("job %s (%s) attempt %d started", claim.id, claim.process, claim.attempt)
            handle = self._start(spec)
            t0 = time.monotonic()
            while True:
                finished = handle.wait(s.poll_interval_s)
                if self._stop.is_set() and not finished:
                    handle.stop()
                    self.store.release(claim, "its worker stopped; waiting for a worker")
                    return
                prog = read_json(spec.progress_path) or {}
                fraction = prog.get("fraction")
                held = self.store.heartbeat(
                    claim,
                    s.lease_s,
                    progress=None if fraction is None else 100.0 * min(float(fraction), 0.99),
                    stage=prog.get("stage"),
                )
                if not held:
                    handle.stop()
                    log.info("job %s attempt %d: lease lost (dismissed?)", claim.id, claim.attempt)
                    return
                if finished:
                    break
                if time.monotonic() - t0 > claim.time_limit_s:
                    handle.stop()
                    why = (
                        f"stopped after the job time limit of {claim.time_limit_s:g} s "
                        "(TREESIM_JOB_TIME_LIMIT_S)"
                    )
                    stopped = with_log(
                        Outcome(False, problem=problem("time-limit", why)), spec.log_path
                    )
                    _rmtree(ctl)
                    _rmtree(work)
                    self.store.fail(claim, stopped.problem or {}, retry=False)
                    return
            outcome = handle.outcome()
            if not outcome.ok:  # the log goes with the failure: the attempt folder does not
                outcome = with_log(outcome, spec.log_path)
            # a job is seen ended only once its attempt's files are gone (a client that
            # lists the job folder at once finds no control files)
            _rmtree(ctl)
            self._finish(claim, outcome, work, jobdir)
        finally:
            _rmtree(ctl)
            _rmtree(work)

    def _finish(self, claim: Claim, outcome: Outcome, work: Path, jobdir: Path) -> None:
        if not outcome.ok:
            _rmtree(work)
            status = self.store.fail(
                claim,
                outcome.problem or problem("internal-error", "no result"),
                retry=outcome.crashed,
            )
            log.info(
                "job %s attempt %d: %s (%s)",
                claim.id,
                claim.attempt,
                status,
                (outcome.problem or {}).get("detail"),
            )
            return
        # still ours? (renews the lease too, so the rename below cannot race a new attempt)
        if not self.store.heartbeat(claim, self.settings.lease_s, stage="saving results"):
            return
        results = jobdir / "results"
        if results.exists():  # an earlier attempt renamed, then lost its lease: replace it
            old = jobdir / f"old-{uuid.uuid4().hex[:8]}"
            os.replace(results, old)
            _rmtree(old)
        os.replace(work, results)
        summary = outcome.summary or {}
        done = self.store.succeed(
            claim, results=list_results(results), summary=summary, message=done_message(summary)
        )
        if done:
            for stage, seconds in (summary.get("timings_s") or {}).items():
                if isinstance(seconds, (int, float)):
                    self.store.bump("stage_seconds", f"{claim.process}:{stage}", float(seconds))
            log.info("job %s attempt %d: successful", claim.id, claim.attempt)
        else:
            job = self.store.job(claim.id)
            if job is not None and job["status"] == "dismissed":
                _rmtree(results)

    # -- housekeeping -----------------------------------------------------------------------
    def _housekeeping(self) -> None:
        last_sweep = time.monotonic()
        while not self._stop.is_set():
            try:
                self.store.worker_heartbeat(self.id)
                expire_leases(self.store)
                if self.settings.heartbeat_file:
                    p = Path(self.settings.heartbeat_file)
                    p.parent.mkdir(parents=True, exist_ok=True)
                    p.touch()
                if time.monotonic() - last_sweep > 300:
                    self._sweep()
                    last_sweep = time.monotonic()
            except Exception:  # noqa: BLE001 - keep beating while the database recovers
                log.exception("housekeeping failed; retrying")
            self._stop.wait(self.settings.poll_interval_s)

    def _clean_attempts(self, jobdir: Path) -> None:
        if jobdir.is_dir():
            for p in jobdir.iterdir():
                if p.name.startswith(("attempt-", "old-")):
                    _rmtree(p)

    def _sweep(self) -> None:
        """Remove folders no job owns: attempts of jobs that are not running, and results
        of dismissed jobs (left by a worker or an API that died at the wrong moment)."""
        root = self.data_dir / "jobs"
        if not root.is_dir():
            return
        for jobdir in root.iterdir():
            if not jobdir.is_dir():
                continue
            job = self.store.job(jobdir.name)
            if job is None:
                continue
            if job["status"] != "running":
                self._clean_attempts(jobdir)
            if job["status"] == "dismissed":
                _rmtree(jobdir / "results")


def expire_leases(store: Store) -> None:
    """Hand back (or fail) the jobs whose lease ran out, each said in the log: a worker's
    housekeeping and the API's :class:`LeaseExpirer` both do this."""
    for job_id, status in store.expire_leases():
        log.warning("job %s: lease expired; now %s", job_id, status)


class LeaseExpirer:
    """A thread that hands back (or fails) jobs whose lease ran out, as a worker's
    housekeeping does: the API runs one when it has no worker of its own, so a job whose
    worker died does not stay ``running`` while no worker is alive to notice.

    Examples
    --------
    >>> expirer = LeaseExpirer(store, interval_s=1.0).start()  # doctest: +SKIP
    >>> expirer.stop()  # doctest: +SKIP
    """

    def __init__(self, store: Store, interval_s: float) -> None:
        self.store = store
        self.interval_s = interval_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="treesim-leases", daemon=True)

    def start(self) -> LeaseExpirer:
        self._thread.start()
        return self

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        self._thread.join(timeout)

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                expire_leases(self.store)
            except Exception:  # noqa: BLE001 - retried next time; the database may recover
                log.warning("expiring leases failed; retrying", exc_info=True)
            self._stop.wait(self.interval_s)


def run_worker(settings: Settings) -> int:
    """``treesim worker``: run until SIGTERM or Ctrl-C, then hand running jobs back."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    store = Store(settings.db_url)
    worker = Worker(settings, store)
    done = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        log.info("worker %s: %s received, stopping", worker.id, _SIGNALS.get(signum, signum))
        done.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    worker.start()
    print(
        f"treesim worker {worker.id}: {settings.workers} job(s) at once on {settings.executor}, "
        f"data {settings.data_dir}",
        flush=True,
    )
    while not done.wait(1.0):
        pass
    worker.stop()
    store.dispose()
    return 0
