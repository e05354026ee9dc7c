"""The leaf-on path of :func:`treesim.reconstruct.reconstruct`: separate, then add leaves.

Kept apart from ``__init__.py`` so that the reconstruction's dispatch changes by two calls:
``separate`` before the model is built (the model sees the wood points only) and
``Separated.apply`` after (labels, figures and the leaf layer).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..cloud import LABEL_CODES, LABEL_NAMES, Cloud
from ..errors import ReconstructionError
from .leafwood import MIN_POINTS, separate_leaves

if TYPE_CHECKING:
    from ..params import ReconstructParams
    from .preprocess import PreparedCloud

#: Fewest wood points the model is built from after separation.
MIN_WOOD_POINTS = 100
#: Share of the points (weighted by the input points they stand for) that the classifier
#: calls leaf from which ``auto`` separates. Measured (2026-11-25, classifier of
#: leafwood_model.json, benchmarks/bench_leaves.py --auto): leaf-off procedural presets
#: (aspen, sapling, old-tupelo scanned at 0.04-0.12 deg) 0.000-0.137, leaf-on ones
#: (aspen-leafon, balsam-fir) 0.56-0.63; real clouds: coffee tree 0.015, aRchi tree 0.056
#: (leaf-off), AdTree tree7 0.195 (leaf clumps in its top), needle-on pine 0.255, leaf-on
#: Lille 0.338. The cut sits between the highest leaf-off and the lowest leaf-on reading.
LEAF_SHARE_CUT = 0.165


@dataclass
class Separated:
    """A prepared cloud split into wood and leaf points."""

    prepared: PreparedCloud
    wood_mask: np.ndarray
    figures: dict[str, Any]
    seconds: float
    #: False where ``auto`` found too few leaves: the model is built from every point and
    #: only the figures (``leaf_share``, ``leaves_present``) are added.
    used: bool = True

    @property
    def wood(self) -> PreparedCloud:
        """The prepared cloud reduced to its wood points."""
        m = self.wood_mask
        p = self.prepared
        return replace(
            p,
            points=p.points[m],
            weights=p.weights[m],
            normals=None if p.normals is None else p.normals[m],
            neighbors=None,  # the full cloud's indices: the QSM searches the wood's own
        )

    def labels(self) -> Cloud:
        """The prepared points in the input's coordinates with a ``label`` field."""
        label = np.where(self.wood_mask, LABEL_CODES["wood"], LABEL_CODES["leaf"])
        return Cloud(
            self.prepared.global_points,
            {"label": label.astype(np.uint8)},
            {"label_names": dict(LABEL_NAMES)},
        )

    def apply(self, model: Any, params: ReconstructParams) -> None:
        """Add to a ``TreeModel`` the labels, the figures and the leaf quads (if asked)."""
        from ..models.leaves import leaf_layer

        model.timings_s["separate_leaves"] = self.seconds
        if not self.used:
            model.figures.update(self.figures)
            return
        model.labels = self.labels()
        figures = dict(self.figures)
        t0 = time.perf_counter()
        if params.leaf_layer:
            p = self.prepared
            layer = leaf_layer(
                p.global_points[~self.wood_mask],
                spacing_m=p.spacing_m,
                side_m=params.leaf_side_m,
            )
            base = len(model.vertices)
            model.vertices = np.concatenate([model.vertices, layer.vertices])
            model.faces = np.concatenate([model.faces, layer.faces + base])
            model.face_label = np.concatenate(
                [model.face_label, np.full(len(layer.faces), LABEL_CODES["leaf"], np.uint8)]
            )
            figures.update(
                n_leaves=layer.n_leaves,
                leaf_area_m2=layer.leaf_area_m2,
                n_triangles_leaf=int(len(layer.faces)),
            )
        model.figures.update(figures)
        model.timings_s["leaf_layer"] = time.perf_counter() - t0


def separate(
    prepared: PreparedCloud, mode: str, model: dict[str, Any] | None = None
) -> Separated | None:
    """Label the prepared points wood or leaf (``mode``: ``on`` or ``auto``).

    ``auto`` keeps the labels only where the classifier calls at least
    :data:`LEAF_SHARE_CUT` of the points leaf (else the result has ``used`` False), and
    returns None for a cloud too small to classify. ``model``: the classifier's
    (default: the shipped one).
    """
    t0 = time.perf_counter()
    if mode == "auto" and len(prepared.points) < MIN_POINTS:
        return None
    result = separate_leaves(prepared.points, model)
    w = prepared.weights
    share = float(w[~result.wood].sum() / w.sum()) if w.sum() > 0 else 0.0
    leafy = share >= LEAF_SHARE_CUT
    figures: dict[str, Any] = {"leaf_share": share, "leaves_present": leafy}
    if mode == "auto" and not leafy:
        figures["leaf_separation"] = "off (auto: no leaves found)"
        return Separated(prepared, result.wood, figures, time.perf_counter() - t0, used=False)
    if int(result.wood.sum()) < MIN_WOOD_POINTS:
        raise ReconstructionError(
            f"wood/leaf separation found only {int(result.wood.sum())} wood points of "
            f"{len(result.wood)}; reconstruct with --separate-leaves off"
        )
    figures.update(leaf_separation=mode, **result.summary(prepared.weights))
    return Separated(prepared, result.wood, figures, time.perf_counter() - t0)
