"""How a user imports treesim's modules (the facade keeps ``treesim.scan``,
``treesim.reconstruct`` and ``treesim.compare`` the functions, also once their
subpackages load). Each statement runs in a fresh interpreter: what is already imported
changes what an import statement sees. The oracle is Python's own import system."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(code: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd="/", capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()


@pytest.mark.parametrize(
    "statement, module",
    [
        ("import treesim.scan.beam as m", "treesim.scan.beam"),
        ("import treesim.scan.footprint as m", "treesim.scan.footprint"),
        ("import treesim.reconstruct.qsm as m", "treesim.reconstruct.qsm"),
        ("import treesim.reconstruct.leafwood as m", "treesim.reconstruct.leafwood"),
        ("import treesim as ts\nts.scan\nimport treesim.scan.rays as m", "treesim.scan.rays"),
        ("from treesim.scan import caster as m", "treesim.scan.caster"),
    ],
)
def test_a_submodule_of_a_verbs_subpackage_imports_by_any_statement(statement, module):
    code = (
        f"{statement}\nimport treesim, types\n"
        "print(m.__name__, isinstance(treesim.scan, types.FunctionType), "
        "isinstance(treesim.reconstruct, types.FunctionType))"
    )
    assert _run(code) == f"{module} True True"


def test_the_verbs_are_the_functions_after_their_subpackages_load():
    code = (
        "import types, treesim.scan.beam, treesim.reconstruct.qsm, treesim.compare\n"
        "import treesim as ts\n"
        "print([type(f) is types.FunctionType for f in (ts.scan, ts.reconstruct, ts.compare)],"
        " ts.scan.beam is treesim.scan.beam)"
    )
    assert _run(code) == "[True, True, True] True"
