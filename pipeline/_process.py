"""Child processes that end with the process that started them (at the bottom of the package).

treesim runs work in processes of its own: a batch's local pool workers
(:mod:`treesim.executors`), a sweep's points (:mod:`treesim.sweep.point`), pymeshlab's
children (:mod:`treesim.reconstruct._pmlworker`) and the service's jobs. When their parent
dies (killed, out of memory) nobody reads what they produce, so each of them calls
:func:`exit_with_parent` and ends by itself instead of running on as an orphan. It imports
nothing from treesim.
"""

from __future__ import annotations

import os
import sys
import threading
import time

__all__ = ["ORPHANED_EXIT", "exit_with_parent"]

#: Exit status of a process that ended because its parent had gone (``EX_SOFTWARE``).
ORPHANED_EXIT = 70


def exit_with_parent(
    parent_pid: int, *, interval_s: float = 1.0, code: int = ORPHANED_EXIT
) -> threading.Thread:
    """End this process with ``code`` as soon as process ``parent_pid`` is gone.

    A daemon thread watches the parent and calls :func:`os._exit` (no clean-up: whatever
    the process was doing is of no use to anyone now). On POSIX it polls
    :func:`os.getppid` every ``interval_s`` seconds: an orphan is re-parented (to init or a
    sub-reaper), so its parent's pid changes. On Windows, which does not re-parent, it
    waits on a handle of the parent process instead (``interval_s`` is not used there).

    Parameters
    ----------
    parent_pid : int
        The pid of the parent, as the parent saw it (``os.getpid()`` there): passed down
        rather than read here, so that a parent that died before this call is noticed too.
    interval_s : float
        Seconds between two looks at the parent (POSIX).
    code : int
        The exit status (default :data:`ORPHANED_EXIT`, 70).

    Returns
    -------
    threading.Thread
        The watching thread, already started.
    """
    watch = _wait_for_windows_process if sys.platform == "win32" else _poll_parent_pid
    thread = threading.Thread(
        target=watch,
        args=(int(parent_pid), float(interval_s), int(code)),
        name="treesim-exit-with-parent",
        daemon=True,
    )
    thread.start()
    return thread


def _poll_parent_pid(parent_pid: int, interval_s: float, code: int) -> None:
    while True:
        time.sleep(interval_s)
        if os.getppid() != parent_pid:
            os._exit(code)  # the parent died: nothing will read our result


def _wait_for_windows_process(parent_pid: int, interval_s: float, code: int) -> None:
    import ctypes
    from ctypes import wintypes

    synchronize, infinite, wait_object_0 = 0x00100000, 0xFFFFFFFF, 0
    error_invalid_parameter = 87  # what OpenProcess says for a pid that no longer exists
    kernel32 = ctypes.WinDLL("kernel32", use_last_error=True)  # type: ignore[attr-defined]
    kernel32.OpenProcess.argtypes = [wintypes.DWORD, wintypes.BOOL, wintypes.DWORD]
    kernel32.OpenProcess.restype = wintypes.HANDLE
    kernel32.WaitForSingleObject.argtypes = [wintypes.HANDLE, wintypes.DWORD]
    kernel32.WaitForSingleObject.restype = wintypes.DWORD
    handle = kernel32.OpenProcess(synchronize, False, parent_pid)
    if not handle:
        if ctypes.get_last_error() == error_invalid_parameter:  # type: ignore[attr-defined]
            os._exit(code)  # already gone
        return  # cannot watch it (access denied): better to run on than to die wrongly
    if kernel32.WaitForSingleObject(handle, infinite) == wait_object_0:
        os._exit(code)
