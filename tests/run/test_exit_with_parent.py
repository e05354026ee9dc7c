"""``treesim._process.exit_with_parent``: the one parent-watch of every child process treesim
starts (pool workers, sweep points, pymeshlab children, service jobs)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from treesim._process import ORPHANED_EXIT

ROOT = Path(__file__).resolve().parents[2]

#: A child that watches the pid in argv[1] and would otherwise sleep for a minute.
WATCHER = """
import sys, time
from treesim._process import exit_with_parent
exit_with_parent(int(sys.argv[1]), interval_s=0.05, code=int(sys.argv[2]))
print("watching", flush=True)
time.sleep(60)
"""

#: A parent that starts a watcher of itself, prints the watcher's pid and exits at once.
SHORT_LIVED_PARENT = f"""
import os, subprocess, sys
child = subprocess.Popen([sys.executable, "-c", {WATCHER!r}, str(os.getpid()), "70"],
                         stdout=subprocess.PIPE, text=True)
assert child.stdout.readline().strip() == "watching"
print(child.pid, flush=True)
"""


def _watcher(parent_pid: int, code: int) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", WATCHER, str(parent_pid), str(code)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )


def test_a_child_whose_parent_is_another_process_exits_with_the_code():
    # the watched pid is not this child's parent: to the child its parent is gone
    child = _watcher(parent_pid=1 if sys.platform != "win32" else 0, code=71)
    assert child.wait(30) == 71


def test_a_child_whose_parent_lives_keeps_running():
    import os

    child = _watcher(parent_pid=os.getpid(), code=ORPHANED_EXIT)
    try:
        assert child.stdout.readline().strip() == "watching"
        time.sleep(0.5)  # ten looks at its parent
        assert child.poll() is None, "the child left while its parent was alive"
    finally:
        child.kill()
        child.wait(30)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_an_orphan_ends_by_itself():
    out = subprocess.run(
        [sys.executable, "-c", SHORT_LIVED_PARENT],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    pid = int(out.stdout.strip())
    stat = Path(f"/proc/{pid}/stat")
    deadline = time.monotonic() + 20
    alive = True
    while time.monotonic() < deadline:
        try:
            # the state after the command name: Z (a zombie nobody reaped yet) has exited
            alive = stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            alive = False  # gone and reaped
        if not alive:
            break
        time.sleep(0.05)
    assert not alive, f"the orphan {pid} still runs 20 s after its parent left"
    # an orphan that did not watch would sleep for its 60 s: it left within the deadline


def test_orphaned_exit_is_70_as_the_callers_always_used():
    from treesim.reconstruct._pmlworker import _EXIT_ORPHANED

    assert ORPHANED_EXIT == 70 and _EXIT_ORPHANED == 70


#: A run's report drawer with its forked drawing processes busy, as a run holds it: prints
#: the drawing processes' pids, then waits to be killed.
DRAWER = """
import os, time
from treesim.report.background import BackgroundDrawer
drawer = BackgroundDrawer(workers=2)
for i in range(2):
    drawer.submit(f"nap{i}", time.sleep, 60)
time.sleep(1.0)
print(" ".join(str(p) for p in drawer._pool._processes), flush=True)
time.sleep(60)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_a_runs_forked_drawing_processes_end_when_the_run_is_killed():
    import os
    import signal

    run = subprocess.Popen(
        [sys.executable, "-c", DRAWER], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        pids = [int(p) for p in run.stdout.readline().split()]
        assert len(pids) == 2
        os.kill(run.pid, signal.SIGKILL)
        run.wait(30)
        deadline = time.monotonic() + 20
        left = pids
        while left and time.monotonic() < deadline:
            left = [p for p in left if _alive(p)]
            time.sleep(0.1)
        assert not left, f"drawing processes {left} outlived the killed run"
    finally:
        if run.poll() is None:
            run.kill()


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie nobody reaped yet has exited)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat[stat.rindex(")") + 2] != "Z"
