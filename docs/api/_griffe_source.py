"""MkDocs hook: lay out the package ``treesim`` where griffe can read it.

mkdocstrings' griffe finds a package by its folder's name, but the repository keeps the
library in ``pipeline/`` and the service in ``service/`` (setuptools maps them to
``treesim`` and ``treesim.service`` at install time). So before each build this hook makes
``build/docs-src/treesim/``: a link to every entry of ``pipeline/`` plus ``service`` linking
to ``service/``, the layout the installed package has. Griffe then reads the source
statically (nothing is imported, so a heavy or optional dependency cannot break the build).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Where the layout is made (``build/`` is git-ignored); ``mkdocs.yml`` points griffe there.
STAGE = ROOT / "build" / "docs-src"


def stage_package(root: Path = ROOT, stage: Path = STAGE) -> Path:
    """Make ``stage/treesim`` mirror the installed package and return ``stage``.

    Parameters
    ----------
    root : Path
        The repository's root (``pipeline/`` and ``service/`` beside each other).
    stage : Path
        The folder to lay the package out in; remade from scratch each time, so a module
        added or removed since the last build is seen.

    Returns
    -------
    Path
        ``stage``, the folder to give griffe as a search path.
    """
    package = stage / "treesim"
    if stage.exists():
        shutil.rmtree(stage)
    package.mkdir(parents=True)
    for entry in sorted((root / "pipeline").iterdir()):
        if entry.name in {"__pycache__", "service"}:
            continue
        (package / entry.name).symlink_to(os.path.relpath(entry, package))
    (package / "service").symlink_to(os.path.relpath(root / "service", package))
    return stage


def on_startup(command: str, dirty: bool) -> None:  # noqa: ARG001 (MkDocs' hook signature)
    """Lay out the package before MkDocs reads its configuration's plugins."""
    stage_package()


def on_config(config):  # noqa: ANN001 (MkDocs' hook signature)
    """Lay it out again per build (``mkdocs serve`` rebuilds without a new start-up)."""
    stage_package()
    return config
