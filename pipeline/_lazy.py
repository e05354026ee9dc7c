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


class _Mirrored(ModuleType):
    """A subpackage hidden behind its parent's function of the same name: each submodule
    bound to it is bound to the function too (see :func:`keep_functions`)."""

    def __setattr__(self, name: str, value: Any) -> None:
        super().__setattr__(name, value)
        if isinstance(value, ModuleType):
            _mirror(self, name, value)


def _mirror(sub: ModuleType, name: str, value: ModuleType) -> None:
    """Bind the submodule ``value`` to the function that hides ``sub`` (if any)."""
    parent, _, leaf = sub.__name__.rpartition(".")
    function = vars(sys.modules[parent]).get(leaf) if parent in sys.modules else None
    if callable(function) and not isinstance(function, ModuleType):
        setattr(function, name, value)


def mirror_submodules(package: str, name: str, function: Any) -> None:
    """Bind to ``function`` (the package's kept function ``name``, as its lazy name has
    just resolved it) the submodules of the subpackage ``package.name`` loaded so far;
    those loaded later are bound as they load (see :func:`keep_functions`).

    Examples
    --------
    >>> import email.mime.text
    >>> def mime(): ...
    >>> mirror_submodules("email", "mime", mime)
    >>> mime.text is email.mime.text
    True
    """
    prefix = f"{package}.{name}."
    for full, module in list(sys.modules.items()):
        if full.startswith(prefix) and "." not in full[len(prefix) :]:
            setattr(function, full[len(prefix) :], module)


def keep_functions(package: str, names: Iterable[str]) -> None:
    """Keep the functions ``names`` of ``package`` bound when its submodules of the same
    names load: the import system binds a loaded submodule to its parent's attribute of
    that name, which would hide the function (as it did not when the package imported the
    function eagerly, after its module). The submodule stays reachable in ``sys.modules``
    and by from-imports; and ``import package.name.module as m`` works, its last step
    reading ``module`` off the function: each submodule of the hidden subpackage is bound
    to the function too, those loaded before the function by the package's lazy name
    (:func:`mirror_submodules`), those loaded after as they load.

    Examples
    --------
    >>> keep_functions("treesim.plan", ["visibility"])  # doctest: +SKIP
    """
    kept = frozenset(names)

    class _Package(ModuleType):
        def __setattr__(self, name: str, value: Any) -> None:
            if name in kept and isinstance(value, ModuleType):
                value.__class__ = _Mirrored  # the package's lazy name mirrors what loaded
                return
            super().__setattr__(name, value)

    sys.modules[package].__class__ = _Package
