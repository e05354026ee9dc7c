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
  scanner stood, and ``stations_posed`` (per scan, whether the file gives it a pose: a
  scan without one is in its own frame, its scanner at the origin).

:func:`read_e57_stations` reads only the scans' poses (the field's station positions, for
``treesim plot scan --stations-from``). :func:`write_e57` writes a cloud with a ``station``
field and ``metadata["stations"]`` as one scan per station, each in its scanner's frame
with its pose (the translation; rotation identity), as a field team's registered project.

``pye57`` is optional: install it with ``pip install pye57`` (MIT, manylinux wheels bundle
libE57Format). Without it, reading or writing an ``.e57`` file raises
:class:`~treesim.errors.InputFormatError` saying so; nothing else needs it.
"""

from __future__ import annotations

import os
import uuid
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


def _pye57(path: Path, verb: str = "reading") -> Any:
    try:
        import pye57
    except ImportError:
        raise InputFormatError(
            f"{path}: {verb} E57 needs the optional package pye57; install it with "
            "`pip install pye57` (or `pip install treesim[e57]`), or convert the file to LAZ "
            "or PLY (e.g. with CloudCompare)"
        ) from None
    return pye57


def _open(path: Path) -> Any:
    pye57 = _pye57(path)
    try:
        return pye57.E57(str(path))
    except Exception as exc:  # libE57Format raises its own exception types
        first = (str(exc).strip().splitlines() or ["unknown error"])[0]
        first = first.split(" (", 1)[0][:160]
        raise InputFormatError(
            f"{path} could not be read as E57 ({first}); is it a complete E57 file?"
        ) from exc


def read_e57_stations(path: str | Path) -> list[list[float]]:
    """Each scan's scanner position (the origin of its pose) in the file's common frame.

    Only the scans' headers are read, not their points.

    Raises
    ------
    InputFormatError
        If the file cannot be read, holds no scan, or a scan has no pose (its position in
        the common frame is then unknown: give the stations as a CSV instead).

    Examples
    --------
    >>> from treesim.io.e57 import read_e57_stations
    >>> read_e57_stations("field.e57")  # doctest: +SKIP
    [[2.0, -3.5, 101.6], [-6.1, 4.0, 101.2]]
    """
    path = Path(path)
    e57 = _open(path)
    try:
        n_scans = int(e57.scan_count)
        if n_scans == 0:
            raise InputFormatError(f"{path} holds no scans, so no station positions")
        out = []
        for i in range(n_scans):
            header = e57.get_header(i)
            if not header.has_pose():
                raise InputFormatError(
                    f"{path}: scan {i} has no pose, so where its scanner stood in the "
                    "plot's frame is unknown; register the scans (e.g. in CloudCompare) or "
                    "give the stations as a CSV (x_m, y_m and z_m columns) instead"
                )
            out.append([float(v) for v in np.asarray(e57.scan_position(i)).reshape(-1)[:3]])
        return out
    finally:
        e57.close()


def write_e57(path: str | Path, cloud: Cloud) -> Path:
    """Write ``cloud`` as an E57 file: one scan per station, each with its pose.

    With a ``station`` field and ``metadata["stations"]`` (one ``[x, y, z]`` per station,
    as :func:`treesim.scan_plot` and :func:`read_e57` give), scan ``i`` holds the points of
    station ``i`` in its scanner's frame (the station at the origin), and its pose's
    translation is the station's position: readers get the points back in the common
    frame, to float64 precision, and the stations from the poses. Without them, one scan
    with an identity pose. ``intensity`` is written when present.

    Examples
    --------
    >>> import treesim as ts
    >>> from treesim.io.e57 import write_e57
    >>> write_e57("field.e57", ts.read_cloud("plot_scan.laz"))  # doctest: +SKIP
    """
    path = Path(path)
    pye57 = _pye57(path, "writing")
    pts = cloud.points
    if len(pts) == 0:
        raise InputFormatError(f"{path}: the cloud has no points; an E57 scan needs at least one")
    stations = cloud.metadata.get("stations")
    if "station" in cloud.fields and stations:
        idx = np.asarray(cloud.fields["station"]).astype(np.int64)
        if idx.min(initial=0) < 0 or idx.max(initial=0) >= len(stations):
            raise InputFormatError(
                f"{path}: the station field names {int(idx.max()) + 1} stations but the "
                f"cloud has {len(stations)} station positions"
            )
        groups = [
            (np.flatnonzero(idx == i), np.asarray(stations[i], float)) for i in range(len(stations))
        ]
    else:
        groups = [(np.arange(len(pts)), np.zeros(3))]
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        e57 = pye57.E57(str(tmp), mode="w")
        try:
            for i, (sel, origin) in enumerate(groups):
                if len(sel) == 0:
                    continue
                local = pts[sel] - origin
                data = {
                    f"cartesian{c}": np.ascontiguousarray(local[:, k]) for k, c in enumerate("XYZ")
                }
                if "intensity" in cloud.fields:
                    data["intensity"] = np.asarray(cloud.fields["intensity"], float)[sel]
                e57.write_scan_raw(
                    data,
                    name=f"station {i}",
                    rotation=np.array([1.0, 0.0, 0.0, 0.0]),
                    translation=origin,
                )
        finally:
            e57.close()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


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
    e57 = _open(path)
    try:
        n_scans = int(e57.scan_count)
        if n_scans == 0:
            raise InputFormatError(f"{path} holds no scans; it has no points")
        chunks: list[np.ndarray] = []
        per_scan: list[dict[str, np.ndarray]] = []
        stations: list[list[float]] = []
        posed: list[bool] = []
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
            posed.append(bool(e57.get_header(i).has_pose()))
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
        "stations_posed": posed,
    }
    return Cloud(np.concatenate(chunks), fields, metadata)
