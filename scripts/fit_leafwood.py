"""Fit the wood/leaf classifier of ``treesim.reconstruct.leafwood`` (its model file).

A CANUPO-style classifier (Brodu & Lague 2012): multiscale eigen features, then a
decision by a one-hidden-layer network (32 tanh units, logistic output; fitted by L-BFGS
on the cross-entropy with a small L2 penalty), in three stacked stages (auto-context).
It is fitted on procedural trees whose wood and leaf labels the virtual scanner records
exactly, scanned with the RIEGL VZ-400 noise model from three stations at several
angular steps (0.05-0.14°), on seeds the tests never use (1 and 2); the tests and the
manual (docs/validation.md) measure it on seed 0. Run from the repository root:

    python scripts/fit_leafwood.py            # writes pipeline/data/leafwood_model.json
    python scripts/fit_leafwood.py --fronds   # pipeline/data/leafwood_fronds_model.json

The frond model adds the scans of :data:`FRONDS` (palms) and counts palms as leaf-on;
the reconstruction asks it for a second opinion where a first QSM warns that leaves may
have been taken for wood (``treesim.reconstruct.SECOND_OPINION_CODES``).

Deterministic (seeded draws and start weights): the same code on the same machine writes
the same model; a different BLAS may change the last digits. About 10 minutes on 2 cores.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.reconstruct.leafon import labelled_voxels, scan_preset, wood_scores  # noqa: E402
from treesim.cloud import LABEL_CODES  # noqa: E402
from treesim.reconstruct.leafwood import base_features as features  # noqa: E402
from treesim.reconstruct.leafwood import neighbours  # noqa: E402

#: (preset, seed, angular step in degrees): the training scans.
TRAINING = (
    ("aspen-leafon", 2, 0.05),
    ("aspen-leafon", 1, 0.06),
    ("aspen-leafon", 2, 0.10),
    ("aspen-leafon", 1, 0.14),
    ("balsam-fir", 1, 0.08),
    ("aspen", 1, 0.08),
    ("sapling", 1, 0.06),
)
#: The frond model's scans on top of :data:`TRAINING` (``--fronds``): palms, whose
#: leaflets hang in curtains that look like twigs at field density, at a fine and a
#: field-like step, and a leaf-off tree as sparse, so that sparse wood stays wood.
FRONDS = (
    ("palm", 1, 0.08),
    ("palm", 2, 0.20),
    ("aspen", 2, 0.20),
)
#: Points drawn from each scan for the fit.
PER_SCAN = 60_000
VOXEL_M = 0.005
#: Stages: the features alone, then two rounds of context.
STAGES = 3
#: Hidden units of each stage's network, and its L2 penalty (on standardised features).
HIDDEN = 32
L2 = 1e-3
#: L-BFGS iterations of a stage's fit.
MAX_ITER = 300
#: Leaf-on presets (the threshold balances precision and recall on their scans).
LEAF_ON = ("aspen-leafon", "balsam-fir")


def fit_network(
    x: np.ndarray, y: np.ndarray, hidden: int = HIDDEN, l2: float = L2, seed: int = 0
) -> dict:
    """A one-hidden-layer network (tanh, logistic output) fitted by L-BFGS on the mean
    cross-entropy plus ``l2 / 2`` times the squared weights, on standardised features."""
    from scipy.optimize import minimize

    mean, scale = x.mean(axis=0), x.std(axis=0) + 1e-9
    z = (x - mean) / scale
    n, d = z.shape
    rng = np.random.default_rng(seed)
    shapes = [(d, hidden), (hidden,), (hidden,), (1,)]
    cuts = np.cumsum([int(np.prod(s)) for s in shapes])[:-1]

    def unpack(theta: np.ndarray) -> list[np.ndarray]:
        return [p.reshape(s) for p, s in zip(np.split(theta, cuts), shapes, strict=True)]

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        w1, b1, w2, b2 = unpack(theta)
        h = np.tanh(z @ w1 + b1)
        a = h @ w2 + b2[0]
        p = 1.0 / (1.0 + np.exp(-np.clip(a, -30, 30)))
        value = np.mean(np.logaddexp(0.0, a) - y * a) + 0.5 * l2 * (np.sum(w1**2) + np.sum(w2**2))
        g = (p - y) / n
        gh = np.outer(g, w2) * (1.0 - h**2)
        grad = [z.T @ gh + l2 * w1, gh.sum(axis=0), h.T @ g + l2 * w2, np.array([g.sum()])]
        return float(value), np.concatenate([q.ravel() for q in grad])

    theta0 = np.concatenate(
        [
            rng.normal(0.0, 1.0 / np.sqrt(d), d * hidden),
            np.zeros(hidden),
            rng.normal(0.0, 1.0 / np.sqrt(hidden), hidden),
            np.zeros(1),
        ]
    )
    res = minimize(loss, theta0, jac=True, method="L-BFGS-B", options={"maxiter": MAX_ITER})
    w1, b1, w2, b2 = unpack(res.x)
    return {"mean": mean, "scale": scale, "W1": w1, "b1": b1, "w2": w2, "b2": b2}


def balanced_threshold(score: np.ndarray, wood: np.ndarray) -> float:
    """The score at which wood precision equals wood recall."""
    order = np.argsort(-score)
    tp = np.cumsum(wood[order])
    k = int(np.argmin(np.abs(tp / np.arange(1, len(score) + 1) - tp / wood.sum())))
    return float(score[order][k])


def main() -> None:
    import argparse
    import json

    from treesim._version import software_versions
    from treesim.reconstruct.leafwood import (
        FRONDS_MODEL_PATH,
        MODEL_PATH,
        context_features,
        stage_score,
    )

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, help="keep the training scans in this folder")
    ap.add_argument(
        "--fronds",
        action="store_true",
        help="the frond model (the scans of FRONDS added; palms count as leaf-on)",
    )
    ap.add_argument("-o", "--output", type=Path)
    args = ap.parse_args()
    training = TRAINING + FRONDS if args.fronds else TRAINING
    leaf_on = (*LEAF_ON, "palm") if args.fronds else LEAF_ON
    output = args.output or (FRONDS_MODEL_PATH if args.fronds else MODEL_PATH)
    rng = np.random.default_rng(0)
    scans = []
    for name, seed, step in training:
        t0 = time.perf_counter()
        cached = args.cache / f"{name}_{seed}_{step}.npz" if args.cache else None
        if cached is not None and cached.is_file():
            d = np.load(cached)
            vox, y = d["points"], d["wood"]
        else:
            _, cloud = scan_preset(name, step, seed=seed)
            wood = cloud.fields["label"] == LABEL_CODES["wood"]
            vox, y = labelled_voxels(cloud.points, wood, VOXEL_M)
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                np.savez(cached, points=vox, wood=y)
        pick = np.sort(rng.choice(len(vox), size=min(PER_SCAN, len(vox)), replace=False))
        nn = neighbours(vox)
        scan = {"name": name, "points": vox, "wood": y, "pick": pick, "nn": nn}
        scan["base"] = features(vox, nn)
        scans.append(scan)
        print(
            f"{name} seed {seed} at {step} deg: {len(vox):,} points, wood {y.mean():.2f}, "
            f"{time.perf_counter() - t0:.1f} s",
            flush=True,
        )
    stages = []
    for k in range(STAGES):
        t0 = time.perf_counter()
        rows = []
        for s in scans:
            x = s["base"]
            if k > 0:
                x = context_features(s["points"], s["score"], s["base"], s["nn"])
            s["x"] = x
            rows.append(x[s["pick"]])
        y = np.concatenate([s["wood"][s["pick"]] for s in scans]).astype(np.float64)
        stage = fit_network(np.concatenate(rows), y)
        stages.append(stage)
        print(f"stage {k}: {len(y):,} rows, {time.perf_counter() - t0:.0f} s", flush=True)
        for s in scans:
            s["score"] = stage_score(stage, s["x"])
    leafy = [s for s in scans if s["name"] in leaf_on]
    score = np.concatenate([s["score"][s["pick"]] for s in leafy])
    wood = np.concatenate([s["wood"][s["pick"]] for s in leafy])
    threshold = balanced_threshold(score, wood)
    for s in scans:
        precision, recall = wood_scores(s["score"] > threshold, s["wood"])
        print(f"training {s['name']}: wood precision {precision:.3f}, recall {recall:.3f}")
    model = {
        "description": "wood/leaf classifier of treesim.reconstruct.leafwood",
        "fitted_by": "scripts/fit_leafwood.py",
        "training": [
            {"preset": n, "seed": sd, "step_deg": st, "scanner": "riegl-vz400 noise", "stations": 3}
            for n, sd, st in training
        ],
        "software": software_versions("pgeof"),
        "decision": f"one hidden layer of {HIDDEN} tanh units, logistic output",
        "threshold": threshold,
        "stages": [{k: v.tolist() for k, v in st.items()} for st in stages],
    }
    output.write_text(json.dumps(model, indent=None) + "\n", encoding="utf-8")
    print(f"threshold {threshold:.3f}; wrote {output}")


if __name__ == "__main__":
    main()
