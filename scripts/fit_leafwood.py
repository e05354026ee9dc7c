"""Fit the wood/leaf classifier of ``pipeline.reconstruct.leafwood`` (its model file).

A CANUPO-style classifier (Brodu & Lague 2012): multiscale eigen features, then a linear
(logistic) decision. It is fitted on procedural trees whose wood and leaf labels the
virtual scanner records exactly, scanned with the RIEGL VZ-400 noise model from three
stations at several angular steps, on seeds the tests never use (1 and 2); the tests and
the README measure it on seed 0. Run from the repository root:

    python scripts/fit_leafwood.py     # writes pipeline/data/leafwood_model.json

Deterministic: the same code writes the same model.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.cloud import LABEL_CODES  # noqa: E402
from pipeline.reconstruct.leafwood import base_features as features  # noqa: E402
from pipeline.reconstruct.leafwood import neighbours  # noqa: E402
from tests.reconstruct.leafon import labelled_voxels, scan_preset, wood_scores  # noqa: E402

#: (preset, seed, angular step in degrees): the training scans.
TRAINING = (
    ("aspen-leafon", 1, 0.06),
    ("aspen-leafon", 2, 0.10),
    ("aspen-leafon", 1, 0.14),
    ("balsam-fir", 1, 0.08),
    ("aspen", 1, 0.08),
    ("sapling", 1, 0.06),
)
#: Points drawn from each scan for the fit.
PER_SCAN = 60_000
VOXEL_M = 0.005
#: Logistic stages: the features alone, then two rounds of context.
STAGES = 3
#: Leaf-on presets (the threshold balances precision and recall on their scans).
LEAF_ON = ("aspen-leafon", "balsam-fir")


def fit_logistic(x: np.ndarray, y: np.ndarray, ridge: float = 1e-2) -> dict:
    """A ridge-regularised logistic regression (IRLS) on standardised features."""
    mean, scale = x.mean(axis=0), x.std(axis=0) + 1e-9
    xb = np.hstack([(x - mean) / scale, np.ones((len(x), 1))])
    w = np.zeros(xb.shape[1])
    for _ in range(60):
        p = 1.0 / (1.0 + np.exp(-np.clip(xb @ w, -30, 30)))
        grad = xb.T @ (y - p) - ridge * w
        hess = (xb * (p * (1 - p))[:, None]).T @ xb + ridge * np.eye(len(w))
        step = np.linalg.solve(hess, grad)
        w += step
        if np.abs(step).max() < 1e-9:
            break
    return {"mean": mean, "scale": scale, "weights": w}


def balanced_threshold(score: np.ndarray, wood: np.ndarray) -> float:
    """The score at which wood precision equals wood recall."""
    order = np.argsort(-score)
    tp = np.cumsum(wood[order])
    k = int(np.argmin(np.abs(tp / np.arange(1, len(score) + 1) - tp / wood.sum())))
    return float(score[order][k])


def main() -> None:
    import argparse
    import json

    from pipeline._version import software_versions
    from pipeline.reconstruct.leafwood import MODEL_PATH, context_features, stage_score

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, help="keep the training scans in this folder")
    ap.add_argument("-o", "--output", type=Path, default=MODEL_PATH)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    scans = []
    for name, seed, step in TRAINING:
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
        rows = []
        for s in scans:
            x = s["base"]
            if k > 0:
                x = context_features(s["points"], s["score"], s["base"], s["nn"])
            s["x"] = x
            rows.append(x[s["pick"]])
        y = np.concatenate([s["wood"][s["pick"]] for s in scans]).astype(np.float64)
        stage = fit_logistic(np.concatenate(rows), y)
        stages.append(stage)
        for s in scans:
            s["score"] = stage_score(stage, s["x"])
    leafy = [s for s in scans if s["name"] in LEAF_ON]
    score = np.concatenate([s["score"][s["pick"]] for s in leafy])
    wood = np.concatenate([s["wood"][s["pick"]] for s in leafy])
    threshold = balanced_threshold(score, wood)
    for s in scans:
        precision, recall = wood_scores(s["score"] > threshold, s["wood"])
        print(f"training {s['name']}: wood precision {precision:.3f}, recall {recall:.3f}")
    model = {
        "description": "wood/leaf classifier of pipeline.reconstruct.leafwood",
        "fitted_by": "scripts/fit_leafwood.py",
        "training": [
            {"preset": n, "seed": sd, "step_deg": st, "scanner": "riegl-vz400 noise", "stations": 3}
            for n, sd, st in TRAINING
        ],
        "software": software_versions("pgeof"),
        "threshold": threshold,
        "stages": [{k: v.tolist() for k, v in st.items()} for st in stages],
    }
    args.output.write_text(json.dumps(model, indent=None) + "\n", encoding="utf-8")
    print(f"threshold {threshold:.3f}; wrote {args.output}")


if __name__ == "__main__":
    main()
