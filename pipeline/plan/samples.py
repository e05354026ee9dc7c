"""Each tree's surface samples: the targets the planner's rays aim at.

Per tree, two strata, both area-uniform and seeded (:func:`treesim.geometry.sample_surface`):

* **coverage samples** (``samples_per_tree``) on the whole tree (stem and crown, every
  part but the terrain); samples inside another closed part of the same tree (buried
  branch bases, end caps) are dropped, as :func:`treesim.compare.compare` drops them, so
  that coverage is of the surface a scanner could see;
* **band samples** (``band_samples``) on the stem between ``dbh_band_m`` above the stem
  base: the wood triangles that reach into the band within ``STEM_SEARCH_M`` of the stem
  base (of a mesh of separate tubes, only the stem's: the piece holding the lowest wood
  triangle), cut to the band. The stem axis and radius there are a circle fitted to the band
  samples (Kasa's least squares), started from their median and refitted on the samples
  within 30 % of its radius: a branch leaving in the band is left out. Each band sample gets the
  ``arc_bin_deg`` sector of its angle around the axis.

Samples are stored tree by tree, each tree's band samples first (sorted by sector), then
its coverage samples: every sector and every tree's coverage is a contiguous block, so
that the objective (:mod:`treesim.plan.cover`) sums them with one ``np.add.reduceat``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cloud import LABEL_CODES
from ..errors import EmptyInputError
from ..frame import LocalFrame
from ..geometry import inside_other_parts, mesh_parts, sample_surface
from ..scene import MeshPart

__all__ = ["STEM_SEARCH_M", "SampleSet", "TreeTarget", "sample_trees"]

#: Horizontal distance from the stem base within which band triangles belong to the stem.
STEM_SEARCH_M = 1.0


@dataclass(frozen=True)
class TreeTarget:
    """One tree as the planner sees it: its id, triangles and stem base.

    Parameters
    ----------
    tree_id : int
    parts : list of MeshPart
        The tree's parts placed in the plot (wood, leaf, ...).
    base_xyz : (3,) float
        The stem base (x, y of the tree's position, z of the terrain there).
    """

    tree_id: int
    parts: Sequence[MeshPart]
    base_xyz: tuple[float, float, float]

    def mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All parts as one mesh: vertices (v, 3), faces (f, 3), label code per face."""
        vs, fs, ls = [], [], []
        off = 0
        for p in self.parts:
            v = np.asarray(p.vertices, dtype=np.float64)
            f = np.asarray(p.faces, dtype=np.int64)
            vs.append(v)
            fs.append(f + off)
            ls.append(np.full(len(f), LABEL_CODES[p.label], dtype=np.uint8))
            off += len(v)
        if not vs:
            raise EmptyInputError(f"tree {self.tree_id} has no mesh parts")
        return np.concatenate(vs), np.concatenate(fs), np.concatenate(ls)


@dataclass
class SampleSet:
    """Every tree's samples, in blocks (see the module's notes).

    Attributes
    ----------
    points : (n, 3) float64
        Sample positions (plot coordinates, m).
    normals : (n, 3) float64
        Unit normals of the triangles they lie on.
    tree_ids : (t,) int64
    tree_of : (n,) int64
        Index into ``tree_ids`` of each sample.
    band : (n,) bool
        Band sample (DBH arc) or coverage sample.
    block_starts : (b,) int64
        First sample of every non-empty block, increasing; blocks tile ``0 .. n``.
    block_tree : (b,) int64
        Tree index of each block.
    block_sector : (b,) int64
        Sector of a band block (0 .. sectors - 1), -1 for a tree's coverage block.
    n_sectors : (t,) int64
        Sectors with band samples, per tree (0: no stem band found).
    stem_xy, stem_radius_m : (t, 2), (t,) float64
        Band axis and median band radius per tree (NaN without a band).
    hidden_dropped : (t,) int64
        Coverage samples dropped as inside another closed part of the tree.
    """

    points: np.ndarray
    normals: np.ndarray
    tree_ids: np.ndarray
    tree_of: np.ndarray
    band: np.ndarray
    block_starts: np.ndarray
    block_tree: np.ndarray
    block_sector: np.ndarray
    n_sectors: np.ndarray
    stem_xy: np.ndarray
    stem_radius_m: np.ndarray
    hidden_dropped: np.ndarray
    arc_bin_deg: float
    bounds: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        t = len(self.tree_ids)
        self.bounds = np.zeros((t, 2, 3))
        for i in range(t):
            p = self.points[self.tree_of == i]
            self.bounds[i] = (p.min(axis=0), p.max(axis=0)) if len(p) else np.nan

    def __len__(self) -> int:
        return len(self.points)

    def tree_slice(self, i: int) -> slice:
        """The samples of tree index ``i`` (contiguous)."""
        idx = np.flatnonzero(self.tree_of == i)
        return slice(int(idx[0]), int(idx[-1]) + 1) if len(idx) else slice(0, 0)

    def summary(self) -> dict[str, Any]:
        return {
            "trees": int(len(self.tree_ids)),
            "samples": int(len(self)),
            "band_samples": int(self.band.sum()),
            "coverage_samples": int((~self.band).sum()),
            "hidden_dropped": int(self.hidden_dropped.sum()),
            "trees_without_stem_band": [
                int(self.tree_ids[i]) for i in np.flatnonzero(self.n_sectors == 0)
            ],
        }


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]


