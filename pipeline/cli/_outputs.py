"""Where a command writes, checked before it does any work.

Every command that writes calls :func:`output_file` or :func:`output_folder` on its
``-o`` first, so that an output it cannot write (a folder where a file is wanted, a file
where a folder is wanted or on the way to one, no permission, one of its own inputs) is a
one-line error (exit 1) before anything is read or computed, not an ``internal error``
after minutes of work.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from ..errors import InvalidParameterError

__all__ = ["output_file", "output_folder"]


def _nearest_existing(path: Path) -> Path:
    """The nearest folder above ``path`` that exists (``.`` at worst)."""
    for p in path.parents:
        if p.exists():
            return p
    return Path(".")


def _check_ancestors(path: Path, flag: str) -> None:
    above = _nearest_existing(path)
    if not above.is_dir():
        raise InvalidParameterError(
            f"cannot write {flag} {path}: {above} is a file, not a folder; give another path"
        )
    target = path if path.exists() else above
    if not os.access(target, os.W_OK | (os.X_OK if target.is_dir() else 0)):
        raise InvalidParameterError(
            f"cannot write {flag} {path}: {target} is not writable (permission denied)"
        )


def output_file(path: str | Path, *, flag: str = "-o", inputs: Iterable[str | Path] = ()) -> Path:
    """``path`` as a file a command may write (created with its folders if missing).

    Raises
    ------
    InvalidParameterError
        If ``path`` is a folder, a file stands where a folder of it should be, it is not
        writable, or it is one of ``inputs`` (which it would overwrite).
    """
    p = Path(path)
    if p.is_dir():
        raise InvalidParameterError(
            f"cannot write {flag} {p}: it is a folder; give a file name (one inside it)"
        )
    _check_ancestors(p, flag)
    if p.exists():
        for q in inputs:
            if Path(q).exists() and os.path.samefile(p, q):
                raise InvalidParameterError(
                    f"cannot write {flag} {p}: it is an input of this command and would be "
                    "overwritten; give another output path"
                )
    return p


def output_folder(path: str | Path, *, flag: str = "-o", files: Iterable[str] = ()) -> Path:
    """``path`` as a folder a command may write into (created if missing), ``files``
    the names the command writes inside it.

    Raises
    ------
    InvalidParameterError
        If ``path`` or a folder above it is a file, it is not writable, or one of
        ``files`` inside it is a folder.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InvalidParameterError(
            f"cannot write into {flag} {p}: it is a file, not a folder; give a folder "
            "(it is created if missing)"
        )
    _check_ancestors(p, flag)
    for name in files:
        if (p / name).is_dir():
            raise InvalidParameterError(
                f"cannot write {p / name}: it is a folder; move it away or give another {flag}"
            )
    return p
