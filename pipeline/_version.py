"""treesim's version and the versions of the software a result was made with.

At the bottom of the package: it imports nothing from treesim, so every stage can record
what made its outputs without importing another stage.
"""

from __future__ import annotations

import platform
import sys

__all__ = ["__version__", "software_versions"]

__version__ = "0.2.0"


def software_versions(*extra: str) -> dict[str, str]:
    """Versions of Python, treesim and the numerical libraries (plus ``extra`` modules).

    Parameters
    ----------
    *extra : str
        Further distribution names to report (e.g. ``"pymeshlab"``).

    Returns
    -------
    dict of str -> str
        ``treesim``, ``python``, ``platform``, then ``numpy``, ``scipy``, ``open3d``,
        ``laspy``, ``plyfile`` and ``extra`` in that order; a distribution that is not
        installed reads ``"not installed"``.
    """
    from importlib import metadata

    out = {
        "treesim": __version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(terse=True),
    }
    for name in ("numpy", "scipy", "open3d", "laspy", "plyfile", *extra):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out