def _circle(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares circle through points (Kasa): centre (2,), radius."""
    a = np.column_stack([xy, np.ones(len(xy))])
    b = -(xy**2).sum(axis=1)
    (d, e, f), *_ = np.linalg.lstsq(a, b, rcond=None)
    c = np.array([-d / 2, -e / 2])
    return c, float(np.sqrt(max(c @ c - f, 0.0)))


def _band(
    v: np.ndarray,
    f: np.ndarray,
    lab: np.ndarray,
    base: np.ndarray,
    band_m: tuple[float, float],
    n: int,
    seed: int,
    bin_deg: float,
    part_of_face: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Band samples (points, normals, sector), axis xy and median radius."""
    empty = (
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros(0, np.int64),
        np.full(2, np.nan),
        math.nan,
    )
    z0, z1 = base[2] + band_m[0], base[2] + band_m[1]
    tri = v[f]
    zmin, zmax = tri[:, :, 2].min(axis=1), tri[:, :, 2].max(axis=1)
    cxy = tri[:, :, :2].mean(axis=1)
    near = np.hypot(cxy[:, 0] - base[0], cxy[:, 1] - base[1]) <= STEM_SEARCH_M
    keep = (lab == LABEL_CODES["wood"]) & (zmax >= z0) & (zmin <= z1) & near
    if part_of_face is not None:
        # a mesh of separate tubes (procedural, QSM): the stem is the piece holding the
        # lowest wood triangle; its band alone, when it reaches the band
        wood = np.flatnonzero(lab == LABEL_CODES["wood"])
        if len(wood):
            stem = part_of_face[wood[np.argmin(zmin[wood])]]
            on_stem = keep & (part_of_face == stem)
            if on_stem.any():
                keep = on_stem
    if not keep.any():
        return empty
    fk = f[keep]
    # oversample: the triangles reach past the band (a tube's facets may span metres);
    # keep the samples inside it, drawing again as many as the first draw's share needs
    m = 4 * n
    for _ in range(2):
        pts, fi = sample_surface(v, fk, m, seed=seed + 7919)
        inb = (pts[:, 2] >= z0) & (pts[:, 2] <= z1)
        share = float(inb.mean())
        if inb.sum() >= n or share == 0:
            break
        m = int(min(200 * n, math.ceil(1.2 * n / share)))
    pts, fi = pts[inb], fi[inb]
    if len(pts) > n:  # samples come in face order: thin them evenly, not the first n
        keep_idx = np.linspace(0, len(pts) - 1, n).round().astype(np.int64)
        pts, fi = pts[keep_idx], fi[keep_idx]
    if len(pts) < 8:
        return empty
    # the stem's axis and radius: a circle fit (Kasa's algebraic fit), refitted on the
    # samples near the circle, so that a branch leaving in the band pulls neither
    # (started from the median of the samples: a branch is a minority of them)
    axis = np.median(pts[:, :2], axis=0)
    rad = float(np.median(np.hypot(pts[:, 0] - axis[0], pts[:, 1] - axis[1])))
    for _ in range(4):
        r = np.hypot(pts[:, 0] - axis[0], pts[:, 1] - axis[1])
        ok = np.abs(r - rad) <= max(0.3 * rad, 0.005)
        if ok.sum() < 8:
            return empty
        axis, rad = _circle(pts[ok, :2])
    r = np.hypot(pts[:, 0] - axis[0], pts[:, 1] - axis[1])
    ok = np.abs(r - rad) <= max(0.3 * rad, 0.005)
    pts, fi = pts[ok], fi[ok]
    r = r[ok]
    ang = np.degrees(np.arctan2(pts[:, 1] - axis[1], pts[:, 0] - axis[0])) % 360.0
    n_bins = int(round(360.0 / bin_deg))
    sector = np.minimum((ang / (360.0 / n_bins)).astype(np.int64), n_bins - 1)
    normals = _face_normals(v, fk[fi])
    return pts, normals, sector, axis, float(np.median(r))


def sample_trees(
    trees: Sequence[TreeTarget],
    *,
    samples_per_tree: int,
    band_samples: int,
    band_m: tuple[float, float] = (1.1, 1.5),
    arc_bin_deg: float = 10.0,
    seed: int = 0,
    hidden: bool = True,
    nthreads: int = 0,
    progress: Any = None,
) -> SampleSet:
    """Coverage and band samples of every tree (see the module's notes).

    Parameters
    ----------
    trees : sequence of TreeTarget
    samples_per_tree, band_samples : int
        Samples drawn per tree on the whole tree and on its stem band (before the
        hidden-surface and stem filters).
    band_m : (2,) float
        The DBH band, heights above the stem base (m).
    arc_bin_deg : float
        Sector width of the DBH arc (360 / width sectors, rounded).
    seed : int
        Sample seed (tree ``k`` uses ``seed + tree_id``).
    hidden : bool
        Drop coverage samples inside another closed part of the tree.
    """
    pts_all, nrm_all, band_all, tree_of = [], [], [], []
    starts, btree, bsector = [], [], []
    n_sectors = np.zeros(len(trees), np.int64)
    stem_xy = np.full((len(trees), 2), np.nan)
    stem_r = np.full(len(trees), np.nan)
    hidden_dropped = np.zeros(len(trees), np.int64)
    n = 0
    for i, t in enumerate(trees):
        if progress is not None:
            progress(i / max(1, len(trees)), f"sampling tree {i + 1}/{len(trees)}")
        v, f, lab = t.mesh()
        base = np.asarray(t.base_xyz, dtype=np.float64)
        s = int(seed) + int(t.tree_id)
        frame = LocalFrame.around(v)
        vl = frame.to_local(v)
        parts = mesh_parts(vl, f)
        bp, bn, bs, axis, r = _band(
            v, f, lab, base, band_m, band_samples, s, arc_bin_deg, parts.part_of_face
        )
        if len(bp):
            order = np.argsort(bs, kind="stable")
            bp, bn, bs = bp[order], bn[order], bs[order]
            stem_xy[i], stem_r[i] = axis, r
            uniq, first = np.unique(bs, return_index=True)
            n_sectors[i] = len(uniq)
            starts += list(n + first)
            btree += [i] * len(uniq)
            bsector += list(uniq)
            pts_all.append(bp)
            nrm_all.append(bn)
            band_all.append(np.ones(len(bp), bool))
            tree_of.append(np.full(len(bp), i))
            n += len(bp)
        cp, cf = sample_surface(v, f, samples_per_tree, seed=s)
        if hidden:
            inside = inside_other_parts(
                frame.to_local(cp), cf, vl, f, parts, seed=s, nthreads=nthreads
            )
            hidden_dropped[i] = int(inside.sum())
            cp, cf = cp[~inside], cf[~inside]
        if len(cp):
            starts.append(n)
            btree.append(i)
            bsector.append(-1)
            pts_all.append(cp)
            nrm_all.append(_face_normals(v, f[cf]))
            band_all.append(np.zeros(len(cp), bool))
            tree_of.append(np.full(len(cp), i))
            n += len(cp)
    if n == 0:
        raise EmptyInputError("no tree has any surface to sample")
    return SampleSet(
        points=np.concatenate(pts_all),
        normals=np.concatenate(nrm_all),
        tree_ids=np.array([t.tree_id for t in trees], np.int64),
        tree_of=np.concatenate(tree_of).astype(np.int64),
        band=np.concatenate(band_all),
        block_starts=np.array(starts, np.int64),
        block_tree=np.array(btree, np.int64),
        block_sector=np.array(bsector, np.int64),
        n_sectors=n_sectors,
        stem_xy=stem_xy,
        stem_radius_m=stem_r,
        hidden_dropped=hidden_dropped,
        arc_bin_deg=360.0 / round(360.0 / arc_bin_deg),
    )
