"""No function in the library (``pipeline/``) or the service (``service/``) runs over
``MAX_BODY_LINES`` lines of body (its docstring excluded): a longer one is stages that want
their own names (issue 22: ``fit_qsm`` had 437 body lines, ``scan`` 171).

Counted with ``ast`` from the first statement after the docstring to the end of the last
one, comments and blank lines inside included, as a reader meets them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAX_BODY_LINES = 100


def body_lines(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the first statement after the docstring to the end of the body."""
    body = fn.body
    first = body[0]
    if (
        isinstance(first, ast.Expr)
        and isinstance(first.value, ast.Constant)
        and isinstance(first.value.value, str)
    ):
        body = body[1:]
    if not body:
        return 0
    return body[-1].end_lineno - body[0].lineno + 1


def long_functions(folder: Path, limit: int) -> list[str]:
    out = []
    for path in sorted(folder.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = body_lines(node)
                if n > limit:
                    out.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {n} lines")
    return out


def test_the_counter_counts_a_body_without_its_docstring():
    src = 'def f():\n    """doc\n    more"""\n    a = 1\n\n    # why\n    return a\n'
    (fn,) = ast.parse(src).body
    assert body_lines(fn) == 4
    (g,) = ast.parse("def g():\n    return 1\n").body
    assert body_lines(g) == 1


@pytest.mark.parametrize("folder", ["pipeline", "service"])
def test_no_function_over_the_limit(folder):
    bad = long_functions(ROOT / folder, MAX_BODY_LINES)
    assert not bad, (
        f"functions with more than {MAX_BODY_LINES} body lines (split them into named "
        "stages):\n" + "\n".join(bad)
    )
