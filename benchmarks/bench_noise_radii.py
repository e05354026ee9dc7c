"""How biased a circle fit's radius is against the range noise: the measurement behind
the QSM's ``resolve_sigmas`` (k = 4).

For each leaf-off preset (or those named), the scan of ``tests/reconstruct/
test_qsm_truth.py`` (three stations at 0.04°, the RIEGL VZ-400's noise, seed 0) is
prepared and fitted with every circle fit accepted however small
(``min_radius_m = 0.1 mm``); each fitted node's radius is divided by the true radius of
the generator's nearest cylinder at that point (its frustum sampled every 5 mm), and the
median ratio is printed per band of fitted radius in units of the estimated noise σ.

Usage: ``python benchmarks/bench_noise_radii.py [PRESET ...]`` (default all four
leaf-off presets; about a minute each on 2 cores). Prints measured figures only.
"""

from __future__ import annotations

import os
import platform
import sys
from datetime import date
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.reconstruct.test_qsm_truth import LEAF_OFF, scan_preset  # noqa: E402
from treesim.cloud import Cloud  # noqa: E402
from treesim.models import CylinderTable, generate_tree  # noqa: E402
from treesim.params import PrepareParams, QSMParams  # noqa: E402
from treesim.reconstruct.preprocess import prepare  # noqa: E402
from treesim.reconstruct.qsm import fit_qsm  # noqa: E402

#: Bands of fitted radius, in units of σ.
BANDS = ((0, 2), (2, 3), (3, 4), (4, 5), (5, 8), (8, 1e9))


def true_radius_at(table: CylinderTable, at: np.ndarray) -> np.ndarray:
    """The true radius of the frustum nearest each point of ``at`` (table coordinates)."""
    ax = table.axis / np.linalg.norm(table.axis, axis=1)[:, None]
    pts, radii = [], []
    for i, length in enumerate(table.length_m):
        t = np.linspace(0.0, 1.0, max(2, int(length / 0.005) + 1))
        pts.append(table.start[i] + t[:, None] * ax[i] * length)
        radii.append(table.radius_m[i] + t * (table.end_radius_m[i] - table.radius_m[i]))
    _, j = cKDTree(np.concatenate(pts)).query(at)
    return np.concatenate(radii)[j]


def main() -> None:
    names = sys.argv[1:] or LEAF_OFF
    print(
        f"bench_noise_radii ({date.today()}, {platform.machine()}, {os.cpu_count()} cores): "
        "fitted / true radius, median per band of fitted radius r / σ"
    )
    print("preset        σ mm " + "".join(f"  [{lo:g},{hi:g})".ljust(16) for lo, hi in BANDS))
    worst = {"at or above 4 σ": 0.0, "below 4 σ": 0.0}
    for name in names:
        _, cloud = scan_preset(name)
        pc = prepare(Cloud(cloud.points), PrepareParams())
        res = fit_qsm(
            pc.points,
            spacing_m=pc.spacing_m,
            weights=pc.weights,
            params=QSMParams(min_radius_m=1e-4),
            neighbors=pc.neighbors,
        )
        sigma = float(res.diagnostics["noise"]["sd_m"])
        truth = generate_tree(name, seed=0, leaves=False).cylinders
        true_r = true_radius_at(truth, res.node_position + pc.frame.origin_array)
        fitted = res.node_fit["radius_m"]
        ok = res.node_measured & np.isfinite(fitted)
        cells = []
        for lo, hi in BANDS:
            sel = ok & (fitted >= lo * sigma) & (fitted < hi * sigma)
            if sel.any():
                med = np.median(fitted[sel] / true_r[sel]) - 1
                key = "at or above 4 σ" if lo >= 4 else "below 4 σ"
                worst[key] = max(worst[key], abs(float(med)))
                cells.append(f"{med * 100:+6.1f} % n={int(sel.sum()):<5d}")
            else:
                cells.append("   -".ljust(16))
        print(f"{name:<12} {sigma * 1e3:5.2f} " + "".join(c.ljust(16) for c in cells))
    print(
        "largest |median| over the presets: "
        + ", ".join(f"{k} {v * 100:.1f} %" for k, v in worst.items())
    )


if __name__ == "__main__":
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("bench-noise-radii"), "bench_noise_radii.py"):
        main()
