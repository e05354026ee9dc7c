"""Names of a package imported on first use (PEP 562), for packages whose modules load
heavy libraries that a caller of one name should not pay for."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterable
from types import ModuleType
from typing import Any


def lazy_names(
    package: str, names: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package`` whose ``names`` (name → module,
    relative to the package) are imported when first used.

    Examples
    --------
    >>> getattr_, dir_ = lazy_names("json", {"dumps": "json"})
    >>> getattr_("dumps")([1])
    '[1]'
    """
    module_globals = vars(sys.modules[package])

    def __getattr__(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        module_globals[name] = value  # found directly from now on
        return value

    def __dir__() -> list[str]:
        return sorted(set(module_globals) | set(names))

    return __getattr__, __dir__


def keep_functions(package: str, names: Iterable[str]) -> None:
    """Keep the functions ``names`` of ``package`` bound when its submodules of the same
    names load: the import system binds a loaded submodule to its parent's attribute of
    that name, which would hide the function (as it did not when the package imported the
    function eagerly, after its module). The submodule stays reachable in ``sys.modules``
    and by from-imports.

    Examples
    --------
    >>> keep_functions("treesim.plan", ["visibility"])  # doctest: +SKIP
    """
    kept = frozenset(names)

    class _Package(ModuleType):
        def __setattr__(self, name: str, value: Any) -> None:
            if name in kept and isinstance(value, ModuleType):
                return
            super().__setattr__(name, value)

    sys.modules[package].__class__ = _Package
