"""JSON output shared by every stage: plain values, no NaN, written atomically."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .atomic import write_text
from .errors import InputFormatError


def json_ready(value: Any) -> Any:
    """Plain-JSON form of ``value``, recursively: numpy scalars and arrays become Python
    numbers and lists, paths strings, and NaN or infinite floats ``None``."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    # a numpy value exists only where numpy is loaded: this module does not load it (the
    # CLI's parameters use it, and `treesim plan --help` should not pay numpy's import)
    np = sys.modules.get("numpy")
    if np is not None and isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if np is not None and isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | Path, data: Any, *, default: Callable[[Any], Any] | None = None) -> Path:
    """Write ``data`` as indented JSON, atomically: the one JSON writer of treesim.

    ``data`` goes through :func:`json_ready` (no NaN: ``null``), then
    :func:`treesim.atomic.write_text` (a temporary file of its own, renamed into place),
    so a half-written file is never seen and two writers of one path never mix.

    Parameters
    ----------
    path : str or Path
        The destination file; its folder must exist.
    data : Any
        Plain data (numpy values and paths are converted).
    default : callable, optional
        What :func:`json.dumps` calls for a value it cannot write (e.g. ``str``); by
        default such a value is a ``TypeError``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputFormatError
        If the file cannot be written (the OS error in the message).
    """
    p = Path(path)
    text = json.dumps(json_ready(data), indent=2, allow_nan=False, default=default) + "\n"
    try:
        write_text(p, text)
    except OSError as exc:
        raise InputFormatError(f"could not write {p}: {exc}") from exc
    return p
