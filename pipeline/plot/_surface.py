"""Terrain surfaces read from files: a DTM raster (ESRI ASCII grid) or a ground cloud.

Both give a height function ``z(x, y)`` in the plot's frame (the file's coordinates):

* ``dtm``: bilinear between cell centres; outside the centres' rectangle the nearest
  edge's value (clamped). NODATA cells take their nearest valid cell's value.
* ``cloud``: the ground points' Delaunay triangulation in x, y, linear on each triangle
  (:class:`scipy.interpolate.LinearNDInterpolator`); outside the points' convex hull the
  nearest point's height. Points sharing an x, y take their mean height; clouds of more
  than :data:`MAX_GROUND_POINTS` points are averaged over a square grid first.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import EmptyInputError, InputFormatError

__all__ = [
    "ASC_NODATA",
    "MAX_GROUND_POINTS",
    "DTM_SUFFIXES",
    "read_asc",
    "surface_from_cloud",
    "surface_from_dtm",
    "surface_from_grid",
    "write_asc",
]

#: Ground clouds larger than this are averaged over a grid before triangulation.
MAX_GROUND_POINTS = 400_000
#: Raster formats a ``dtm`` terrain reads.
DTM_SUFFIXES = (".asc",)

Height = Callable[[np.ndarray, np.ndarray], np.ndarray]

_ASC_KEYS = ("ncols", "nrows", "xllcorner", "yllcorner", "xllcenter", "yllcenter", "cellsize")


def read_asc(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read an ESRI ASCII grid.

    Returns
    -------
    x : (ncols,) float64
        Cell-centre x, ascending.
    y : (nrows,) float64
        Cell-centre y, ascending (the file's last row first).
    z : (ncols, nrows) float64
        Heights, NaN where the file has NODATA.
    """
    p = Path(path)
    fix = "write it as an ESRI ASCII grid (ncols, nrows, xllcorner, yllcorner, cellsize, then rows)"
    try:
        lines = p.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{p}: cannot read the DTM ({exc}); {fix}") from exc
    head: dict[str, float] = {}
    i = 0
    while i < len(lines):
        tok = lines[i].split()
        if not tok:
            i += 1
            continue
        key = tok[0].lower()
        if key in (*_ASC_KEYS, "nodata_value") and len(tok) == 2:
            try:
                head[key] = float(tok[1])
            except ValueError as exc:
                raise InputFormatError(f"{p}: header {tok[0]} is not a number; {fix}") from exc
            i += 1
        else:
            break
    need = ["ncols", "nrows", "cellsize"]
    missing = [k for k in need if k not in head]
    if (
        missing
        or not (("xllcorner" in head) or ("xllcenter" in head))
        or not (("yllcorner" in head) or ("yllcenter" in head))
    ):
        raise InputFormatError(
            f"{p}: the DTM header lacks {', '.join(missing) or 'xllcorner/yllcorner'}; {fix}"
        )
    nc, nr, cs = int(head["ncols"]), int(head["nrows"]), head["cellsize"]
    if nc < 1 or nr < 1 or not (math.isfinite(cs) and cs > 0):
        raise InputFormatError(f"{p}: ncols, nrows and cellsize must be > 0; {fix}")
    try:
        vals = np.array(" ".join(lines[i:]).split(), dtype=np.float64)
    except ValueError as exc:
        raise InputFormatError(f"{p}: a DTM cell is not a number; {fix}") from exc
    if vals.size != nc * nr:
        raise InputFormatError(
            f"{p}: the DTM has {vals.size} cells, its header says {nr} rows x {nc} columns; {fix}"
        )
    z = vals.reshape(nr, nc)[::-1].T.copy()  # (ncols, nrows), y ascending
    if "nodata_value" in head:
        z[z == head["nodata_value"]] = np.nan
    z[~np.isfinite(z)] = np.nan
    x0 = head["xllcenter"] if "xllcenter" in head else head["xllcorner"] + 0.5 * cs
    y0 = head["yllcenter"] if "yllcenter" in head else head["yllcorner"] + 0.5 * cs
    return x0 + cs * np.arange(nc), y0 + cs * np.arange(nr), z


#: The NODATA value :func:`write_asc` writes for NaN cells.
ASC_NODATA = -9999.0


def write_asc(path: str | Path, x0: float, y0: float, cell_m: float, z: np.ndarray) -> Path:
    """Write an ESRI ASCII grid that :func:`read_asc` reads back exactly.

    Parameters
    ----------
    path : str or Path
        The ``.asc`` file to write.
    x0, y0 : float
        The grid's lower-left corner (``xllcorner``, ``yllcorner``), in the file's
        coordinates.
    cell_m : float
        The cell size (> 0).
    z : (ncols, nrows) array
        Heights in :func:`read_asc`'s layout (x first, y ascending); NaN cells are written
        as NODATA (:data:`ASC_NODATA`).

    Returns
    -------
    Path
        The file written. Values are written with the shortest text that parses back to
        the same float64 (``repr``), so a read gives the very same numbers.

    Examples
    --------
    >>> import numpy as np
    >>> z = np.array([[1.0, 2.0], [np.nan, 4.25]])
    >>> p = write_asc("dtm.asc", 100.0, 200.0, 0.5, z)  # doctest: +SKIP
    >>> read_asc(p)[2]  # doctest: +SKIP
    array([[1.  , 2.  ],
           [ nan, 4.25]])
    """
    z = np.asarray(z, dtype=np.float64)
    if z.ndim != 2 or z.size == 0:
        raise InputFormatError(f"{path}: a DTM grid must be a non-empty 2-D array, got {z.shape}")
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise InputFormatError(f"{path}: the DTM cell size must be > 0, got {cell_m}")
    nc, nr = z.shape
    rows = z[:, ::-1].T  # the file's first row is the northern one
    lines = [
        f"ncols {nc}",
        f"nrows {nr}",
        f"xllcorner {float(x0)!r}",
        f"yllcorner {float(y0)!r}",
        f"cellsize {float(cell_m)!r}",
        f"NODATA_value {ASC_NODATA!r}",
    ]
    nodata = repr(ASC_NODATA)
    for row in rows.tolist():
        lines.append(" ".join(nodata if math.isnan(v) else repr(v) for v in row))
    p = Path(path)
    p.write_text("\n".join(lines) + "\n")
    return p


