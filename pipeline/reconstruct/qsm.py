"""Cylinder-fitting quantitative structure model (QSM), deterministic.

Outline (every step is deterministic: no random cover sets, fixed RANSAC seeds):

1. **Graph.** A k-nearest-neighbour graph with edges up to ``link_m``; its connected
   components are joined by their shortest gaps (Borůvka steps over cross-component
   neighbour pairs, then nearest points), so occlusion gaps are bridged.
2. **Geodesic distance** from the base (the points within ``base_band_m`` of the lowest
   height near the stem's foot, :mod:`treesim.reconstruct.foot`; without a foot, of the
   lowest point) by Dijkstra, with predecessors.
3. **Slices** of the geodesic distance, ``slice_m`` thick; the graph restricted to each
   slice splits it into clusters: the skeleton's nodes. A node's parent is the node its
   points' shortest paths come from (a tree by construction: distance grows along paths).
4. **Branches**: from the base, each node continues its branch through the child with
   the longest subtree; other children start branches of the next order.
5. **Radii, measured where the data allow**: per node, points are projected on the plane
   normal to the local axis, a circle is fitted by RANSAC and refined by robust
   (soft-L1) least squares; the fit is accepted ("measured") only when its arc coverage,
   residual, inlier share and radius pass quality gates. Accepted fits also move the node
   to the circle's centre (a centroid is biased toward the scanned side). A wide stem
   node fits the slab of every point square to the stem's axis around it instead of its
   own slice (a geodesic slice of a stem scanned from one side holds half its ring).
6. **Regularised radii**: a per-tree pipe model ``r² = r_tip² + a · S`` of radius against
   growth length S (the length of the subtree a node supports, as rTwig does) is fitted
   to the measured nodes, the branches' ``a`` at most the stem's; unmeasured nodes take
   the model (``modelled``), or interpolate between measured neighbours on their branch
   (``interpolated``). A measured radius far from its branch's running median is an
   outlier (a whorl, a needle clump); a modelled radius never exceeds its branch's
   nearest measured one; the stem tapers linearly from its last measurement to its top.
   Along each branch the radius is a running median never wider than the data below it
   by more than the noise, a child never exceeds its parent at the junction, and nothing
   is thinner than the twig prior.
7. **Cylinders** (frusta) between consecutive nodes, children starting at their parent's
   surface, tips extended by half a slice, the stem extended down to the base.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from functools import cache
from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ..errors import ReconstructionError
from ..models import CylinderTable
from ..params import QSMParams
from .foot import StemFoot
from .neighbours import _index_dtype, _lengths, nearest_neighbors


@dataclass
class QSMResult:
    """A fitted QSM in local coordinates and what the fit found."""

    table: CylinderTable
    node_position: np.ndarray  # (m, 3)
    node_radius: np.ndarray  # (m,)
    node_measured: np.ndarray  # (m,) bool
    #: per node, the circle fit's radius, residual scatter, coverage (NaN: no fit)
    node_fit: dict[str, np.ndarray] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)


#: Measured branch nodes needed before the branches get their own pipe-model coefficient.
BRANCH_A_MIN_FITS = 10

# ---------------------------------------------------------------------------- graph
#: Points handled at a time when the graph is built (bounds temporary memory).
_CHUNK = 65536
#: Neighbours of each point searched for gap-bridging candidates.
BRIDGE_NEIGHBORS = 24


def _knn_graph(
    points: np.ndarray, neighbors: np.ndarray, k: int, link_m: float
) -> sparse.csr_matrix:
    """Symmetric graph joining each point to its ``k`` nearest others within ``link_m``,
    weighted by length (at least 1e-9).

    ``neighbors`` (n, >= k + 1) are each point's nearest points, itself first
    (:func:`~treesim.reconstruct.preprocess.nearest_neighbors`). The symmetric matrix
    is filled in place, a chunk of points at a time, in two passes (count, then fill):
    each edge a point keeps, and its mirror when the far end does not keep it too. The
    result equals ``A.maximum(A.T)`` of the one-sided graph ``A`` (both directions of an
    edge have the same length, bit for bit) without building ``A``, ``A.T`` and the
    merge: about a third of the memory.
    """
    n = len(points)
    k = min(k + 1, n)

    def chunks():  # (first row, far ends, lengths, kept, kept by the far end too)
        for lo in range(0, n, _CHUNK):
            j = neighbors[lo : lo + _CHUNK, 1:k]
            i = np.arange(lo, lo + len(j), dtype=j.dtype)[:, None]
            w = _lengths(points, i, j)
            keep = w <= link_m
            mutual = (neighbors[j, 1:k] == i[:, :, None]).any(axis=2)
            yield lo, j, w, keep, keep & ~mutual

    own = np.zeros(n, dtype=np.int64)
    mirrored = np.zeros(n, dtype=np.int64)
    for lo, j, _, keep, lone in chunks():
        own[lo : lo + len(j)] = keep.sum(axis=1)
        mirrored += np.bincount(j[lone], minlength=n)
    nnz = int(own.sum() + mirrored.sum())
    itype = _index_dtype(max(nnz, n))
    indptr = np.zeros(n + 1, dtype=itype)
    np.cumsum(own + mirrored, out=indptr[1:])
    indices = np.empty(nnz, dtype=itype)
    data = np.empty(nnz)
    cursor = indptr[:-1] + own  # next free slot of each row's mirrored part
    del own, mirrored
    for lo, j, w, keep, lone in chunks():
        rank = np.cumsum(keep, axis=1) - 1
        pos = (indptr[lo : lo + len(j), None] + rank)[keep]
        indices[pos] = j[keep]
        data[pos] = np.maximum(w[keep], 1e-9)
        far = j[lone]  # rows that receive a mirrored edge, grouped by row
        if len(far):
            near = np.broadcast_to(np.arange(lo, lo + len(j))[:, None], j.shape)[lone]
            order = np.argsort(far, kind="stable")
            far, near, wl = far[order], near[order], w[lone][order]
            head = np.flatnonzero(np.r_[True, far[1:] != far[:-1]])
            rank = np.arange(len(far)) - np.repeat(head, np.diff(np.r_[head, len(far)]))
            pos = cursor[far] + rank
            indices[pos] = near
            data[pos] = np.maximum(wl, 1e-9)
            cursor += np.bincount(far, minlength=n).astype(itype)
    g = sparse.csr_matrix((data, indices, indptr), shape=(n, n))
    g.sort_indices()
    return g


def _components(g: sparse.csr_matrix) -> tuple[int, np.ndarray]:
    """``connected_components(g, directed=False)`` of a symmetric ``g``, numbered the same
    way (by each component's lowest vertex), without SciPy's transposed copy of ``g``:
    the strong components of ``g`` as a directed graph are the same sets."""
    m, lab = connected_components(g, directed=True, connection="strong")
    first = np.unique(lab, return_index=True)[1]  # lowest vertex of each label
    rank = np.empty(m, dtype=lab.dtype)
    rank[np.argsort(first, kind="stable")] = np.arange(m, dtype=lab.dtype)
    return m, rank[lab]


def _roots(parent: np.ndarray) -> np.ndarray:
    """The union-find root of every element (pointer jumping, vectorised)."""
    root = parent.copy()
    while True:
        nxt = root[root]
        if np.array_equal(nxt, root):
            return root
        root = nxt


def _bridge(
    points: np.ndarray, g: sparse.csr_matrix, neighbors: np.ndarray, main_hint: int
) -> tuple[sparse.csr_matrix, int]:
    """Join every component to the rest by its shortest gaps; returns (graph, bridges).

    Candidate gaps are the pairs (point, one of its ``BRIDGE_NEIGHBORS`` nearest) that
    lie in different components; Borůvka rounds join each component by its shortest
    candidate; components left without one join the main component at their nearest
    point. Only the candidate pairs are kept (a few per stray point), never the whole
    neighbour table.
    """
    n = len(points)
    ncomp, labels = _components(g)
    if ncomp == 1:
        return g, 0
    k = min(BRIDGE_NEIGHBORS, n)
    ci_l, cj_l = [], []
    for lo in range(0, n, _CHUNK):
        j = neighbors[lo : lo + _CHUNK, :k]
        cross = labels[lo : lo + len(j), None] != labels[j]
        ci_l.append(np.broadcast_to(np.arange(lo, lo + len(j))[:, None], j.shape)[cross])
        cj_l.append(j[cross].astype(np.int64))
    ci, cj = np.concatenate(ci_l), np.concatenate(cj_l)  # in (point, rank) order
    cw = _lengths(points, ci, cj)
    lab_i, lab_j = labels[ci], labels[cj]
    extra_r, extra_c, extra_w = [], [], []
    parent = np.arange(ncomp)

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for _ in range(64):  # Borůvka rounds over the candidate pairs
        root = _roots(parent)
        li, lj = root[lab_i], root[lab_j]
        cross = np.flatnonzero(li != lj)
        if len(cross) == 0:
            break
        comp = li[cross]
        order = cross[np.lexsort((cw[cross], comp))]
        first = np.ones(len(order), dtype=bool)
        first[1:] = li[order][1:] != li[order][:-1]
        merged = False
        for e in order[first]:
            a, b = find(int(lab_i[e])), find(int(lab_j[e]))
            if a != b:
                parent[a] = b
                extra_r.append(ci[e])
                extra_c.append(cj[e])
                extra_w.append(cw[e])
                merged = True
        if not merged:
            break
    lab = _roots(parent)[labels]
    roots = np.unique(lab)
    if len(roots) > 1:  # components with no candidate pair: nearest point of the main one
        main = lab[main_hint]
        main_idx = np.flatnonzero(lab == main)
        other = np.flatnonzero(lab != main)
        dd, jj = cKDTree(points[main_idx]).query(points[other], k=1)
        # each component's point nearest to the main one (the first such point on a tie),
        # components in label order: one query and one sort, not a pass over every point
        # per component (quadratic on a noisy cloud of many stray clumps)
        order = np.lexsort((dd, lab[other]))
        comp = lab[other][order]
        first = np.ones(len(order), dtype=bool)
        first[1:] = comp[1:] != comp[:-1]
        pick = order[first]
        extra_r.extend(other[pick].tolist())
        extra_c.extend(main_idx[jj[pick]].tolist())
        extra_w.extend(dd[pick].tolist())
    b = sparse.coo_matrix(
        (np.maximum(np.asarray(extra_w), 1e-9), (np.asarray(extra_r), np.asarray(extra_c))),
        shape=g.shape,
    ).tocsr()
    b = b.maximum(b.T)
    return g.maximum(b).tocsr(), len(extra_w)


# ---------------------------------------------------------------------------- circles
def _circle_3pt(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circles through point triples p (t, 3, 2): centres (t, 2), radii (t,)."""
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    d = 2 * (
        a[:, 0] * (b[:, 1] - c[:, 1])
        + b[:, 0] * (c[:, 1] - a[:, 1])
        + c[:, 0] * (a[:, 1] - b[:, 1])
    )
    sa, sb, sc = (a**2).sum(1), (b**2).sum(1), (c**2).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (sa * (b[:, 1] - c[:, 1]) + sb * (c[:, 1] - a[:, 1]) + sc * (a[:, 1] - b[:, 1])) / d
        uy = (sa * (c[:, 0] - b[:, 0]) + sb * (a[:, 0] - c[:, 0]) + sc * (b[:, 0] - a[:, 0])) / d
    cen = np.stack([ux, uy], axis=1)
    return cen, np.linalg.norm(a - cen, axis=1)


@dataclass
class CircleFit:
    centre: np.ndarray  # (2,)
    radius: float
    rms: float
    coverage_deg: float
    inlier_share: float
    scatter: float  # robust scale (1.4826 MAD) of every point's residual, inliers or not


def fit_circle(
    q: np.ndarray, w: np.ndarray, rng: np.random.Generator, band_min: float
) -> CircleFit | None:
    """Robust circle fit to 2-D points ``q`` (m, 2) with weights ``w``."""
    m = len(q)
    if m < 6:
        return None
    t = 96
    tri = rng.integers(0, m, size=(t, 3))
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    if len(tri) == 0:
        return None
    cen, rad = _circle_3pt(q[tri])
    # robust size of the point set: median distance from the median point (about r for
    # points around a circle, whatever a few outliers do)
    ext = 2.0 * float(np.median(np.linalg.norm(q - np.median(q, axis=0), axis=1)))
    ok = np.isfinite(rad) & (rad > 0) & (rad < 2.0 * ext + band_min)
    if not ok.any():
        return None
    cen, rad = cen[ok], rad[ok]
    # one inlier band for every candidate (a band growing with the radius would favour
    # huge circles that pass through everything)
    band = max(band_min, 0.04 * ext)
    dist = np.abs(np.linalg.norm(q[None, :, :] - cen[:, None, :], axis=2) - rad[:, None])
    score = ((dist < band) * w[None, :]).sum(axis=1)
    best = int(np.argmax(score))
    inl = dist[best] < band
    if inl.sum() < 5:
        return None
    x = _refine_circle(q[inl], w[inl], np.array([cen[best, 0], cen[best, 1], rad[best]]), band)
    r = float(abs(x[2]))
    d_all = np.abs(np.linalg.norm(q - x[:2], axis=1) - r)
    inl = d_all < band
    if inl.sum() < 5:
        return None
    rms = float(np.sqrt(np.average(d_all[inl] ** 2, weights=w[inl])))
    res_all = np.linalg.norm(q - x[:2], axis=1) - r
    scatter = 1.4826 * float(np.median(np.abs(res_all - np.median(res_all))))
    ang = np.arctan2(q[inl, 1] - x[1], q[inl, 0] - x[0])
    sectors = np.unique(np.floor((ang + np.pi) / (2 * np.pi) * 36).astype(int) % 36)
    return CircleFit(
        centre=x[:2].copy(),
        radius=r,
        rms=rms,
        coverage_deg=10.0 * len(sectors),
        inlier_share=float(w[inl].sum() / w.sum()),
        scatter=scatter,
    )


def _refine_circle(q: np.ndarray, w: np.ndarray, x0: np.ndarray, f_scale: float) -> np.ndarray:
    """Geometric circle fit: iteratively reweighted Gauss-Newton with soft-L1 weights
    (the robust loss of ``scipy.optimize.least_squares(loss="soft_l1")``), analytic
    Jacobian; a few dozen numpy operations instead of a numerically differentiated
    solver."""
    x = x0.astype(np.float64).copy()
    for _ in range(20):
        dv = q - x[:2]
        d = np.linalg.norm(dv, axis=1)
        d = np.where(d > 1e-12, d, 1e-12)
        res = d - x[2]
        wt = w / np.sqrt(1.0 + (res / f_scale) ** 2)
        jac = np.column_stack([-dv[:, 0] / d, -dv[:, 1] / d, -np.ones(len(d))])
        jw = jac * wt[:, None]
        a = jac.T @ jw
        g = jw.T @ res
        try:
            step = np.linalg.solve(a + 1e-12 * np.eye(3), -g)
        except np.linalg.LinAlgError:
            break
        x += step
        if np.abs(step).max() < 1e-10 * max(1.0, abs(x[2])):
            break
    if not np.isfinite(x).all():
        return x0
    return x


#: The stem continues through the child reaching highest among those supporting at least
#: this share of the longest child subtree (a conifer's leader is shorter in subtree
#: length than a whorl branch near the top; the stem goes up, a branch goes out).
STEM_SUBTREE_SHARE = 0.3


def _continuation(kids: list[int], sub_len: np.ndarray, sub_top: np.ndarray, stem: bool) -> int:
    """The child a branch continues through: the one with the longest subtree; on the
    stem, the highest-reaching of the children with a substantial subtree."""
    longest = max(kids, key=lambda c: (sub_len[c], -c))
    if not stem:
        return longest
    big = [c for c in kids if sub_len[c] >= STEM_SUBTREE_SHARE * sub_len[longest]]
    return max(big, key=lambda c: (sub_top[c], sub_len[c], -c))


#: A stem node at least this many slice lengths wide (half its extent across the axis)
#: fits the slab of points square to the stem's axis around it (see ``_fit_nodes``, 5.); a
#: thinner stem's slice is a slab already (and a slab over a thin, curved stem widens
#: its circles: +12 % stem volume on the sapling).
STEM_SLAB_MIN_EXTENT_SLICES = 1.0
#: The slab takes every point (any node's: the far side of a stem can sit in a parallel
#: chain of nodes) within this many times the node's half-extent of its centroid across
#: the axis (a half-ring's centroid lies about 0.6 r off the stem's centre).
STEM_SLAB_REACH = 2.5
#: The slab is a slice thick, at least STEM_SLAB_M (m) ...
STEM_SLAB_M = 0.15
#: ... where the node's own slice holds fewer points than this and the stem is at least
#: as wide as STEM_SLAB_M: a sparse, one-sided stem has one row of points per slice.
STEM_SPARSE_POINTS = 60
#: Half-width (m) of the moving average that straightens the stem's unmeasured stretches.
STEM_SMOOTH_M = 0.5
#: A measured radius further than this share from the running median of its branch's
#: measured radii (or 3 noise σ, whichever is larger) is an outlier: a fit pulled by a
#: whorl's branch stubs, a needle clump, a neighbour's twig.
OUTLIER_REL = 0.2
#: Measured nodes on each side of a node in that running median.
OUTLIER_HALF_WINDOW = 3


#: The taper's floor (the narrowest data below a node) counts only nodes this far (m)
#: along the branch from its start: a stem's foot (cut, ragged, half in litter) and a
#: branch's junction give small circles that would clamp everything above them.
TAPER_FROM_M = 0.5


def _running_median(r: np.ndarray) -> np.ndarray:
    """The median of each value and its ``OUTLIER_HALF_WINDOW`` neighbours on each side
    (fewer at the ends)."""
    k = OUTLIER_HALF_WINDOW
    padded = np.concatenate([np.full(k, np.nan), r, np.full(k, np.nan)])
    return np.nanmedian(np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1), axis=1)


