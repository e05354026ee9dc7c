"""Atomic file output: write beside the destination, then rename into place.

treesim's writers go through :func:`atomic_path`, so a reader never sees a
half-written file and a failed write leaves the destination as it was (and no temporary
file behind). At the bottom of the package: it imports nothing from treesim.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text"]


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; move it onto ``path`` on success.

    The temporary file is ``.<name>.tmp`` beside ``path`` (same file system, so the
    final ``os.replace`` is atomic). If the ``with`` body raises, the temporary file is
    removed and the exception propagates; ``path`` is left untouched. OS errors are not
    mapped: callers translate them into their own messages.

    Parameters
    ----------
    path : str or Path
        The destination file; its folder must exist.

    Yields
    ------
    Path
        Where to write the content.
    """
    p = Path(path)
    tmp = p.with_name(f".{p.name}.tmp")
    try:
        yield tmp
        os.replace(tmp, p)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text(path: str | Path, text: str, *, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_path`).

    Parameters
    ----------
    path : str or Path
        The destination file; its folder must exist.
    text : str
        The whole content.
    encoding : str
        Text encoding (default UTF-8).

    Returns
    -------
    Path
        ``path``.
    """
    p = Path(path)
    with atomic_path(p) as tmp:
        tmp.write_text(text, encoding=encoding)
    return p
