"""Wood and leaf separation of a field cloud, before the QSM.

A leaf-on cloud handed to the QSM as it is gives nonsense: leaves are taken for twigs
(the aspen-leafon preset comes out +33 % in total volume). :func:`separate_leaves` labels
every point ``wood`` or ``leaf`` so that the QSM sees the wood only.

The classifier is CANUPO's kind (Brodu & Lague 2012, ISPRS J. 68:121): multiscale
eigen features, then a learned decision (CANUPO's is linear; here a small network), with
two rounds of context (auto-context):

1. **Eigen features** of each point's neighbourhood at several scales, computed with
   pgeof (C++; MIT): linearity, planarity, scattering, verticality, normal, length,
   surface, volume, curvature of the 8, 16, 32 and 64 nearest neighbours, and
   linearity, planarity, verticality, eigenentropy and curvature within 2.5, 5, 10 and
   20 cm (the larger radii on a voxel support of a quarter of the radius, so the cost
   stays linear). A stem is planar at a small scale and linear at a large one; a twig is
   linear at every scale; a leaf blade (3-15 cm) is planar at its own scale and scattered
   at a larger one.
2. A small neural network (one hidden layer of 32 tanh units, a logistic output) scores
   those features: a first wood probability. A linear (logistic) score, CANUPO's own
   decision, left wood recall at 0.947 on the aspen-leafon test scan: which features
   mark wood depends on the scale of the branch (a stem is planar where a twig is
   linear), a conjunction a linear score cannot express.
3. **Context**, twice: the mean wood probability of the 4 ... 32 nearest neighbours, and
   the shape of the *candidate wood skeleton* around each point: the linearity,
   planarity and verticality of the 8 and 16 nearest candidate wood points (probability
   above ½), and the distance to the nearest of them. A twig hidden among leaves is a
   clean line once the leaves are set aside; a blade seen edge-on is a short line with
   no candidate wood continuing it. A new network scores these with the features of
   step 1.
4. A point is wood where the last score exceeds the model's threshold (the score at
   which precision equals recall on the training scans).

The weights live in ``pipeline/data/leafwood_model.json``, fitted by
``scripts/fit_leafwood.py`` on procedural trees whose labels the virtual scanner records
exactly (aspen-leafon, balsam-fir shoots, leaf-off aspen and sapling), scanned with the
RIEGL VZ-400 noise model at several angular steps, on seeds 1 and 2; the tests measure
it on seed 0. Measured there, see the manual (docs/guides/reconstruction.md, "Leaf-on
field clouds"). A second model, ``leafwood_fronds_model.json`` (:func:`fronds_model`),
is fitted on the same scans plus palms; :func:`treesim.reconstruct.reconstruct` asks it
for a second opinion where the first QSM warns that leaves were taken for wood.

Everything is deterministic; coordinates enter pgeof as float32 in the local frame the
reconstruction works in (float32 resolves 1 µm at 20 m).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ReconstructionError

__all__ = [
    "KNN_SCALES",
    "MODEL_PATH",
    "RADIUS_SCALES_M",
    "LeafWoodResult",
    "base_features",
    "context_features",
    "fronds_model",
    "neighbours",
    "separate_leaves",
]

#: Neighbour counts of the kNN eigen features.
KNN_SCALES = (8, 16, 32, 64)
#: Radii of the radius eigen features (m): a leaf blade, a twig's run between leaves, a
#: branch's cross-section.
RADIUS_SCALES_M = (0.025, 0.05, 0.1, 0.2)
#: Largest neighbourhood of a radius feature (points).
RADIUS_MAX_KNN = 48
#: Neighbour counts over which the wood probability is averaged (context).
CONTEXT_K = (4, 8, 16, 32)
#: Neighbour counts of the candidate-skeleton features (context).
SKELETON_K = (8, 16)
#: The fitted model (scripts/fit_leafwood.py writes it).
MODEL_PATH = Path(__file__).resolve().parents[1] / "data" / "leafwood_model.json"
#: The frond model (``scripts/fit_leafwood.py --fronds``): the same features, fitted with
#: palm scans too; used for a second opinion where the first leaves fronds as wood.
FRONDS_MODEL_PATH = MODEL_PATH.with_name("leafwood_fronds_model.json")
#: Fewest points the classifier accepts.
MIN_POINTS = max(KNN_SCALES) + 1
#: Points whose context features are made and scored at a time: the float64 features
#: and the network's intermediates (about 2 KB a point) live for one chunk only, so the
#: classifier holds little more than its base features and the neighbour table (768 B a
#: point); scored at once, a 1.5 M-point cloud took 6.8 GB.
CHUNK_ROWS = 65_536


@dataclass(frozen=True)
class LeafWoodResult:
    """Per-point wood/leaf labels.

    Attributes
    ----------
    wood : (n,) bool
        True where the point is wood.
    score : (n,) float64
        The last stage's score (log-odds of wood); ``wood = score > threshold``.
    threshold : float
    """

    wood: np.ndarray
    score: np.ndarray
    threshold: float

    def summary(self, weights: np.ndarray | None = None) -> dict[str, Any]:
        """Point counts (and, with ``weights``, the input points they stand for)."""
        w = np.ones(len(self.wood)) if weights is None else np.asarray(weights, np.float64)
        total = float(w.sum())
        return {
            "points_wood": int(self.wood.sum()),
            "points_leaf": int((~self.wood).sum()),
            "wood_fraction": float(w[self.wood].sum() / total) if total > 0 else 0.0,
            "threshold": self.threshold,
        }


def _f32(points: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(points, dtype=np.float32)


def _knn(points32: np.ndarray, k: int) -> np.ndarray:
    import pgeof

    nn, _ = pgeof.knn_search(points32, points32, int(k))
    return np.asarray(nn, dtype=np.uint32)


def _multiscale(points32: np.ndarray, nn: np.ndarray, scales: tuple[int, ...]) -> np.ndarray:
    """pgeof's 11 features at each k of ``scales`` from a (n, max k) neighbour table
    (float32, as pgeof computes them from float32 points)."""
    import pgeof

    n, k = nn.shape
    ptr = np.arange(0, n * k + 1, k, dtype=np.uint32)
    f = pgeof.compute_features_multiscale(points32, np.ascontiguousarray(nn.ravel()), ptr, scales)
    return np.asarray(f, dtype=np.float32).reshape(n, -1)


def neighbours(points: np.ndarray) -> np.ndarray:
    """The (n, 64) nearest-neighbour table the features share (self first)."""
    return _knn(_f32(points), max(KNN_SCALES))


def base_features(points: np.ndarray, nn: np.ndarray | None = None) -> np.ndarray:
    """The multiscale eigen features of step 1, (n, 4 × 11 + 4 × 5) float64.

    Parameters
    ----------
    points : (n, 3) float
        Local coordinates (m), at least :data:`MIN_POINTS` points.
    nn : (n, 64) uint32, optional
        :func:`neighbours` of the points (computed when not given).
    """
    import pgeof

    from .preprocess import voxel_downsample

    pts = np.asarray(points, dtype=np.float64)
    p32 = _f32(pts)
    nn = neighbours(pts) if nn is None else nn
    cols = [_multiscale(p32, nn, KNN_SCALES)]
    fid = pgeof.EFeatureID
    ids = [fid.Linearity, fid.Planarity, fid.Verticality, fid.Eigentropy, fid.Curvature]
    for r in RADIUS_SCALES_M:
        sup, _, inv = voxel_downsample(pts, r / 4.0)
        f = pgeof.compute_features_selected(np.ascontiguousarray(sup), r, RADIUS_MAX_KNN, ids)
        cols.append(np.asarray(f)[inv])  # (float64: pgeof computes in the support's type)
    return np.hstack(cols, dtype=np.float64)


class _Context:
    """What step 3's features of any point need from a previous stage's ``score``: the
    wood probability of every point and the candidate wood skeleton (its k-d tree and
    its points' linearity, planarity and verticality at :data:`SKELETON_K`)."""

    def __init__(self, points: np.ndarray, score: np.ndarray, nn: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        self.pts = np.asarray(points, dtype=np.float64)
        self.nn = nn
        self.score = score
        self.prob = 1.0 / (1.0 + np.exp(-np.clip(score, -30.0, 30.0)))
        cand = np.flatnonzero(self.prob > 0.5)
        self.skeleton = None
        if len(cand) > max(SKELETON_K):
            c32 = _f32(self.pts[cand])
            f = _multiscale(c32, _knn(c32, max(SKELETON_K)), SKELETON_K)
            f = f.reshape(len(cand), -1, 11)[:, :, [0, 1, 3]].reshape(len(cand), -1)
            self.skeleton = (cKDTree(self.pts[cand]), f)

    def features(self, base: np.ndarray, rows: slice) -> np.ndarray:
        """Step 3's features of the points ``rows``: their ``base`` features, the score,
        the mean probability of their 4 ... 32 nearest neighbours, the skeleton's shape
        at its nearest point and the log distance to it; float64."""
        nn = self.nn[rows, : max(CONTEXT_K)].astype(np.int64)
        cols = [self.score[rows, None]]
        cols += [self.prob[nn[:, :k]].mean(axis=1)[:, None] for k in CONTEXT_K]
        n_skel = 3 * len(SKELETON_K)
        if self.skeleton is not None:
            tree, f = self.skeleton
            dist, near = tree.query(self.pts[rows], workers=-1)
            skel = f[near]
        else:  # no candidate skeleton: every point is far from wood
            m = len(nn)
            dist, skel = np.full(m, 10.0), np.zeros((m, n_skel), dtype=np.float32)
        cols += [skel, np.log(dist + 1e-4)[:, None]]
        return np.hstack([base[rows], *cols], dtype=np.float64)


def context_features(
    points: np.ndarray, score: np.ndarray, base: np.ndarray, nn: np.ndarray | None = None
) -> np.ndarray:
    """Step 3's features: ``base`` plus the context of a previous stage's ``score``
    (``nn``: :func:`neighbours` of the points, computed when not given), (n, 76) float64."""
    nn = neighbours(points) if nn is None else nn
    return _Context(points, score, nn).features(base, slice(None))


def _chunks(n: int) -> list[slice]:
    return [slice(lo, min(n, lo + CHUNK_ROWS)) for lo in range(0, n, CHUNK_ROWS)]


@cache
def _model(path: Path = MODEL_PATH) -> dict[str, Any]:
    try:
        model = json.loads(path.read_text(encoding="utf-8"))
        for stage in model["stages"]:
            for key in ("mean", "scale", "W1", "b1", "w2", "b2"):
                stage[key] = np.asarray(stage[key], dtype=np.float64)
    except (OSError, ValueError, KeyError) as exc:
        raise ReconstructionError(
            f"cannot read the wood/leaf model {path}: {exc}; reinstall treesim or "
            "run scripts/fit_leafwood.py"
        ) from exc
    return model


def fronds_model() -> dict[str, Any]:
    """The frond model (:data:`FRONDS_MODEL_PATH`), read once.

    Returns
    -------
    dict
        Stages and threshold, as :func:`separate_leaves` takes them.

    Examples
    --------
    >>> from treesim.reconstruct.leafwood import fronds_model
    >>> len(fronds_model()["stages"])
    3
    """
    return _model(FRONDS_MODEL_PATH)


def stage_score(stage: dict[str, Any], x: np.ndarray) -> np.ndarray:
    """One stage's score (log-odds of wood) of the feature rows ``x``: a one-hidden-layer
    network (``W1``, ``b1``, ``w2``, ``b2``) on the standardised features."""
    z = (x - stage["mean"]) / stage["scale"]
    return np.tanh(z @ stage["W1"] + stage["b1"]) @ stage["w2"] + float(stage["b2"][0])


def separate_leaves(points: np.ndarray, model: dict[str, Any] | None = None) -> LeafWoodResult:
    """Label each point wood or leaf.

    Parameters
    ----------
    points : (n, 3) float
        One tree's points in local coordinates (m), e.g. a ``PreparedCloud``'s.
    model : dict, optional
        Stages and threshold (default: the shipped ``leafwood_model.json``).

    Returns
    -------
    LeafWoodResult

    Raises
    ------
    ReconstructionError
        Fewer than :data:`MIN_POINTS` points.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < MIN_POINTS:
        raise ReconstructionError(
            f"wood/leaf separation needs at least {MIN_POINTS} points, got {len(pts)}; "
            "turn it off (--separate-leaves off)"
        )
    model = _model() if model is None else model
    nn = neighbours(pts)
    base = base_features(pts, nn)
    stages = model["stages"]
    chunks = _chunks(len(pts))
    score = np.concatenate([stage_score(stages[0], base[c]) for c in chunks])
    for stage in stages[1:]:
        ctx = _Context(pts, score, nn)
        score = np.concatenate([stage_score(stage, ctx.features(base, c)) for c in chunks])
    threshold = float(model["threshold"])
    return LeafWoodResult(wood=score > threshold, score=score, threshold=threshold)
