"""Every ``treesim`` command imports the package, and the package imports
:mod:`treesim.sweep`: what a sweep needs only while it runs (its page, the point's
process, the plotting and ray-casting libraries, the TOML reader) stays unloaded."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: Loaded only when a sweep runs, reads its file or draws its page.
LATER = (
    "treesim.report.sweep_page",
    "treesim.sweep.point",
    "matplotlib",
    "open3d",
    "tomllib",
)


def test_importing_the_package_loads_none_of_the_sweeps_run_time_parts():
    code = (
        "import json, sys, treesim; "
        f"print(json.dumps(sorted(m for m in {LATER!r} if m in sys.modules)))"
    )
    env = dict(os.environ)
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, check=True
    ).stdout
    assert json.loads(out) == [], "imported by 'import treesim' (every treesim command)"
