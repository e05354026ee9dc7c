"""What every ``treesim`` command pays before it starts: the libraries a stage needs are
imported when the stage runs, not when the command line is built."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: Libraries of one stage each (scipy: reconstruction's fits; open3d: ray casting and
#: comparison; matplotlib: reports; pymeshlab: surfaces; the web stack: the service).
HEAVY = ("scipy", "open3d", "matplotlib", "pymeshlab", "fastapi", "pydantic", "sqlalchemy")


def test_building_the_command_line_imports_no_stage_library():
    code = (
        "import sys\n"
        "from treesim.cli import build_parser\n"
        "build_parser()\n"
        f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"imported at start-up: {out.stdout.strip()}"
