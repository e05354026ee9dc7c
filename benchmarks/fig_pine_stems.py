"""The real pine plot's stems, for a person to check: is every stem one can see in the twin?

Issue 23 asks for "a twin with every stem a person can see in the cloud". This script
draws what a person looks at, independently of the stem detector's own stages:

* the plot from above, every point 1.0-2.0 m above the ground (the DTM of
  :func:`treesim.plot.dtm.ground_and_dtm`), with the stems ``treesim plot from-cloud``
  found drawn as circles of their DBH;
* every group of those points (connected on a 10 cm grid, at least 20 points) farther
  than 0.3 m from every stem found, from the side: its points within 0.6 m up to 12 m
  above the ground, with the height its points reach in a continuous column above it (a
  stem reaches into the crown; a stump, a shrub or a branch tip does not, though
  branches crossing the column above one lengthen it: the side view decides).

It prints each unmatched group with that column height, and writes
``docs/img/twin/pine_stems_top.png`` and ``docs/img/twin/pine_stems_unmatched.png``.

Usage: ``python benchmarks/fig_pine_stems.py [--docs]`` (needs ``../shared/data/plots``; about
1 minute on 2 cores).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]
PINE = ROOT.parent / "shared" / "data" / "plots" / "treels_pine_plot" / "pine_plot.laz"
OUT = ROOT / "docs" / "img" / "twin"
#: The slice a person reads stems in (m above the ground).
SLICE_M = (1.0, 2.0)
#: Grid of the slice's groups (m) and the fewest points of a group.
CELL_M, MIN_POINTS = 0.1, 20
#: A group this close to a stem found is that stem (m).
MATCH_M = 0.3


def _groups(xy: np.ndarray) -> list[np.ndarray]:
    """Indices of the slice's points by group: connected cells of a CELL_M grid."""
    ij = np.floor((xy - xy.min(0)) / CELL_M).astype(int)
    grid = np.zeros(ij.max(0) + 1, dtype=bool)
    grid[ij[:, 0], ij[:, 1]] = True
    lab, _ = ndimage.label(grid, structure=np.ones((3, 3)))
    per_point = lab[ij[:, 0], ij[:, 1]]
    order = np.argsort(per_point, kind="stable")
    cuts = np.flatnonzero(np.diff(per_point[order])) + 1
    return [g for g in np.split(order, cuts) if len(g) >= MIN_POINTS]


def _column_top(pts: np.ndarray, h: np.ndarray, xy: np.ndarray, radius_m: float) -> float:
    """How high the points above ``xy`` (within ``radius_m``) reach without a gap of
    more than 1 m."""
    near = np.sort(h[np.hypot(*(pts[:, :2] - xy).T) < radius_m])
    near = near[near >= SLICE_M[0]]
    if len(near) == 0:
        return float("nan")
    gaps = np.flatnonzero(np.diff(near) > 1.0)
    return float(near[gaps[0]] if len(gaps) else near[-1])


def _slab_spread(pts: np.ndarray, h: np.ndarray, stems: list, dtm) -> None:
    """The independent slab reference (``tests/reconstruct/slab_reference.py``) of each
    stem at 1.1 ... 1.5 m: how much 10 cm slabs a few decimetres apart differ."""
    sys.path.insert(0, str(ROOT))
    from tests.reconstruct.slab_reference import fit_slab

    print("slab reference (10 cm slabs) at 1.1, 1.2, 1.3, 1.4, 1.5 m above the ground:")
    spreads = []
    for s in stems:
        z0 = float(dtm.height_at(np.array([s.x_m]), np.array([s.y_m]))[0])
        row = []
        for dz in (1.1, 1.2, 1.3, 1.4, 1.5):
            sl = fit_slab(pts, z_m=z0 + dz, height_m=dz, centre_xy=(s.x_m, s.y_m),
                          radius_m=s.dbh_m / 2)  # fmt: skip
            row.append(sl.diameter_m if sl.clean else None)
        clean = np.array([d for d in row if d is not None])
        spread = float(np.ptp(clean) / np.median(clean)) if len(clean) >= 2 else None
        if spread is not None:
            spreads.append(spread)
        cells = " ".join("  –  " if d is None else f"{d * 100:5.1f}" for d in row)
        print(
            f"  stem at ({s.x_m:.2f}, {s.y_m:.2f}), DBH {s.dbh_m * 100:.1f} cm: {cells} cm"
            + ("" if spread is None else f"; clean slabs span {spread * 100:.1f} % of their median")
        )
    if spreads:
        print(
            f"clean slabs of one stem span a median {np.median(spreads) * 100:.1f} %, at most "
            f"{max(spreads) * 100:.1f} % of their median ('–': not clean)"
        )


