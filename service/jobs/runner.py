"""What runs inside a job's own process (a spawned child, or a task on a Dask worker).

The worker hands over a :class:`JobSpec` (plain data); the job reads its inputs, runs its
process (:mod:`treesim.service.processes`) writing into the attempt folder, reports progress into a
small file the worker polls, and ends with a result file: ``{"ok": true, "summary": ...}``
or ``{"ok": false, "problem": ...}``. A child that dies without writing one crashed (a
signal, the out-of-memory killer, a pymeshlab segfault): the worker sees its exit code.
Nothing here touches the job store: only the worker writes job records, fenced by the
attempt number.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from treesim._process import exit_with_parent
from treesim.errors import TreesimError
from treesim.jsonio import write_json

__all__ = ["JobSpec", "ProgressFile", "child_main", "dask_main", "execute", "read_json"]


@dataclass(frozen=True)
class JobSpec:
    """Everything a job's process needs (paths absolute, parameters as the user sent them)."""

    job_id: str
    attempt: int
    process: str
    inputs: dict[str, str]
    parameters: dict[str, Any]
    outdir: str
    control_dir: str
    threads: int
    name: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def progress_path(self) -> Path:
        return Path(self.control_dir) / "progress.json"

    @property
    def result_path(self) -> Path:
        return Path(self.control_dir) / "result.json"

    @property
    def log_path(self) -> Path:
        return Path(self.control_dir) / "job.log"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _write_json(path: Path, data: Any) -> None:
    """treesim's atomic JSON writer; a value JSON has no form for is written as its str."""
    write_json(path, data, default=str)


def read_json(path: Path) -> Any:
    """A JSON file, or None when missing or not (yet) valid."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


class ProgressFile:
    """A ``progress(fraction, message)`` callback writing ``{"fraction", "stage"}`` to a
    file, at most every ``interval_s`` (and always at the end)."""

    def __init__(self, path: Path, interval_s: float = 0.5) -> None:
        self.path = path
        self.interval_s = interval_s
        self._last = 0.0

    def __call__(self, fraction: float, message: str) -> None:
        now = time.monotonic()
        if now - self._last < self.interval_s and fraction < 1.0:
            return
        self._last = now
        try:
            _write_json(self.path, {"fraction": float(fraction), "stage": str(message)})
        except (OSError, TreesimError):
            pass  # progress is best effort; the result is what counts


def execute(spec: JobSpec) -> dict[str, Any]:
    """Run the job's process; returns its summary (raises treesim's errors)."""
    from ..processes import PROCESSES, check_parameters

    proc = PROCESSES[spec.process]
    params = check_parameters(proc, spec.parameters)
    out = Path(spec.outdir)
    out.mkdir(parents=True, exist_ok=True)
    progress = ProgressFile(spec.progress_path)
    progress(0.0, "starting")
    inputs = {k: Path(v) for k, v in spec.inputs.items()}
    summary = proc.execute(inputs, params, out, int(spec.threads), progress, spec.name)
    progress(1.0, "done")
    return summary


def _outcome(spec: JobSpec) -> dict[str, Any]:
    from ..problems import is_disk_full, problem, problem_for

    try:
        return {"ok": True, "summary": execute(spec)}
    except (TreesimError, MemoryError) as exc:
        if is_disk_full(exc):  # a reader's wrapped ENOSPC: the path stays in the job log
            traceback.print_exc()
        return {"ok": False, "problem": problem_for(exc)}
    except Exception as exc:  # a bug: the traceback goes to the job's log, not the user
        if is_disk_full(exc):
            traceback.print_exc()
            return {"ok": False, "problem": problem_for(exc)}
        traceback.print_exc()
        return {
            "ok": False,
            "problem": problem(
                "internal-error",
                f"{type(exc).__name__}: {exc} (a bug in treesim; the traceback is in this "
                "problem's log)",
            ),
        }


def child_main(spec_dict: dict[str, Any], parent_pid: int) -> None:
    """Entry point of a job's spawned process: log to the job's log file, die with the
    worker, run, write the result file."""
    spec = JobSpec(**spec_dict)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the worker decides when to stop us
    exit_with_parent(parent_pid, interval_s=0.5)  # status 70: nobody will read our result
    try:
        log = open(spec.log_path, "a", buffering=1)  # noqa: SIM115 - lives as long as we do
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        sys.stdout = sys.stderr = log
    except OSError:
        pass
    result = _outcome(spec)
    _write_json(spec.result_path, result)
    sys.stdout.flush()


def dask_main(spec_dict: dict[str, Any]) -> dict[str, Any]:
    """Entry point of a job run as a Dask task: the same, returning the result (the
    control folder lives on the shared data folder, so progress still reaches the
    worker)."""
    spec = JobSpec(**spec_dict)
    result = _outcome(spec)
    try:
        _write_json(spec.result_path, result)
    except (OSError, TreesimError):
        pass
    return result