def _fill_nodata(z: np.ndarray, where: str) -> np.ndarray:
    bad = np.isnan(z)
    if bad.all():
        raise EmptyInputError(f"{where}: every DTM cell is NODATA")
    if bad.any():
        from scipy.ndimage import distance_transform_edt

        idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
        z = z[tuple(idx)]
    return z


def surface_from_dtm(path: str | Path) -> Height:
    """The height function of a DTM raster (:data:`DTM_SUFFIXES`)."""
    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"{p}: DTM not found; check the terrain path")
    if p.suffix.lower() not in DTM_SUFFIXES:
        raise InputFormatError(
            f"{p}: a DTM must be an ESRI ASCII grid ({', '.join(DTM_SUFFIXES)}); convert it "
            "(e.g. gdal_translate -of AAIGrid in.tif out.asc) or give the ground points as a "
            "cloud terrain"
        )
    xs, ys, z = read_asc(p)
    return surface_from_grid(xs, ys, _fill_nodata(z, str(p)))


def surface_from_grid(xs: np.ndarray, ys: np.ndarray, z: np.ndarray) -> Height:
    """The bilinear height function of a grid of cell-centre heights (no NaN).

    ``xs`` (ncols,) and ``ys`` (nrows,) are evenly spaced ascending cell centres and ``z``
    is (ncols, nrows), as :func:`read_asc` returns them. Between the centres the height is
    bilinear; outside the centres' rectangle it is the nearest edge's value (clamped).

    Examples
    --------
    >>> import numpy as np
    >>> f = surface_from_grid(np.array([0.5, 1.5]), np.array([0.5]), np.array([[1.0], [3.0]]))
    >>> f(np.array([1.0, 9.0]), np.array([0.0, 0.0])).tolist()
    [2.0, 3.0]
    """

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast_shapes(x.shape, y.shape)
        x, y = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
        out = np.empty(x.shape)
        fx = _frac_index(xs, x)
        fy = _frac_index(ys, y)
        i0, j0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
        i0 = np.clip(i0, 0, max(len(xs) - 2, 0))
        j0 = np.clip(j0, 0, max(len(ys) - 2, 0))
        i1, j1 = np.minimum(i0 + 1, len(xs) - 1), np.minimum(j0 + 1, len(ys) - 1)
        tx, ty = np.clip(fx - i0, 0.0, 1.0), np.clip(fy - j0, 0.0, 1.0)
        out[:] = (
            z[i0, j0] * (1 - tx) * (1 - ty)
            + z[i1, j0] * tx * (1 - ty)
            + z[i0, j1] * (1 - tx) * ty
            + z[i1, j1] * tx * ty
        )
        return out.reshape(shape)

    return height


def _frac_index(centres: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Fractional index of ``v`` among evenly spaced ``centres`` (clamped to them)."""
    if len(centres) == 1:
        return np.zeros_like(v)
    step = centres[1] - centres[0]
    return np.clip((v - centres[0]) / step, 0.0, len(centres) - 1.0)


def surface_from_cloud(path: str | Path) -> Height:
    """The height function of a ground point cloud (any format :func:`read_cloud` reads)."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
    from scipy.spatial import QhullError

    from ..io import read_cloud

    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"{p}: ground cloud not found; check the terrain path")
    pts = read_cloud(p).points
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        raise EmptyInputError(f"{p}: the ground cloud has no (finite) points")
    xy, z = _thin(pts)
    near = NearestNDInterpolator(xy, z)
    if len(xy) < 3:
        lin = None
    else:
        try:
            lin = LinearNDInterpolator(xy, z)
        except QhullError:  # all on a line: nearest everywhere
            lin = None

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast_shapes(x.shape, y.shape)
        q = np.stack([np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()], 1)
        out = np.full(len(q), np.nan) if lin is None else lin(q)
        miss = np.isnan(out)
        if miss.any():
            out[miss] = near(q[miss])
        return out.reshape(shape)

    return height


def _thin(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x, y and the mean z of each distinct x, y (of each grid cell for big clouds)."""
    xy = pts[:, :2]
    if len(pts) > MAX_GROUND_POINTS:
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        cell = max(float(np.sqrt(np.prod(np.maximum(hi - lo, 1e-9)) / MAX_GROUND_POINTS)), 1e-6)
        key = np.floor((xy - lo) / cell).astype(np.int64)
    else:
        key = xy
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    sx = np.bincount(inv, xy[:, 0]) / cnt
    sy = np.bincount(inv, xy[:, 1]) / cnt
    sz = np.bincount(inv, pts[:, 2]) / cnt
    return np.stack([sx, sy], axis=1), sz