def main() -> int:
    import matplotlib

    matplotlib.use("Agg")  # a script of its own: no display
    import matplotlib.pyplot as plt

    import treesim as ts
    from treesim.plot.dtm import ground_and_dtm, heights_above_ground
    from treesim.plot.stems import detect_stems

    if not PINE.is_file():
        print(f"skipped: {PINE} not found (the project's shared data)")
        return 0
    pts = ts.read_cloud(PINE).points
    _, dtm, _ = ground_and_dtm(pts)
    h = heights_above_ground(pts, dtm)
    stems, _ = detect_stems(pts, h)
    sxy = np.array([[s.x_m, s.y_m] for s in stems])
    m = (h >= SLICE_M[0]) & (h <= SLICE_M[1])
    slice_pts = pts[m]
    unmatched = []
    for g in _groups(slice_pts[:, :2]):
        c = slice_pts[g, :2].mean(0)
        if len(sxy) and np.hypot(*(sxy - c).T).min() <= MATCH_M:
            continue
        width = float(np.ptp(slice_pts[g, :2], axis=0).max())
        unmatched.append((c, len(g), width, _column_top(pts, h, c, max(0.15, width / 2))))
    print(
        f"{PINE.name}: {len(stems)} stems found; {len(unmatched)} groups of points "
        f"{SLICE_M[0]}-{SLICE_M[1]} m above the ground farther than {MATCH_M} m from them:"
    )
    for c, n, w, top in unmatched:
        print(
            f"  at ({c[0]:.2f}, {c[1]:.2f}): {n} points, {w:.2f} m across; the points above "
            f"it reach {top:.1f} m with no gap over 1 m (crossing branches count too)"
        )
    _slab_spread(pts, h, stems, dtm)
    OUT.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.scatter(slice_pts[:, 0], slice_pts[:, 1], s=0.3, c="k")
    for s in stems:
        ax.add_patch(plt.Circle((s.x_m, s.y_m), s.dbh_m / 2, fill=False, color="r"))
    for c, *_ in unmatched:
        ax.add_patch(plt.Circle(tuple(c), 0.25, fill=False, color="b", ls="--"))
    ax.set_aspect("equal")
    ax.set_title(f"points {SLICE_M[0]}-{SLICE_M[1]} m above the ground; red: the {len(stems)} "
                 "stems found (DBH); blue: other groups", fontsize=9)  # fmt: skip
    fig.savefig(OUT / "pine_stems_top.png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    n = max(1, len(unmatched))
    fig, axs = plt.subplots(1, n, figsize=(2.2 * n, 5), squeeze=False)
    for ax, (c, _, _, top) in zip(axs[0], unmatched, strict=False):
        near = (np.hypot(*(pts[:, :2] - c).T) < 0.6) & (h < 12)
        ax.scatter(pts[near, 0] - c[0], h[near], s=0.4, c="k")
        ax.set_xlim(-0.6, 0.6)
        ax.set_title(f"({c[0]:.1f}, {c[1]:.1f})\ncolumn to {top:.1f} m", fontsize=8)
    axs[0][0].set_ylabel("height above the ground (m)")
    fig.savefig(OUT / "pine_stems_unmatched.png", dpi=70, bbox_inches="tight")
    plt.close(fig)
    rel = OUT.relative_to(ROOT)
    print(f"wrote {rel / 'pine_stems_top.png'} and {rel / 'pine_stems_unmatched.png'}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("fig-pine-stems"), "fig_pine_stems.py"):
        code = main()
    sys.exit(code)
