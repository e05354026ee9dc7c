"""pymeshlab in a child process: a crash or a hang fails one reconstruction, not the caller.

pymeshlab runs native code that can abort or segfault its process, and Open3D deadlocks
in a child created by ``fork``. :func:`run_in_child` therefore starts a fresh interpreter
(``python -c``, importing this module: what the ``spawn`` start method does, but
without re-running the caller's main module, which ``multiprocessing``'s spawn does and
which recurses in a script without an ``if __name__ == "__main__":`` guard). Arrays go in
and come back as ``.npy`` files in a private temporary folder, so no pipe can block
either side. A signal or a non-zero exit, a timeout (the child is killed), or an exception
in the child becomes a :class:`~treesim.errors.ReconstructionError` whose message says
what happened and what to try. The child exits by itself (status 70) if the parent dies
(:func:`treesim._process.exit_with_parent`, given the parent's pid on its command line).

Test hook: when the environment variable :data:`FAULT_ENV` is ``abort`` the child calls
``os.abort()`` before its task, ``segfault`` kills itself with SIGSEGV, ``hang`` sleeps
for an hour, and ``raise`` raises a ``RuntimeError``. Nothing else reads it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from .._process import ORPHANED_EXIT, exit_with_parent
from ..errors import ReconstructionError

#: Environment variable the child honours to simulate failures (tests only).
FAULT_ENV = "TREESIM_TEST_PMLWORKER_FAULT"

#: Exit code of a child whose task raised (it also writes the error to ``result.json``).
_EXIT_TASK_ERROR = 3
#: Exit code of a child that noticed its parent had gone.
_EXIT_ORPHANED = ORPHANED_EXIT

#: What the child interpreter runs (``-c``, so that importing the package does not warn
#: about this module being run as ``__main__`` after it was imported).
_CHILD_COMMAND = (
    "import sys; from treesim.reconstruct._pmlworker import _child_main; "
    "sys.exit(_child_main(sys.argv[1:]))"
)

#: The folder holding the installed ``treesim`` package (site-packages for a wheel), put on
#: the child's ``PYTHONPATH`` in case the parent found it through a path set by hand; an
#: editable install is found by the child's own ``site`` (the same interpreter).
_PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])


# --------------------------------------------------------------------------- child side


def _poisson(arrays: dict[str, np.ndarray], params: dict[str, Any]) -> dict[str, np.ndarray]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(
        pymeshlab.Mesh(
            vertex_matrix=np.ascontiguousarray(arrays["points"], dtype=np.float64),
            v_normals_matrix=np.ascontiguousarray(arrays["normals"], dtype=np.float64),
        )
    )
    ms.generate_surface_reconstruction_screened_poisson(
        depth=int(params["depth"]),
        threads=int(params["threads"]),
        samplespernode=float(params["samples_per_node"]),
        pointweight=float(params["point_weight"]),
        preclean=False,
    )
    if ms.mesh_number() < 2:
        return {"vertices": np.zeros((0, 3)), "faces": np.zeros((0, 3), np.int64)}
    m = ms.current_mesh()
    out = {
        "vertices": np.asarray(m.vertex_matrix(), dtype=np.float64),
        "faces": np.asarray(m.face_matrix(), dtype=np.int64),
    }
    if m.vertex_number() and m.has_vertex_scalar():
        # After screened Poisson the vertex quality ("scalar") holds the sample density.
        out["density"] = np.asarray(m.vertex_scalar_array(), dtype=np.float64)
    return out


def _ball_pivoting(arrays: dict[str, np.ndarray], params: dict[str, Any]) -> dict[str, np.ndarray]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(
        pymeshlab.Mesh(
            vertex_matrix=np.ascontiguousarray(arrays["points"], dtype=np.float64),
            v_normals_matrix=np.ascontiguousarray(arrays["normals"], dtype=np.float64),
        )
    )
    # One pass per radius, smallest first; later passes keep the faces of earlier ones
    # (deletefaces=False) and fill the holes the smaller ball could not cross.
    for r in params["radii_m"]:
        ms.generate_surface_reconstruction_ball_pivoting(
            ballradius=pymeshlab.PureValue(float(r)),
            clustering=float(params["clustering_pct"]),
            creasethr=float(params["crease_angle_deg"]),
            deletefaces=False,
        )
    m = ms.current_mesh()
    return {
        "vertices": np.asarray(m.vertex_matrix(), dtype=np.float64),
        "faces": np.asarray(m.face_matrix(), dtype=np.int64),
    }


_TASKS = {"poisson": _poisson, "ball_pivoting": _ball_pivoting}


def _apply_test_fault() -> None:
    fault = os.environ.get(FAULT_ENV, "")
    if fault == "abort":
        os.abort()
    elif fault == "segfault":
        os.kill(os.getpid(), signal.SIGSEGV)
    elif fault == "hang":
        time.sleep(3600)
    elif fault == "raise":
        raise RuntimeError("simulated failure (test hook)")


def _child_main(argv: list[str]) -> int:
    task, folder, parent_pid = argv[0], Path(argv[1]), int(argv[2])
    exit_with_parent(parent_pid, interval_s=0.5, code=_EXIT_ORPHANED)
    result_path = folder / "result.json"
    try:
        params = json.loads((folder / "params.json").read_text())
        arrays = {p.stem[3:]: np.load(p, allow_pickle=False) for p in folder.glob("in_*.npy")}
        _apply_test_fault()
        start = time.perf_counter()
        out = _TASKS[task](arrays, params)
        worker_s = time.perf_counter() - start
        for name, arr in out.items():
            np.save(folder / f"out_{name}.npy", np.ascontiguousarray(arr), allow_pickle=False)
        result_path.write_text(json.dumps({"status": "ok", "worker_s": worker_s}))
        return 0
    except Exception as exc:
        result_path.write_text(
            json.dumps(
                {
                    "status": "error",
                    "message": f"{type(exc).__name__}: {exc}",
                    "traceback": traceback.format_exc(),
                }
            )
        )
        return _EXIT_TASK_ERROR


# --------------------------------------------------------------------------- parent side


def _signal_name(code: int) -> str:
    try:
        return f"signal {code}, {signal.Signals(code).name}"
    except ValueError:
        return f"signal {code}"


def _log_tail(path: Path, chars: int = 600) -> str:
    try:
        text = path.read_text(errors="replace").strip()
    except OSError:
        return ""
    return text[-chars:]


def run_in_child(
    task: str,
    arrays: dict[str, np.ndarray],
    params: dict[str, Any],
    *,
    timeout_s: float,
    what: str,
    advice: str = "",
) -> tuple[dict[str, np.ndarray], float]:
    """Run a pymeshlab task in a fresh child interpreter.

    Parameters
    ----------
    task : {"poisson", "ball_pivoting"}
    arrays : dict of str -> ndarray
        ``points`` (n, 3) and ``normals`` (n, 3), float64.
    params : dict
        The task's parameters (JSON-serialisable).
    timeout_s : float
        Wall-clock limit; the child is killed when it passes.
    what : str
        What is being done, for messages ("screened Poisson on 12000 points").
    advice : str
        What the user could try, appended to crash and timeout messages.

    Returns
    -------
    result : dict of str -> ndarray
        The task's output arrays.
    worker_s : float
        Seconds the task took inside the child (without start-up and transfers).

    Raises
    ------
    ReconstructionError
        The child crashed (signal or exit code named), timed out, or raised.
    """
    if task not in _TASKS:
        raise ValueError(f"unknown pymeshlab task {task!r}")
    tail = f" {advice}" if advice else ""
    with tempfile.TemporaryDirectory(prefix="treesim-pymeshlab-") as tmp:
        folder = Path(tmp)
        for name, arr in arrays.items():
            np.save(folder / f"in_{name}.npy", np.ascontiguousarray(arr), allow_pickle=False)
        (folder / "params.json").write_text(json.dumps(params))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (_PACKAGE_ROOT, env.get("PYTHONPATH", "")) if p
        )
        # OpenMP threads that spin while waiting make pymeshlab's Poisson up to 15x slower
        # when the cores are shared (measured: depth 6, 2 threads, 0.6-9 s); let them sleep.
        env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        log = folder / "log.txt"
        with open(log, "wb") as log_file:
            proc = subprocess.Popen(
                [sys.executable, "-c", _CHILD_COMMAND, task, str(folder), str(os.getpid())],
                stdin=subprocess.DEVNULL,
                stdout=log_file,
                stderr=subprocess.STDOUT,
                env=env,
                cwd=folder,
            )
            try:
                code = proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                raise ReconstructionError(
                    f"{what} did not finish within {timeout_s:g} s and was stopped.{tail}"
                ) from None
        result_path = folder / "result.json"
        result = json.loads(result_path.read_text()) if result_path.exists() else None
        if result is not None and result.get("status") == "error":
            raise ReconstructionError(f"pymeshlab failed during {what}: {result['message']}")
        if code != 0 or result is None:
            how = (
                f"pymeshlab crashed ({_signal_name(-code)})"
                if code < 0
                else f"the pymeshlab worker exited with code {code} without a result"
            )
            log_text = _log_tail(log)
            shown = f" Its last output: {log_text}" if log_text else ""
            raise ReconstructionError(
                f"{how} during {what}; this reconstruction failed, the caller did not.{tail}{shown}"
            )
        out = {p.stem[4:]: np.load(p, allow_pickle=False) for p in folder.glob("out_*.npy")}
        return out, float(result["worker_s"])
