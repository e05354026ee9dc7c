"""What every ``treesim`` command pays before it starts: the libraries a stage needs are
imported when the stage runs, not when the command line is built, nor when ``--help`` of
any command is printed. The oracle is ``sys.modules`` of a fresh interpreter, not a time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: Libraries of one stage each (scipy: reconstruction's fits; open3d: ray casting and
#: comparison; matplotlib: reports; pymeshlab and trimesh: surfaces; laspy: LAS/LAZ files;
#: dask and pandas: batches on a cluster; the web stack: the service).
HEAVY = (
    "scipy",
    "open3d",
    "matplotlib",
    "pymeshlab",
    "trimesh",
    "laspy",
    "lazrs",
    "dask",
    "distributed",
    "pandas",
    "fastapi",
    "pydantic",
    "sqlalchemy",
)


def _loaded(code: str) -> list[str]:
    """The modules of :data:`HEAVY` (and numpy) that ``code`` leaves in ``sys.modules``."""
    names = (*HEAVY, "numpy")
    probe = (
        f"import json, sys\n{code}\nprint(json.dumps([m for m in {names!r} if m in sys.modules]))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", probe], env=env, cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def _help(*words: str) -> str:
    """Code that prints ``treesim WORDS --help`` as the command does (into nothing)."""
    return (
        "import contextlib, io\n"
        "from treesim.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        f"    main({[*words, '--help']!r})\n"
    )


def test_building_the_command_line_imports_no_stage_library():
    loaded = _loaded("from treesim.cli import build_parser\nbuild_parser()")
    assert [m for m in loaded if m != "numpy"] == [], f"imported at start-up: {loaded}"


def test_importing_the_command_line_imports_not_even_numpy():
    assert _loaded("import treesim.cli") == []
    assert _loaded("import treesim") == []


def test_the_commands_list_imports_not_even_numpy():
    """``treesim --help`` lists the commands without importing their modules."""
    assert _loaded(_help()) == []


@pytest.mark.parametrize(
    "command",
    [
        "scan",
        "plot",
        "model",
        "reconstruct",
        "compare",
        "report",
        "run",
        "batch",
        "sweep",
        "plan",
        "validate",
        "demo",
    ],
)
def test_a_commands_help_imports_no_stage_library(command):
    loaded = _loaded(_help(command))
    assert [m for m in loaded if m != "numpy"] == [], f"'treesim {command} --help': {loaded}"


def test_the_plan_commands_help_imports_not_even_numpy():
    """Issue 25 names ``treesim plan --help`` (under 0.3 s): its options come from the
    parameters alone (numpy's import was most of its time)."""
    assert _loaded(_help("plan")) == []


def test_the_commands_list_says_what_the_commands_register():
    """The lines of ``treesim --help`` (``SUMMARIES``, written out so that the list imports
    no command) are those the command modules register, in the same order."""
    from treesim.cli import COMMANDS, SUMMARIES, build_parser

    full = build_parser()
    listed = build_parser(only="")
    assert listed.format_help() == full.format_help()
    sub = next(a for a in full._actions if a.dest == "command")
    registered = {a.dest: a.help for a in sub._choices_actions}
    assert {c: registered[c] for c in COMMANDS} == SUMMARIES
    for command in COMMANDS:  # each command's own parser is the full one
        alone = build_parser(only=command)
        one = next(a for a in alone._actions if a.dest == "command").choices[command]
        assert one.format_help() == sub.choices[command].format_help()


def test_a_built_in_commands_run_reads_no_distribution_metadata():
    """Commands from other packages (entry points) are looked up for the commands list and
    for a command that is not built in, not for ``treesim scan ...``: the look-up reads
    every installed distribution's metadata at start-up. The oracle is ``sys.modules``."""
    probe = (
        "import sys\nfrom treesim.cli import build_parser\n"
        "build_parser(only={only!r})\nprint('importlib.metadata' in sys.modules)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    seen = {}
    for only in ("scan", ""):
        out = subprocess.run(
            [sys.executable, "-c", probe.format(only=only)],
            env=env,
            cwd=ROOT,
            capture_output=True,
            text=True,
        )
        assert out.returncode == 0, out.stderr
        seen[only] = out.stdout.strip().splitlines()[-1]
    assert seen == {"scan": "False", "": "True"}
