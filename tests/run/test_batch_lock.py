"""The output folder's lock (``treesim.batch._lock``): one batch or sweep per folder, held
across processes through filelock, refused at once with a clear error, released at the end."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from treesim.batch import _LOCK_NAME, _lock
from treesim.errors import InvalidParameterError

ROOT = Path(__file__).resolve().parents[2]

#: A process that takes the folder's lock, says so, and holds it until its stdin closes.
HOLDER = """
import sys
from pathlib import Path
from treesim.batch import _lock
with _lock(Path(sys.argv[1]), "sweep"):
    print("held", flush=True)
    sys.stdin.read()
"""


def test_a_second_process_is_refused_at_once_then_admitted(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(tmp_path)],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        assert (tmp_path / _LOCK_NAME).is_file()
        # refused without waiting: the message names the folder and what to do
        with pytest.raises(InvalidParameterError, match=r"another batch is writing into "):
            with _lock(tmp_path):
                pytest.fail("took a lock another process holds")
        with pytest.raises(InvalidParameterError, match=r"another sweep is writing into "):
            with _lock(tmp_path, "sweep"):
                pytest.fail("took a lock another process holds")
    finally:
        holder.stdin.close()
        assert holder.wait(60) == 0
    # the holder's lock went with it
    with _lock(tmp_path):
        entered = True
    assert entered


def test_the_lock_is_released_when_the_block_raises(tmp_path):
    with pytest.raises(RuntimeError, match="boom"):
        with _lock(tmp_path):
            raise RuntimeError("boom")
    with _lock(tmp_path):
        pass


def test_one_process_cannot_take_the_same_folder_twice(tmp_path):
    # a second batch started from the same process (another thread, or nested) is refused too
    with _lock(tmp_path):
        with pytest.raises(InvalidParameterError, match="another batch"):
            with _lock(tmp_path):
                pass
