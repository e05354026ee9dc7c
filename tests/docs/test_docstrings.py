"""Every verb and type the facade exports (``treesim.__all__``) has a numpydoc docstring
with an ``Examples`` section, functions a ``Parameters`` section naming each of their
parameters; and the examples run (doctest), except lines marked ``# doctest: +SKIP``
(those need a user's files or run the loop for long). The examples of every other
module's functions and classes run too (the architecture tests ask each public function
for one)."""

from __future__ import annotations

import doctest
import importlib
import inspect
import pkgutil
import re

import pytest

import treesim

PUBLIC = [
    name
    for name in treesim.__all__
    if inspect.isfunction(getattr(treesim, name)) or inspect.isclass(getattr(treesim, name))
]


def sections(doc: str) -> dict[str, str]:
    """A numpydoc docstring's sections by title (``Parameters``, ``Examples``, ...)."""
    found = {}
    parts = re.split(r"^([A-Z][A-Za-z ]+)\n(-{3,})$", doc, flags=re.M)
    # parts: [summary, title, underline, body, title, underline, body, ...]
    for title, underline, body in zip(parts[1::3], parts[2::3], parts[3::3], strict=True):
        if len(underline) == len(title):
            found[title] = body
    return found


def documented_parameters(body: str) -> set[str]:
    """The names a numpydoc Parameters section documents (``a, b : int`` names two)."""
    names = set()
    for line in body.splitlines():
        if line and not line[0].isspace():
            for name in line.split(":")[0].split(","):
                names.add(name.strip().lstrip("*"))
    return names


def test_sections_reads_numpydoc():
    doc = (
        "Summary.\n\nParameters\n----------\na, b : int\n    Two.\nc : str\n\n"
        "Examples\n--------\n>>> 1\n1\n"
    )
    found = sections(doc)
    assert list(found) == ["Parameters", "Examples"]
    assert documented_parameters(found["Parameters"]) == {"a", "b", "c"}


def test_the_facade_exports_the_plot_and_plan_verbs():
    assert {"Plot", "PlotTree", "Terrain", "read_plot", "scan_plot", "plan_scans"} <= set(PUBLIC)


@pytest.mark.parametrize("name", PUBLIC)
def test_documented(name):
    obj = getattr(treesim, name)
    doc = inspect.getdoc(obj) or ""
    found = sections(doc)
    assert "Examples" in found and ">>>" in found["Examples"], f"treesim.{name}: no Examples"
    if inspect.isfunction(obj):
        assert "Parameters" in found, f"treesim.{name}: no Parameters section"
        wanted = {
            p.name
            for p in inspect.signature(obj).parameters.values()
            if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        }
        missing = wanted - documented_parameters(found["Parameters"])
        assert not missing, f"treesim.{name}: parameters not documented: {sorted(missing)}"


@pytest.mark.parametrize("name", PUBLIC)
def test_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples write their files here
    monkeypatch.setenv("MPLBACKEND", "Agg")
    obj = getattr(treesim, name)
    tests = doctest.DocTestFinder(recurse=False).find(obj, f"treesim.{name}", globs={})
    runner = doctest.DocTestRunner(
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False
    )
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"treesim.{name}: {result.failed} example(s) failed (above)"


def _library_modules() -> list[str]:
    """Every module of the library (``treesim.*``, the service's too), ``__main__``
    modules left out (importing one runs it)."""
    found = pkgutil.walk_packages(treesim.__path__, "treesim.")
    return sorted(m.name for m in found if not m.name.endswith("__main__"))


@pytest.mark.parametrize("module", _library_modules())
def test_every_modules_examples_run(module, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples write their files here
    monkeypatch.setenv("MPLBACKEND", "Agg")
    mod = importlib.import_module(module)
    tests = doctest.DocTestFinder().find(mod, module)
    runner = doctest.DocTestRunner(
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False
    )
    for test in tests:
        if test.examples and test.name.startswith(module):  # its own, not an import's
            runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{module}: {result.failed} example(s) failed (above)"
