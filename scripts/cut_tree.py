"""Cut one tree's column out of a public TLS plot cloud, reproducibly.

A field cloud of a single tree is usually a column cut from a plot scan: the ground,
litter, understory and the neighbours' branches come with it. This script makes such a
cut from a plot cloud by one documented rule, so that the cut can be repeated from the
source file and nothing is hand-edited:

1. Stems are found as vertical columns of points between 0.5 and 4.0 m above the
   terrain. The terrain height under each point is the 2nd percentile of z in its
   1 m x 1 m cell (cells with fewer than 20 points take the plot's 2nd percentile).
   Points in that band are rasterised at 5 cm; a cell is stem-like when at least 10 of
   its 14 height bins (0.25 m each) hold a point (shrubs, litter and low branches fill
   only a few). Stem-like cells, closed by one cell, are grouped by 8-connectivity;
   a group with at least 30 points in the 1.0-1.6 m slab is a stem candidate, whose
   centre and diameter are the algebraic (Kasa) circle fitted to those slab points.
2. ``--list`` prints the candidates (centre, circle diameter, points, distance to the
   nearest other candidate) so that the choice of tree is visible.
3. The cut keeps every point whose horizontal distance to the chosen stem centre is at
   most ``--radius-m``, at any height: no point is thinned, moved or dropped inside the
   column. Coordinates, intensity and the other LAS fields are copied unchanged.

Usage::

    python scripts/cut_tree.py PLOT.laz --list
    python scripts/cut_tree.py PLOT.laz --stem K --radius-m 2.0 -o OUT.laz

The stem index K refers to the ``--list`` output, which is sorted by x then y of the
centre, so it does not depend on the order of the points in the file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import laspy
import numpy as np
from scipy import ndimage

SLAB_LOW_M = 1.0
SLAB_HIGH_M = 1.6
GROUND_CELL_M = 1.0
GROUND_PERCENTILE = 2.0
GROUND_MIN_POINTS = 20
RASTER_M = 0.05
MIN_STEM_POINTS = 30
BAND_LOW_M = 0.5
BAND_HIGH_M = 4.0
BIN_M = 0.25
MIN_BINS = 10


def terrain_height_m(xyz_m: np.ndarray) -> np.ndarray:
    """Terrain height under each point (m): low percentile of z in its ground cell.

    Parameters
    ----------
    xyz_m : (N, 3) float64 array
        Point coordinates (m).

    Returns
    -------
    (N,) float64 array
        Terrain height under each point (m).
    """
    ij = np.floor((xyz_m[:, :2] - xyz_m[:, :2].min(axis=0)) / GROUND_CELL_M).astype(np.int64)
    keys = ij[:, 0] * 1_000_003 + ij[:, 1]
    uniq, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    fallback_m = np.percentile(xyz_m[:, 2], GROUND_PERCENTILE)
    ground_m = np.full(len(uniq), fallback_m)
    order = np.argsort(inverse, kind="stable")
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    z_sorted = xyz_m[order, 2]
    for k, (start, count) in enumerate(zip(starts, counts, strict=True)):
        if count >= GROUND_MIN_POINTS:
            ground_m[k] = np.percentile(z_sorted[start : start + count], GROUND_PERCENTILE)
    return ground_m[inverse]


def kasa_circle(xy_m: np.ndarray) -> tuple[float, float, float]:
    """Algebraic least-squares circle (Kasa) through 2-D points.

    Parameters
    ----------
    xy_m : (N, 2) float64 array
        Points (m).

    Returns
    -------
    tuple of float
        Centre x, centre y and radius (m).
    """
    mean_m = xy_m.mean(axis=0)
    local_m = xy_m - mean_m  # centred: georeferenced coordinates would ruin the squares
    a = np.c_[2.0 * local_m, np.ones(len(local_m))]
    b = (local_m**2).sum(axis=1)
    (cx, cy, c), *_ = np.linalg.lstsq(a, b, rcond=None)
    radius_m = float(np.sqrt(max(c + cx * cx + cy * cy, 0.0)))
    return float(cx + mean_m[0]), float(cy + mean_m[1]), radius_m


def find_stems(xyz_m: np.ndarray) -> list[dict]:
    """Stem candidates: vertical point columns 0.5-4.0 m above the terrain.

    Parameters
    ----------
    xyz_m : (N, 3) float64 array
        Plot points (m).

    Returns
    -------
    list of dict
        One dict per candidate (keys ``x_m``, ``y_m``, ``dbh_m``, ``points``,
        ``nearest_m``), sorted by centre x then y.
    """
    above_m = xyz_m[:, 2] - terrain_height_m(xyz_m)
    band = (above_m >= BAND_LOW_M) & (above_m < BAND_HIGH_M)
    if not band.any():
        return []
    xy = xyz_m[band, :2]
    origin = xy.min(axis=0)
    ij = np.floor((xy - origin) / RASTER_M).astype(np.int64)
    shape = tuple(ij.max(axis=0) + 1)
    n_bins = int(round((BAND_HIGH_M - BAND_LOW_M) / BIN_M))
    zbin = np.minimum(((above_m[band] - BAND_LOW_M) / BIN_M).astype(np.int64), n_bins - 1)
    occupied = np.zeros(shape + (n_bins,), dtype=bool)
    occupied[ij[:, 0], ij[:, 1], zbin] = True
    stemlike = occupied.sum(axis=2) >= MIN_BINS
    stemlike = ndimage.binary_closing(stemlike, structure=np.ones((3, 3), dtype=bool))
    labels, _ = ndimage.label(stemlike, structure=np.ones((3, 3), dtype=bool))
    in_slab = (above_m[band] >= SLAB_LOW_M) & (above_m[band] <= SLAB_HIGH_M)
    point_label = labels[ij[:, 0], ij[:, 1]]
    stems = []
    for lab in np.unique(point_label[in_slab & (point_label > 0)]):
        pts = xy[in_slab & (point_label == lab)]
        if len(pts) < MIN_STEM_POINTS:
            continue
        cx, cy, r = kasa_circle(pts)
        stems.append({"x_m": cx, "y_m": cy, "dbh_m": 2.0 * r, "points": len(pts)})
    stems.sort(key=lambda s: (round(s["x_m"], 3), round(s["y_m"], 3)))
    centres = np.array([[s["x_m"], s["y_m"]] for s in stems]).reshape(-1, 2)
    for k, s in enumerate(stems):
        d = np.hypot(*(centres - centres[k]).T)
        d[k] = np.inf
        s["nearest_m"] = float(d.min()) if len(d) > 1 else float("inf")
    return stems


def main(argv: list[str] | None = None) -> int:
    """Command line entry: list stem candidates or cut one column."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("plot", type=Path, help="plot cloud (LAS/LAZ)")
    ap.add_argument("--list", action="store_true", help="print the stem candidates")
    ap.add_argument("--stem", type=int, help="index of the stem in the --list output")
    ap.add_argument("--radius-m", type=float, default=2.0, help="column radius (m)")
    ap.add_argument("-o", "--output", type=Path, help="output LAS/LAZ file")
    args = ap.parse_args(argv)
    try:
        las = laspy.read(args.plot)
    except (OSError, laspy.errors.LaspyException) as exc:
        print(f"error: cannot read {args.plot}: {exc}", file=sys.stderr)
        return 2
    xyz_m = np.c_[las.x, las.y, las.z].astype(np.float64)
    stems = find_stems(xyz_m)
    if args.list or args.stem is None:
        print("k  x_m        y_m        dbh_m  points  nearest_m")
        for k, s in enumerate(stems):
            print(
                f"{k:<2} {s['x_m']:<10.3f} {s['y_m']:<10.3f} {s['dbh_m']:<6.3f} "
                f"{s['points']:<7d} {s['nearest_m']:.2f}"
            )
        return 0
    if not 0 <= args.stem < len(stems):
        print(f"error: --stem must be in 0..{len(stems) - 1}", file=sys.stderr)
        return 2
    if args.output is None:
        print("error: -o/--output is required with --stem", file=sys.stderr)
        return 2
    s = stems[args.stem]
    keep = np.hypot(xyz_m[:, 0] - s["x_m"], xyz_m[:, 1] - s["y_m"]) <= args.radius_m
    out = laspy.LasData(las.header)
    out.points = las.points[keep].copy()
    out.update_header()
    out.write(args.output)
    print(
        f"stem {args.stem} at ({s['x_m']:.3f}, {s['y_m']:.3f}), radius {args.radius_m} m: "
        f"kept {int(keep.sum())} of {len(xyz_m)} points -> {args.output}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
