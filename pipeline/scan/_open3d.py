"""Open3D, imported without its Plotly/Dash viewer.

``import open3d`` (0.19) imports ``open3d.visualization.draw_plotly``, which imports
Plotly and Dash: about half of Open3D's import time (0.8 of 1.7 s of CPU measured on a
2-core host), paid by every scan, for a viewer treesim never opens. :func:`load_open3d`
imports Open3D with that one module standing in lazily: its three functions
(``get_plotly_fig``, ``draw_plotly``, ``draw_plotly_server``) import the real module
when first called, and so does any other of its names that Open3D asks for while it is
imported. Once Open3D is imported, the stand-in leaves ``sys.modules``: a later ``import
open3d.visualization.draw_plotly`` gets the real module. If Open3D is already imported,
nothing changes.
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Callable
from typing import Any

#: The Open3D module whose import pulls in Plotly and Dash.
VIEWER = "open3d.visualization.draw_plotly"
#: Its names that ``open3d.visualization`` imports (Open3D 0.19).
VIEWER_NAMES = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def _real_viewer() -> types.ModuleType:
    """The real viewer module, imported now (Plotly and Dash with it)."""
    if isinstance(sys.modules.get(VIEWER), _LazyViewer):
        del sys.modules[VIEWER]
    module = importlib.import_module(VIEWER)
    vis = sys.modules.get("open3d.visualization")
    if vis is not None:  # the import bound the module over the function of its name
        for name in VIEWER_NAMES:
            if hasattr(module, name):
                setattr(vis, name, getattr(module, name))
    return module


def _deferred(name: str) -> Callable[..., Any]:
    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(_real_viewer(), name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"Open3D's ``{name}``, imported (with Plotly and Dash) when first called."
    return call


class _LazyViewer(types.ModuleType):
    """The stand-in: the viewer's functions, deferred; any other name imports it."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(_real_viewer(), name)


def load_open3d() -> types.ModuleType:
    """The ``open3d`` module, imported without Plotly and Dash if not yet imported.

    Examples
    --------
    >>> o3d = load_open3d()
    >>> "dash" in sys.modules or hasattr(o3d.t.geometry, "RaycastingScene")
    True
    """
    if "open3d" in sys.modules or VIEWER in sys.modules:
        import open3d

        return open3d
    stand_in = _LazyViewer(VIEWER)
    for name in VIEWER_NAMES:
        setattr(stand_in, name, _deferred(name))
    sys.modules[VIEWER] = stand_in
    try:
        import open3d
    finally:
        if sys.modules.get(VIEWER) is stand_in:
            del sys.modules[VIEWER]
    return open3d
