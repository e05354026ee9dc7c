"""Atomic file output: write beside the destination, then rename into place.

treesim's writers go through :func:`atomic_path` (the one place that does this), so a
reader never sees a half-written file, a failed write leaves the destination as it was
(and no temporary file behind), and two writers of one path never write into the same
temporary file: the last to finish wins, whole. At the bottom of the package: it imports
nothing from treesim.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text"]

#: Attempts at a free temporary name before giving up (each is 64 random bits: a clash
#: means something else is filling the folder with files of this pattern).
_NAME_ATTEMPTS = 100


def _reserve_temporary(path: Path) -> Path:
    """Create an empty ``.<name>.<random>.tmp`` beside ``path``, that no other writer has.

    Like :func:`tempfile.mkstemp` (``O_EXCL``: the name is ours once created), but with the
    permissions an ordinary ``open(path, "w")`` gives (``0o666`` less the umask) rather
    than mkstemp's ``0o600``: the temporary file becomes the output. The name keeps the
    ``.tmp`` suffix, so no writer that picks a format by suffix can take it for the
    destination's format.
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(_NAME_ATTEMPTS):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
        try:
            fd = os.open(tmp, flags, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"no free temporary name beside {path} after {_NAME_ATTEMPTS} tries")


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; move it onto ``path`` on success.

    The temporary file, ``.<name>.<random>.tmp`` beside ``path`` (same file system, so the
    final ``os.replace`` is atomic), exists and is empty when the block starts; writers
    overwrite it. Each call gets a name of its own, so concurrent writers of one path do
    not clobber each other's content: each moves a whole file into place. If the ``with``
    body raises, the temporary file is removed and the exception propagates; ``path`` is
    left untouched. OS errors are not mapped: callers translate them into their own
    messages.

    Parameters
    ----------
    path : str or Path
        The destination file; its folder must exist.

    Yields
    ------
    Path
        Where to write the content.

    Raises
    ------
    OSError
        If the temporary file cannot be created (a missing or read-only folder) or moved.
    """
    p = Path(path)
    tmp = _reserve_temporary(p)
    try:
        yield tmp
        os.replace(tmp, p)
    finally:
        # after a successful replace the name is gone; otherwise the partial file goes
        tmp.unlink(missing_ok=True)


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