def _taper(r: np.ndarray, data: np.ndarray, tol: float) -> np.ndarray:
    """A branch's radii (base to tip) as a taper: a running median over
    ``2 * OUTLIER_HALF_WINDOW + 1`` nodes, then never wider than the narrowest of the
    nodes below it that rest on data (``data``: measured or interpolated) by more than
    ``tol`` (the noise). Unlike an isotonic fit, a swelling (under a fork, a whorl) is
    clipped instead of pooled into the measured radii below it."""
    if len(r) > 2 * OUTLIER_HALF_WINDOW:
        r = _running_median(r)
    floor = np.minimum.accumulate(np.where(data, r, np.inf))
    return np.minimum(r, floor + tol)


def _drop_outliers(radius: np.ndarray, measured: np.ndarray, noise_sd: float) -> int:
    """Unmark (in ``measured``) the measured radii of one branch's nodes (base to tip)
    that are outliers against the running median of the branch's measured radii; returns
    how many. Branches with fewer than five measured nodes are left alone."""
    idx = np.flatnonzero(measured)
    if len(idx) < 5:
        return 0
    r = radius[idx]
    med = _running_median(r)
    out = np.abs(r - med) > np.maximum(OUTLIER_REL * med, 3.0 * noise_sd)
    measured[idx[out]] = False
    return int(out.sum())


