"""The facade ``treesim`` imports its names when first used (PEP 562): every public name
still resolves, to the object of the module that defines it, and a verb that shares its
name with a subpackage (``scan``, ``reconstruct``, ``compare``) stays the verb after the
subpackage is loaded."""

from __future__ import annotations

import importlib
import inspect

import treesim


def test_every_public_name_resolves_to_its_defining_modules_object():
    for name in treesim.__all__:
        value = getattr(treesim, name)
        if name in treesim._LAZY:
            module = importlib.import_module(treesim._LAZY[name], "treesim")
            assert value is getattr(module, name), name
    assert set(treesim.__all__) <= set(dir(treesim))


def test_a_verb_stays_the_verb_once_its_subpackage_is_loaded():
    for verb in ("scan", "reconstruct", "compare"):
        package = importlib.import_module(f"treesim.{verb}")
        assert inspect.isfunction(getattr(treesim, verb)), verb
        assert getattr(treesim, verb) is getattr(package, verb)
    importlib.import_module("treesim.scan.trace")
    assert inspect.isfunction(treesim.scan)


def test_a_subpackage_is_reached_as_an_attribute():
    assert treesim.io.read_cloud is treesim.read_cloud
    assert treesim.scan.__module__ == "treesim.scan.trace"
    try:
        treesim.no_such_part  # noqa: B018
    except AttributeError as exc:
        assert "no_such_part" in str(exc)
    else:
        raise AssertionError("an unknown name must raise AttributeError")
