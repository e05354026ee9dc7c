"""E57 point clouds (ASTM E2807), read through the optional ``pye57`` package.

An E57 file holds one or more scans, each with its own pose (rotation and translation
into the file's common frame) and Cartesian or spherical coordinates. :func:`read_e57`
reads every scan, applies its pose in float64 (so georeferenced translations keep full
precision), drops the points a scan marks invalid, and merges the scans into one
:class:`~treesim.cloud.Cloud`:

* ``points``: x, y, z in the file's common frame, float64;
* fields ``station`` (the 0-based scan index, int32), ``intensity`` (float64) and
  ``red``/``green``/``blue`` (as stored) when every scan has them;
* metadata ``source_path``, ``e57_scans`` (scan count) and ``stations``: each scan's
  position in the common frame (``[x, y, z]``, the origin of its pose), which is where the
  scanner stood.

``pye57`` is optional: install it with ``pip install pye57`` (MIT, manylinux wheels bundle
libE57Format). Without it, reading an ``.e57`` file raises
:class:`~treesim.errors.InputFormatError` saying so; nothing else needs it. Writing E57 is
not supported (write LAZ or PLY).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import Cloud
from ..errors import InputFormatError

#: Suffixes handled by this module.
SUFFIXES: tuple[str, ...] = (".e57",)

_COLOURS = (("colorRed", "red"), ("colorGreen", "green"), ("colorBlue", "blue"))


def available() -> bool:
    """Whether the optional ``pye57`` package can be imported."""
    try:
        import pye57  # noqa: F401
    except ImportError:
        return False
    return True


def read_e57(path: str | Path) -> Cloud:
    """Read every scan of an E57 file into one point cloud.

    Parameters
    ----------
    path : str or Path
        The ``.e57`` file.

    Returns
    -------
    Cloud
        See the module docstring for the points, fields and metadata.

    Raises
    ------
    InputFormatError
        If ``pye57`` is not installed, the file cannot be read as E57, or it holds no scan.
    """
    path = Path(path)
    try:
        import pye57
    except ImportError:
        raise InputFormatError(
            f"{path}: reading E57 needs the optional package pye57; install it with "
            "`pip install pye57`, or convert the file to LAZ or PLY (e.g. with CloudCompare)"
        ) from None
    try:
        e57 = pye57.E57(str(path))
    except Exception as exc:  # libE57Format raises its own exception types
        first = (str(exc).strip().splitlines() or ["unknown error"])[0]
        first = first.split(" (", 1)[0][:160]
        raise InputFormatError(
            f"{path} could not be read as E57 ({first}); is it a complete E57 file?"
        ) from exc
    try:
        n_scans = int(e57.scan_count)
        if n_scans == 0:
            raise InputFormatError(f"{path} holds no scans; it has no points")
        chunks: list[np.ndarray] = []
        per_scan: list[dict[str, np.ndarray]] = []
        stations: list[list[float]] = []
        for i in range(n_scans):
            try:
                data = e57.read_scan(
                    i, intensity=True, colors=True, transform=True, ignore_missing_fields=True
                )
                position = np.asarray(e57.scan_position(i), dtype=np.float64).reshape(-1)
            except InputFormatError:
                raise
            except Exception as exc:
                raise InputFormatError(f"{path}: scan {i} could not be read: {exc}") from exc
            xyz = np.column_stack(
                [np.asarray(data[f"cartesian{c}"], dtype=np.float64) for c in "XYZ"]
            )
            chunks.append(xyz)
            extra: dict[str, np.ndarray] = {"station": np.full(len(xyz), i, dtype=np.int32)}
            if "intensity" in data:
                extra["intensity"] = np.asarray(data["intensity"], dtype=np.float64)
            for src, name in _COLOURS:
                if src in data:
                    extra[name] = np.asarray(data[src])
            per_scan.append(extra)
            stations.append([float(x) for x in position[:3]])
    finally:
        e57.close()
    common = set(per_scan[0])
    for extra in per_scan[1:]:
        common &= set(extra)
    fields = {name: np.concatenate([e[name] for e in per_scan]) for name in sorted(common)}
    metadata: dict[str, Any] = {
        "source_path": str(path),
        "e57_scans": n_scans,
        "stations": stations,
    }
    return Cloud(np.concatenate(chunks), fields, metadata)