def _drop_wider_than_below(
    radius: np.ndarray, measured: np.ndarray, along: np.ndarray, tol: float
) -> int:
    """Unmark (in ``measured``) a stem's measured radii (base to tip; ``along``: distance
    along the stem) wider by more than ``tol`` than the narrowest running median of the
    measured radii below them (from ``TAPER_FROM_M`` up); returns how many. A stem does
    not widen upwards: such fits are partial arcs through whorls, fronds or a fork's
    pair, and as interpolation anchors they held a palm's stem at its base's radius 5 m
    up into its fronds."""
    idx = np.flatnonzero(measured)
    if len(idx) < 2:
        return 0
    med = _running_median(radius[idx])
    floor = np.minimum.accumulate(np.where(along[idx] >= TAPER_FROM_M, med, np.inf))
    below = np.concatenate([[np.inf], floor[:-1]])
    wide = radius[idx] > below + tol
    measured[idx[wide]] = False
    return int(wide.sum())


def _branch_radii(
    radius: np.ndarray,
    model: np.ndarray,
    measured: np.ndarray,
    pos: np.ndarray,
    *,
    stem: bool,
    noise_sd: float,
    tol_m: float,
    r_tip: float,
    tip_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One branch's radii, base to tip, from its nodes' fitted ``radius``, the radius
    ``model`` and which fits are ``measured`` (positions ``pos``, (k, 3)).

    Outlying fits are dropped (they take the model), on the stem also those wider than
    the stem below them (:func:`_drop_wider_than_below`); unmeasured nodes between measured
    ones interpolate them, those below the first take its radius, and those above the
    last never exceed its radius; on the stem (``stem``) the radius above the last
    measurement tapers linearly to ``r_tip`` at ``tip_m`` beyond the last node; then
    :func:`_taper` with ``tol_m``.

    Returns
    -------
    radius : (k,) float
    tag : (k,) int
        0 measured, 1 interpolated, 2 modelled.
    measured : (k,) bool
        ``measured`` less the outliers.
    outliers : int
    """
    measured = measured.copy()
    dropped = _drop_outliers(radius, measured, noise_sd)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    if stem:
        dropped += _drop_wider_than_below(radius, measured, along, tol_m)
    r = np.where(measured, radius, model)  # an outlier takes the model
    tag = np.where(measured, 0, 2)
    if measured.any():
        first, last = np.flatnonzero(measured)[[0, -1]]
        ii = np.arange(len(r))
        inner = (~measured) & (ii > first) & (ii < last)
        if inner.any():  # interpolate between measured anchors along the branch
            r[inner] = np.interp(along[inner], along[measured], radius[measured])
            tag[inner] = 1
        # below its first measurement a branch is as wide as there (no thinner at its
        # base, no wider than the data); above its last, never wider than there
        r[ii < first] = radius[first]
        after = ii > last
        r[after] = np.minimum(r[after], radius[last])
        if stem and after.any():  # the stem tapers from its last measurement to the top
            top = along[-1] + tip_m
            frac = (top - along[after]) / max(top - along[last], 1e-9)
            r[after] = np.minimum(r[after], r_tip + (radius[last] - r_tip) * frac)
    r = _taper(r, (tag < 2) & (along >= TAPER_FROM_M), tol_m)
    return r, tag, measured, dropped


def _basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ref = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = np.cross(a, ref)
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


#: Without a noise estimate, the smallest measured radius is this many point spacings
#: (the rule before noise was estimated).
NO_NOISE_MIN_RADIUS_SPACINGS = 1.5
#: Fewest well-measured fits a noise estimate is taken from.
NOISE_MIN_FITS = 3


def estimate_noise(
    scatter: np.ndarray,
    good_fit: np.ndarray,
    coverage_deg: np.ndarray,
    radius: np.ndarray,
    on_stem: np.ndarray,
    params: QSMParams,
    spacing_m: float,
) -> dict[str, Any]:
    """The noise of the points about the wood's surface, from the circle fits.

    Each fit's scatter is the robust scale (1.4826 × MAD) of its points' radial
    residuals. The estimate is their median over the *well-measured* fits: on the stem,
    arcs of at least ``min_coverage_deg`` passing every gate, radius at least two point
    spacings (a cross-section the scan samples densely, so the scatter is the points'
    noise, not the fit's). Failing three of those, every such fit of the tree; failing
    that, no estimate (``sd_m`` None).

    Returns
    -------
    dict
        ``sd_m`` (float or None), ``fits`` (how many it is the median of), ``from``
        (``"stem"``, ``"branches"`` or ``None``).
    """
    well = (
        good_fit
        & np.isfinite(scatter)
        & (coverage_deg >= params.min_coverage_deg)
        & (radius >= 2.0 * spacing_m)
    )
    for source, sel in (("stem", well & on_stem), ("branches", well)):
        if sel.sum() >= NOISE_MIN_FITS:
            return {"sd_m": float(np.median(scatter[sel])), "fits": int(sel.sum()), "from": source}
    return {"sd_m": None, "fits": 0, "from": None}


def _sources(p: np.ndarray, foot: StemFoot | None, band: float, link: float) -> np.ndarray:
    """The graph's sources: the points within ``band`` of the lowest height above the
    terrain among those near the foot's axis (a cloud cut from a plot has litter and
    fallen wood lower than the stem's foot); without a foot, the cloud's lowest points."""
    if foot is not None:
        near = foot.axis_distance(p) <= 1.5 * foot.radius_m + link + 0.05
        if near.sum() >= 3:
            hag = foot.height(p)
            return np.flatnonzero(near & (hag <= float(hag[near].min()) + band))
    return np.flatnonzero(p[:, 2] <= float(p[:, 2].min()) + band)


# ---------------------------------------------------------------------------- stages
#: Names of the radius tags (0 measured, 1 interpolated, 2 modelled).
_TAG_NAMES = np.array(["measured", "interpolated", "modelled"])


@dataclass
class _Graph:
    """Stages 1-2: the point graph and every point's geodesic distance from the base."""

    #: the bridged graph; :func:`_slice_clusters` takes it and leaves None, so that it is
    #: freed before the slices' components are found
    g: sparse.csr_matrix | None
    dist: np.ndarray  # (n,) geodesic distance from the base
    pred: np.ndarray  # (n,) each point's predecessor on its shortest path (< 0: none)
    n_bridges: int


@dataclass
class _Skeleton:
    """Stages 3-4: the skeleton's nodes (slice clusters), their tree and its branches."""

    cl: np.ndarray  # (n,) the node of each point
    node_parent: np.ndarray  # (m,) -1 at the main root
    centroid: np.ndarray  # (m, 3) weighted centroid of the node's points
    wsum: np.ndarray  # (m,) the node's points' weights
    main_root: int
    sub_len: np.ndarray  # (m,) the length of the subtree a node supports
    sub_top: np.ndarray  # (m,) the highest node a node's subtree reaches
    children: list[list[int]]
    keep: np.ndarray  # (m,) False for a pruned spur
    members_sorted: np.ndarray  # the points sorted by node; node v's are
    bounds: np.ndarray  # members_sorted[bounds[v] : bounds[v + 1]]
    # stage 4: the branches (node sequences, base to tip, in DFS order, the stem first)
    branches: list[list[int]] = field(default_factory=list)
    branch_of: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    branch_order: list[int] = field(default_factory=list)
    branch_parent_node: list[int] = field(default_factory=list)

    def members(self, v: int) -> np.ndarray:
        """The indices of node ``v``'s points."""
        return self.members_sorted[self.bounds[v] : self.bounds[v + 1]]


@dataclass
class _Fits:
    """Stage 5: the nodes' circle fits and positions."""

    pos: np.ndarray  # (m, 3) the node's position: its centroid, or its circle's centre
    radius: np.ndarray  # (m,) the fit's radius (NaN: no fit)
    quality: np.ndarray  # (m,) coverage share x inlier share of an accepted fit, else 0
    good_fit: np.ndarray  # (m,) passes every gate but the radius floor
    fit_centre: np.ndarray  # (m, 3)
    scatter: np.ndarray  # (m,)
    coverage: np.ndarray  # (m,) degrees
    axes: np.ndarray  # (m, 3) the local axis
    extent: np.ndarray  # (m,) half the data's extent across the axis (inf: not measured)
    measured: np.ndarray | None = None  # (m,) stage 5b: good fits above the radius floor


def _geodesic(
    p: np.ndarray,
    params: QSMParams,
    link: float,
    band: float,
    neighbors: np.ndarray | None,
    foot: StemFoot | None,
) -> _Graph:
    """Stages 1-2: the graph, its components bridged, and the geodesic distance from the
    base."""
    n = len(p)
    k_needed = min(max(params.neighbors + 1, BRIDGE_NEIGHBORS), n)
    if neighbors is None or len(neighbors) != n or neighbors.shape[1] < k_needed:
        neighbors, _ = nearest_neighbors(p, k_needed)
    g = _knn_graph(p, neighbors, params.neighbors, link)
    sources = _sources(p, foot, band, link)
    g, n_bridges = _bridge(p, g, neighbors, int(sources[0]))
    del neighbors
    # g is symmetric: as a directed graph it gives the same distances and predecessors
    # as directed=False, without SciPy's transposed copy of the graph
    dist, pred, _ = dijkstra(
        g, directed=True, indices=sources, min_only=True, return_predecessors=True
    )
    if not np.isfinite(dist).all():
        raise ReconstructionError("the point graph is not connected after gap bridging")
    return _Graph(g=g, dist=dist, pred=pred, n_bridges=n_bridges)


def _slice_clusters(graph: _Graph, h: float) -> tuple[int, np.ndarray]:
    """Stage 3a: slices of the geodesic distance ``h`` thick, split by the graph
    restricted to each slice into clusters (the nodes); returns (m, node of each point).
    Takes ``graph.g`` (left None)."""
    g, graph.g = graph.g, None
    n = g.shape[0]
    sl = np.floor(graph.dist / h).astype(np.int64)
    # the graph's edges within a slice, a chunk of rows at a time (whole-graph row and
    # slice arrays were 1.2 GB of temporaries at 3.9 M points)
    same = np.empty(g.nnz, dtype=bool)
    per_row = np.empty(n, dtype=g.indptr.dtype)
    for lo in range(0, n, _CHUNK):
        hi = min(lo + _CHUNK, n)
        a, b = g.indptr[lo], g.indptr[hi]
        count = np.diff(g.indptr[lo : hi + 1])
        keep = np.repeat(sl[lo:hi], count) == sl[g.indices[a:b]]
        same[a:b] = keep
        per_row[lo:hi] = np.bincount(
            np.repeat(np.arange(hi - lo), count), weights=keep, minlength=hi - lo
        )
    indptr = np.zeros(n + 1, dtype=g.indptr.dtype)
    np.cumsum(per_row, out=indptr[1:])
    data, indices = g.data[same], g.indices[same]
    del g, same, per_row
    gs = sparse.csr_matrix((data, indices, indptr), shape=(n, n))
    return _components(gs)  # gs is symmetric too


def _node_tree(p: np.ndarray, w: np.ndarray, graph: _Graph, m: int, cl: np.ndarray) -> _Skeleton:
    """Stage 3b: the nodes' tree (a node's parent is the node its points' shortest paths
    come from), their centroids and subtree lengths; spurs pruned."""
    dist, pred = graph.dist, graph.pred
    # parent cluster by predecessor votes
    has_pred = pred >= 0
    ci, cp = cl[has_pred], cl[pred[has_pred]]
    cross = ci != cp
    votes = sparse.coo_matrix((w[has_pred][cross], (ci[cross], cp[cross])), shape=(m, m)).tocsr()
    node_parent = np.full(m, -1, dtype=np.int64)
    nz = np.diff(votes.indptr) > 0
    node_parent[nz] = np.asarray(votes[nz].argmax(axis=1)).ravel()
    wsum = np.bincount(cl, weights=w, minlength=m)
    centroid = np.stack([np.bincount(cl, weights=w * p[:, j], minlength=m) for j in range(3)], 1)
    centroid /= wsum[:, None]
    npts = np.bincount(cl, minlength=m)
    roots = np.flatnonzero(node_parent < 0)
    main_root = int(roots[np.argmax(wsum[roots])])
    for r in roots:  # extra bases (e.g. buttresses, stray low points) hang off the main one
        if r != main_root:
            node_parent[r] = main_root

    # children, subtree length (process nodes by decreasing geodesic distance)
    node_dist = np.bincount(cl, weights=w * dist, minlength=m) / wsum
    order = np.argsort(-node_dist, kind="stable")
    edge_len = np.zeros(m)
    has_par = node_parent >= 0
    edge_len[has_par] = np.linalg.norm(centroid[has_par] - centroid[node_parent[has_par]], axis=1)
    sub_len = edge_len.copy()
    sub_top = centroid[:, 2].copy()  # the highest node a node's subtree reaches
    for v in order:
        pv = node_parent[v]
        if pv >= 0:
            sub_len[pv] += sub_len[v]
            sub_top[pv] = max(sub_top[pv], sub_top[v])
    children: list[list[int]] = [[] for _ in range(m)]
    for v in np.argsort(node_dist, kind="stable"):
        pv = node_parent[v]
        if pv >= 0:
            children[pv].append(int(v))

    # prune spurs: leaf nodes with very few points hanging off a node that continues
    keep = np.ones(m, dtype=bool)
    for v in range(m):
        if not children[v] and node_parent[v] >= 0 and npts[v] < 4:
            if len(children[node_parent[v]]) > 1:
                keep[v] = False
    for v in range(m):
        children[v] = [c for c in children[v] if keep[c]]
    return _Skeleton(
        cl=cl,
        node_parent=node_parent,
        centroid=centroid,
        wsum=wsum,
        main_root=main_root,
        sub_len=sub_len,
        sub_top=sub_top,
        children=children,
        keep=keep,
        members_sorted=np.argsort(cl, kind="stable"),
        bounds=np.concatenate([[0], np.cumsum(np.bincount(cl, minlength=m))]),
    )


def _trace_branches(sk: _Skeleton) -> None:
    """Stage 4: the branches (filled into ``sk``). A node continues its branch through
    the child with the longest subtree (alternatives tried on the procedural presets:
    weighting by straightness or by the child's cross-section picked fork limbs or whorl
    branches as the stem); its other children start branches of the next order."""
    sk.branch_of = np.full(len(sk.centroid), -1, dtype=np.int64)
    stack = [(sk.main_root, 0, -1)]
    while stack:
        start, order_k, junction = stack.pop()
        b = len(sk.branches)
        seq = []
        v = start
        while True:
            seq.append(v)
            sk.branch_of[v] = b
            kids = sk.children[v]
            if not kids:
                break
            main = _continuation(kids, sk.sub_len, sk.sub_top, stem=order_k == 0)
            for c in sorted(kids, reverse=True):
                if c != main:
                    stack.append((c, order_k + 1, v))
            v = main
        sk.branches.append(seq)
        sk.branch_order.append(order_k)
        sk.branch_parent_node.append(junction)


def _node_axis(sk: _Skeleton, seq: list[int], i: int) -> np.ndarray:
    """The unit axis at node ``seq[i]`` of a branch: from the node before it (its
    parent, at the branch's start) to the node after it, or the one-sided direction at
    an end; vertical for a lone node."""
    centroid, v = sk.centroid, seq[i]
    prev_pt = (
        centroid[seq[i - 1]]
        if i > 0
        else (centroid[sk.node_parent[v]] if sk.node_parent[v] >= 0 else None)
    )
    next_pt = centroid[seq[i + 1]] if i + 1 < len(seq) else None
    if prev_pt is not None and next_pt is not None:
        a = next_pt - prev_pt
    elif next_pt is not None:
        a = next_pt - centroid[v]
    elif prev_pt is not None:
        a = centroid[v] - prev_pt
    else:
        a = np.array([0.0, 0.0, 1.0])
    na = np.linalg.norm(a)
    return a / na if na > 0 else np.array([0.0, 0.0, 1.0])


def _stem_slab(
    p: np.ndarray,
    sk: _Skeleton,
    seq: list[int],
    i: int,
    a: np.ndarray,
    extent: float,
    h: float,
    tree_all: Callable[[], cKDTree],
    own: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A wide stem node's points for its circle fit: the slab of every point square to
    the stem's axis around it (see :func:`_fit_nodes`); ``a`` is the node's own axis.

    Returns (indices, plane coordinates, u, v): the slab's, in the plane square to the
    axis over the slab's reach, or ``own`` (the node's own points, their plane coordinates
    and basis) unchanged where the slab holds fewer than six points: a fit's centre is
    mapped back with the basis its coordinates were taken in.
    """
    v = seq[i]
    centroid = sk.centroid
    sparse_node = len(own[0]) < STEM_SPARSE_POINTS and extent >= STEM_SLAB_M
    half_t = 0.5 * (max(h, STEM_SLAB_M) if sparse_node else h)
    reach = int(np.ceil((half_t + 2.0 * extent) / h))
    # the axis over the slab's reach: tilted slices make consecutive
    # centroids zig-zag, and a slab square to a tilted axis is an ellipse
    a_long = centroid[seq[min(len(seq) - 1, i + reach)]] - centroid[seq[max(0, i - reach)]]
    if np.linalg.norm(a_long) > 0:
        a = a_long / np.linalg.norm(a_long)
    r_near = STEM_SLAB_REACH * extent
    cand = np.asarray(tree_all().query_ball_point(centroid[v], r_near + half_t), dtype=np.int64)
    rel_c = p[cand] - centroid[v]
    on_axis = rel_c @ a
    slab = (np.abs(on_axis) <= half_t) & (np.sum(rel_c**2, axis=1) - on_axis**2 <= r_near**2)
    if slab.sum() < 6:
        return own
    u, vv = _basis(a)
    rel = rel_c[slab]
    return cand[slab], np.stack([rel @ u, rel @ vv], axis=1), u, vv


def _accepted(
    fit: CircleFit, q: np.ndarray, params: QSMParams, spacing_m: float, band_min: float
) -> bool:
    """Whether a circle fit passes the quality gates (all but the radius floor): a full
    arc with a small residual or a partial arc with a smaller one, most points inliers,
    and a radius the data's extent across the axis allows."""
    full = (
        fit.coverage_deg >= params.min_coverage_deg
        and fit.rms <= params.max_rel_residual * fit.radius + 0.5 * spacing_m
    )
    partial = (
        fit.coverage_deg >= params.partial_coverage_deg
        and fit.rms <= params.partial_rel_residual * fit.radius + 0.25 * spacing_m
    )
    return bool(
        (full or partial)
        and fit.inlier_share >= 0.6
        and fit.radius <= 0.6 * float(np.ptp(q, axis=0).max()) + band_min
    )


#: A stem fragment's slab fit stands for the stem only when it is no wider than this
#: share of the stem's last full ring below (a slab in a fork or among fronds is wider).
FRAGMENT_MAX_WIDENING = 1.1


def _fragment_fit(
    own_fit: CircleFit | None,
    slab: tuple,
    r_below: float,
    w: np.ndarray,
    rng: np.random.Generator,
    params: QSMParams,
    band_min: float,
) -> tuple[CircleFit | None, tuple]:
    """A fragment of a wide stem: its own fit, or the slab's where that is better.

    Inside a crown the stem's slices break into fragments (the paths to its far side come
    through the branches; the real pine from 12 m up: nodes of 2-40 points on 60-140
    degrees, read 5-6 cm on a stem of 7.2 cm). Where the node's own points give no full
    arc, the slab of every point square to the axis around it, reaching as far as the
    stem's last full ring below (``r_below``), is fitted; its circle replaces the own fit
    when it is a full arc no wider than :data:`FRAGMENT_MAX_WIDENING` times ``r_below``.
    ``slab`` is :func:`_stem_slab`'s arguments but the extent, with the node's own
    (indices, plane coordinates, u, v) last; returns (fit, the points it was fitted on).
    """
    p, sk, seq, i, a, h, tree_all, own = slab
    if own_fit is not None and own_fit.coverage_deg >= params.min_coverage_deg:
        return own_fit, own
    got = _stem_slab(p, sk, seq, i, a, r_below, h, tree_all, own)
    if got[0] is own[0]:
        return own_fit, own
    fit = fit_circle(got[1], w[got[0]], rng, band_min)
    if (
        fit is not None
        and fit.coverage_deg >= params.min_coverage_deg
        and fit.radius <= FRAGMENT_MAX_WIDENING * r_below
    ):
        return fit, got
    return own_fit, own


def _fit_nodes(
    p: np.ndarray, w: np.ndarray, sk: _Skeleton, params: QSMParams, spacing_m: float, h: float
) -> _Fits:
    """Stage 5: a circle fit per node, in the plane normal to its local axis."""
    m = len(sk.centroid)
    f = _Fits(
        pos=sk.centroid.copy(),
        radius=np.full(m, np.nan),
        quality=np.zeros(m),
        good_fit=np.zeros(m, dtype=bool),
        fit_centre=np.zeros((m, 3)),
        scatter=np.full(m, np.nan),
        coverage=np.full(m, np.nan),
        axes=np.zeros((m, 3)),
        extent=np.full(m, np.inf),
    )
    rng_base = params.seed * 1_000_003
    band_min = max(1.0 * spacing_m, 0.001)
    # a wide stem node's fit takes the slab of points square to the stem's axis around it:
    # the geodesic slices are level sets of the path length from the base, which on a stem
    # scanned from one side tilt and wind (the far side's paths run round the stem), so one
    # slice, and the chain of nodes it belongs to, held half the ring and a parallel chain
    # the other half (the real pine: 180-240 degrees per node against 240-350 in a
    # horizontal slab), and half-ring circles read its DBH +4 %
    tree_all = cache(lambda: cKDTree(p))  # every point, built for the first wide stem node
    wide = STEM_SLAB_MIN_EXTENT_SLICES * h
    for bi, seq in enumerate(sk.branches):
        r_below = 0.0  # the stem's last full-ring radius below (0 until one is fitted)
        for i, v in enumerate(seq):
            a = _node_axis(sk, seq, i)
            f.axes[v] = a
            if not sk.keep[v]:
                continue
            idx = sk.members(v)
            fragment = bi == 0 and r_below >= wide  # see _fragment_fit
            if len(idx) < (1 if fragment else 6):
                continue
            u, vv = _basis(a)
            rel = p[idx] - sk.centroid[v]
            q = np.stack([rel @ u, rel @ vv], axis=1)
            extent = 0.5 * float(np.ptp(q, axis=0).max())
            if len(idx) >= 6:  # a few points of a fragment say nothing of the data's width
                f.extent[v] = extent
            if bi == 0 and extent >= wide:
                idx, q, u, vv = _stem_slab(p, sk, seq, i, a, extent, h, tree_all, (idx, q, u, vv))
            rng = np.random.default_rng(rng_base + v)
            fit = fit_circle(q, w[idx], rng, band_min) if len(idx) >= 6 else None
            if fragment and extent < wide:
                slab = (p, sk, seq, i, a, h, tree_all, (idx, q, u, vv))
                fit, (idx, q, u, vv) = _fragment_fit(fit, slab, r_below, w, rng, params, band_min)
            if fit is None:
                continue
            f.radius[v] = fit.radius
            f.scatter[v], f.coverage[v] = fit.scatter, fit.coverage_deg
            if _accepted(fit, q, params, spacing_m, band_min):
                f.good_fit[v] = True
                f.quality[v] = (fit.coverage_deg / 360.0) * fit.inlier_share
                f.fit_centre[v] = sk.centroid[v] + fit.centre[0] * u + fit.centre[1] * vv
                if bi == 0 and fit.coverage_deg >= params.min_coverage_deg:
                    r_below = fit.radius
    return f


def _noise_floor(
    f: _Fits, sk: _Skeleton, params: QSMParams, res: dict[str, Any], spacing_m: float
) -> tuple[dict[str, Any], float, str]:
    """Stage 5b: the noise of the points about the surface, from the stem's well-measured
    fits, and the smallest radius the noise lets a circle fit resolve (k sigma); sets
    ``f.measured`` (good fits at least that wide), which move their nodes to the circles'
    centres. Returns (noise, min radius, its rule)."""
    noise = estimate_noise(
        f.scatter, f.good_fit, f.coverage, f.radius, sk.branch_of == 0, params, spacing_m
    )
    if params.min_radius_m is not None:
        r_min, r_min_rule = params.min_radius_m, "given"
    elif noise["sd_m"] is not None:
        r_min = max(params.resolve_sigmas * noise["sd_m"], res["min_radius_floor_m"])
        r_min_rule = f"max({params.resolve_sigmas:g} × noise σ, floor)"
    else:
        r_min = NO_NOISE_MIN_RADIUS_SPACINGS * spacing_m
        r_min_rule = f"{NO_NOISE_MIN_RADIUS_SPACINGS:g} × spacing (no σ)"
    f.measured = f.good_fit & (f.radius >= r_min)
    f.quality[~f.measured] = 0.0
    f.pos[f.measured] = f.fit_centre[f.measured]
    return noise, r_min, r_min_rule


def _weighted_a(
    radius: np.ndarray,
    quality: np.ndarray,
    grow: np.ndarray,
    r_tip: float,
    e: float,
    sel: np.ndarray,
) -> float:
    """The quality-weighted median over the nodes ``sel`` of the pipe model's
    coefficient ``a = (r^e - r_tip^e) / S`` (``e = 1 / b``, S the growth length)."""
    ratio = (radius[sel] ** e - r_tip**e) / grow[sel]
    o = np.argsort(ratio)
    cw = np.cumsum(quality[sel][o])
    return float(ratio[o][np.searchsorted(cw, 0.5 * cw[-1])])


def _radius_model(
    p: np.ndarray, sk: _Skeleton, f: _Fits, params: QSMParams, h: float, spacing_m: float
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Stage 6, the model: the per-tree pipe model's radius at every node; returns (model radius,
    growth length, the model's diagnostics)."""
    # 6. radius model (S: growth length, the length of the subtree a node supports):
    # r^(1/b) = r_tip^(1/b) + a * S; b = 0.5 is the pipe model, "cross-section area = tip
    # area + area proportional to the length supported". a comes from the measured nodes
    # (weighted median); without measurements, from the spread of the base's points.
    # The stem and the branches get their own a: a stem grows girth that supports no
    # length (below the crown, and its heartwood), so the stem's a is 2-4x the branches'
    # (4.3x in the balsam-fir preset's own table; Shinozaki et al. 1964 for the pipe model
    # inside the crown), and the stem's a on a conifer's branches gave them 2.5x their
    # volume. The branches' a is the smaller of the stem's and their own measured nodes'
    # (at least BRANCH_A_MIN_FITS of them): those are biased up (only radii above the
    # noise floor are measured, and bark bumps on a stem read as short thick branches: the
    # real pine's gave 6x its branch volume), so they may only lower it.
    r_tip = params.twig_radius_m
    b_fit = params.pipe_exponent
    grow = sk.sub_len + 0.5 * h
    e = 1.0 / b_fit
    mm = f.measured & sk.keep & (f.radius > r_tip * 1.05)
    on_stem = sk.branch_of == 0

    def weighted_a(sel: np.ndarray) -> float:
        return _weighted_a(f.radius, f.quality, grow, r_tip, e, sel)

    if mm.sum() >= 3:
        a_stem = weighted_a(mm & on_stem) if (mm & on_stem).sum() >= 3 else weighted_a(mm)
        a_source = "measured nodes"
        a_branch, a_branch_source = a_stem, "the stem's (too few measured branch nodes)"
        if (mm & ~on_stem).sum() >= BRANCH_A_MIN_FITS:
            a_own = weighted_a(mm & ~on_stem)
            a_branch_source = "the stem's (lower than the measured branch nodes')"
            if a_own < a_stem:
                a_branch, a_branch_source = a_own, "measured branch nodes"
    else:
        idx = sk.members(sk.main_root)
        spread = float(np.sqrt(np.mean(np.sum((p[idx, :2] - p[idx, :2].mean(0)) ** 2, 1))))
        a_stem = a_branch = max(spread**e - r_tip**e, 0.0) / grow[sk.main_root]
        a_source = a_branch_source = "base spread (no measured nodes)"
    model = (r_tip**e + np.where(on_stem, a_stem, a_branch) * grow) ** b_fit
    # never wider than the data around the node
    model = np.minimum(model, np.where(np.isfinite(f.extent), f.extent + 0.25 * spacing_m, model))
    info = {
        "r_tip_m": r_tip,
        "b": b_fit,
        "a_stem": a_stem,
        "a_stem_from": a_source,
        "a_branch": a_branch,
        "a_branch_from": a_branch_source,
    }
    return model, grow, info


def _final_radii(
    sk: _Skeleton,
    f: _Fits,
    model: np.ndarray,
    noise_sd: float,
    params: QSMParams,
    spacing_m: float,
    h: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Stage 6, per branch: each branch's radii (measured, interpolated or modelled, outliers
    dropped from ``f.measured``, tapered), never wider than the parent at the junction
    nor thinner than the twig prior. Returns (radius, tag, outliers)."""
    r_tip = params.twig_radius_m
    measured = f.measured
    final_r = np.where(measured, f.radius, model)
    tag = np.where(measured, 0, 2)  # 0 measured, 1 interpolated, 2 modelled
    n_outliers = 0
    for b, seq in enumerate(sk.branches):
        s = np.asarray(seq)
        final_r[s], tag[s], measured[s], dropped = _branch_radii(
            f.radius[s],
            model[s],
            measured[s],
            f.pos[s],
            stem=b == 0,
            noise_sd=noise_sd,
            tol_m=2.0 * noise_sd + 0.25 * spacing_m,
            r_tip=r_tip,
            tip_m=0.5 * h,
        )
        n_outliers += dropped
    # parent >= child at junctions, twig prior; parents first (branches are in DFS order)
    for b, seq in enumerate(sk.branches):
        j = sk.branch_parent_node[b]
        s = np.asarray(seq)
        if j >= 0:
            final_r[s] = np.minimum(final_r[s], final_r[j])
        final_r[s] = np.maximum(final_r[s], r_tip)
    return final_r, tag, n_outliers


def _smooth_axes(
    pos: np.ndarray, branches: list[list[int]], measured: np.ndarray, h: float
) -> None:
    """Stage 6b: smooth each branch's axis (``pos``, in place)."""
    # fitted centres jitter by a few mm to cm (partial arcs, furcations, centroid
    # fall-backs) and a zig-zag axis is longer than the branch, which inflates length and
    # volume (+14 % stem length measured on a 30 m preset).
    # A (1, 2, 3, 2, 1) moving average along the branch, ends kept, removes the jitter.
    # The stem's unmeasured stretches (hidden in the crown, among needles or leaves) follow
    # slice clusters of foliage that wander metres sideways; a stem goes up: there the
    # axis is a moving average over ±STEM_SMOOTH_M.
    stem = np.asarray(branches[0])
    half = max(2, int(round(STEM_SMOOTH_M / h)))
    if len(stem) > 2 * half:
        csum = np.vstack([np.zeros(3), np.cumsum(pos[stem], axis=0)])
        ii = np.arange(len(stem))
        lo, hi = np.clip(ii - half, 0, None), np.clip(ii + half + 1, None, len(stem))
        wide = (csum[hi] - csum[lo]) / (hi - lo)[:, None]
        hidden = ~measured[stem]
        hidden[0] = hidden[-1] = False
        pos[stem[hidden]] = wide[hidden]
    kernel = np.array([1.0, 2.0, 3.0, 2.0, 1.0])
    for seq in branches:
        if len(seq) < 5:
            continue
        s_idx = np.asarray(seq)
        xyz = pos[s_idx]
        padded = np.concatenate([np.repeat(xyz[:1], 2, 0), xyz, np.repeat(xyz[-1:], 2, 0)])
        sm = np.stack(
            [np.convolve(padded[:, j], kernel / kernel.sum(), mode="valid") for j in range(3)],
            axis=1,
        )
        sm[0], sm[-1] = xyz[0], xyz[-1]
        pos[s_idx] = sm


def _branch_polyline(
    seq: list[int],
    j: int,
    pos: np.ndarray,
    final_r: np.ndarray,
    tag: np.ndarray,
    axes: np.ndarray,
    foot: StemFoot | None,
    zmin: float,
    h: float,
) -> tuple[list[np.ndarray], list[float], list[int]]:
    """A branch's cylinder ends (points, radii, tags), its nodes ``seq`` extended: the stem
    (``j < 0``) down to the ground, a branch back to its parent node ``j``'s surface, and
    the tip by half a slice."""
    pts = [pos[v] for v in seq]
    rads = [final_r[v] for v in seq]
    tg = [tag[v] for v in seq]
    if j < 0:  # stem: extend from the ground up to the first node
        a = axes[seq[0]]
        h0 = (
            float(foot.height(pos[seq[0]][None, :])[0])
            if foot is not None
            else float(pos[seq[0]][2] - zmin)
        )
        base = pos[seq[0]] - a * max(h0 / max(a[2], 0.2), 0.0)
        pts = [base, *pts]
        rads = [rads[0], *rads]
        tg = [tg[0], *tg]
    else:  # start at the parent's surface
        d0 = pts[0] - pos[j]
        L0 = float(np.linalg.norm(d0))
        if L0 > 0:
            off = min(final_r[j], 0.5 * L0)
            pts = [pos[j] + d0 / L0 * off, *pts]
        else:
            pts = [pos[j], *pts]
        rads = [rads[0], *rads]
        tg = [tg[0], *tg]
    if len(pts) >= 2:  # tip: half a slice beyond the last node
        d1 = pts[-1] - pts[-2]
        L1 = float(np.linalg.norm(d1))
        if L1 > 0:
            pts[-1] = pts[-1] + d1 / L1 * 0.5 * h
    return pts, rads, tg


def _cylinders(
    sk: _Skeleton,
    f: _Fits,
    final_r: np.ndarray,
    tag: np.ndarray,
    foot: StemFoot | None,
    zmin: float,
    h: float,
) -> tuple[CylinderTable, list[str]]:
    """Stage 7: cylinders (frusta) between consecutive nodes; returns (table, tag of each
    cylinder)."""
    starts, ends, r0, r1, par, bra, ordr, tags = [], [], [], [], [], [], [], []
    end_row_of_node = np.full(len(sk.centroid), -1, dtype=np.int64)
    for b, seq in enumerate(sk.branches):
        j = sk.branch_parent_node[b]
        pts, rads, tg = _branch_polyline(seq, j, f.pos, final_r, tag, f.axes, foot, zmin, h)
        prev_row = -1
        for i in range(len(pts) - 1):
            node = seq[i]  # segment i ends at node seq[i]
            if np.linalg.norm(pts[i + 1] - pts[i]) < 1e-6:
                end_row_of_node[node] = (
                    prev_row if prev_row >= 0 else (end_row_of_node[j] if j >= 0 else -1)
                )
                continue
            row = len(starts)
            starts.append(pts[i])
            ends.append(pts[i + 1])
            r0.append(rads[i])
            r1.append(rads[i + 1])
            if prev_row >= 0:
                par.append(prev_row)
            else:
                par.append(int(end_row_of_node[j]) if j >= 0 else -1)
            bra.append(b + 1)
            ordr.append(sk.branch_order[b])
            tags.append(_TAG_NAMES[tg[i + 1]])
            prev_row = row
            end_row_of_node[node] = row
    if not starts:
        raise ReconstructionError("no cylinders could be built (is the cloud a tree?)")
    par_arr = np.asarray(par, dtype=np.int64)
    table = CylinderTable.from_endpoints(
        np.asarray(starts),
        np.asarray(ends),
        np.asarray(r0),
        end_radius_m=np.asarray(r1),
        parent=par_arr,
        branch=np.asarray(bra),
        branch_order=np.asarray(ordr),
        tag=np.asarray(tags),
    )
    return table, tags


# ---------------------------------------------------------------------------- main
def fit_qsm(
    points: np.ndarray,
    *,
    spacing_m: float,
    weights: np.ndarray | None = None,
    params: QSMParams | None = None,
    neighbors: np.ndarray | None = None,
    foot: StemFoot | None = None,
) -> QSMResult:
    """Fit a cylinder QSM to a single-tree cloud.

    Parameters
    ----------
    points : (n, 3) float64
        The tree's points in a local frame (metres, z up), prepared (downsampled, outliers
        removed).
    spacing_m : float
        Typical point spacing (median nearest-neighbour distance).
    weights : (n,) float, optional
        Points represented by each point (voxel counts); default 1.
    params : QSMParams
    neighbors : (n, k) int, optional
        Each point's nearest points, itself first, sorted by distance
        (:attr:`~treesim.reconstruct.preprocess.PreparedCloud.neighbors`); searched here
        when absent or when it has fewer than ``max(params.neighbors + 1,
        BRIDGE_NEIGHBORS)`` columns.
    foot : StemFoot, optional
        The terrain and the stem's foot (:attr:`PreparedCloud.foot
        <treesim.reconstruct.preprocess.PreparedCloud.foot>`): the graph grows from the
        lowest points near the foot's axis and the stem starts on the terrain. Without
        it, from the cloud's lowest points.

    Returns
    -------
    QSMResult
        The cylinder table (local coordinates) and per-node diagnostics.
    """
    params = params or QSMParams()
    res = params.resolved(spacing_m)
    h, link, band = res["slice_m"], res["link_m"], res["base_band_m"]
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    if n < 50:
        raise ReconstructionError(f"only {n} points after preparation; a QSM needs hundreds")

    graph = _geodesic(p, params, link, band, neighbors, foot)  # 1-2. graph, distance
    m, cl = _slice_clusters(graph, h)  # 3. slices -> clusters (nodes)
    sk = _node_tree(p, w, graph, m, cl)
    _trace_branches(sk)  # 4. branches
    fits = _fit_nodes(p, w, sk, params, spacing_m, h)  # 5. circle fits per node
    noise, r_min, r_min_rule = _noise_floor(fits, sk, params, res, spacing_m)  # 5b.
    model, grow, radius_model = _radius_model(p, sk, fits, params, h, spacing_m)  # 6.
    final_r, tag, n_outliers = _final_radii(
        sk, fits, model, noise["sd_m"] or 0.0, params, spacing_m, h
    )
    _smooth_axes(fits.pos, sk.branches, fits.measured, h)  # 6b.
    zmin = float(p[:, 2].min())
    table, tags = _cylinders(sk, fits, final_r, tag, foot, zmin, h)  # 7. cylinders
    diagnostics = {
        "params": {**asdict(params), **res, "min_radius_m": r_min},
        "points": n,
        "noise": {**noise, "min_radius_m": r_min, "min_radius_rule": r_min_rule},
        "graph_bridges": graph.n_bridges,
        "nodes": int(sk.keep.sum()),
        "nodes_measured": int(fits.measured.sum()),
        "radius_outliers": n_outliers,
        "branches": len(sk.branches),
        "radius_model": radius_model,
        "cylinders_by_tag": {t: int((np.asarray(tags) == t).sum()) for t in _TAG_NAMES},
    }
    return QSMResult(
        table=table,
        node_position=fits.pos,
        node_radius=final_r,
        node_measured=fits.measured,
        node_fit={
            "radius_m": fits.radius,
            "scatter_m": fits.scatter,
            "coverage_deg": fits.coverage,
            "branch": sk.branch_of,
            "growth_m": grow,
        },
        diagnostics=diagnostics,
    )
