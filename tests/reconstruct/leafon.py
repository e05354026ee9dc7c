"""Procedural trees scanned as the wood/leaf classifier's training and test scans are:
the RIEGL VZ-400 noise model from three stations, every point labelled exactly by the
virtual scanner. Shared by ``test_leafwood.py``, ``benchmarks/bench_leaves.py`` and
``scripts/fit_leafwood.py``, with the wood precision and recall they report."""

from __future__ import annotations

import numpy as np

from treesim.cloud import LABEL_CODES


def scan_preset(name: str, step_deg: float, seed: int = 0):
    """The preset ``name`` (seed ``seed``) scanned at ``step_deg``: (tree, cloud)."""
    from treesim.models import SPECIES, generate_tree
    from treesim.scan import instrument, ring_layout, scan
    from treesim.scene import MeshPart, Scene

    tree = generate_tree(name, seed=seed, leaves=SPECIES[name].leaves_on)
    v, f, lab = tree.mesh(32)
    parts = [
        MeshPart(vertices=v, faces=f[lab == code], label=part, name=part)
        for part, code in LABEL_CODES.items()
        if (lab == code).any()
    ]
    scene = Scene(parts)
    lo, hi = scene.bounds
    stations = ring_layout(
        3,
        distance_m=max(10.0, 0.5 * (hi[2] - lo[2])),
        height_m=1.5,
        centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
        base_z_m=float(lo[2]),
    )
    spec = instrument("riegl-vz400").spec(
        noise=True, horizontal_resolution_deg=step_deg, vertical_resolution_deg=step_deg
    )
    return tree, scan(scene, stations, spec, nthreads=2).cloud


def labelled_voxels(
    points: np.ndarray, wood: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The points thinned to ``voxel_m`` voxels (as preparation does, in a local frame) and
    each voxel's truth: wood when at least half its points are."""
    from treesim.reconstruct.preprocess import voxel_downsample

    local = points - points.mean(axis=0)
    pts, _, inv = voxel_downsample(local, voxel_m)
    share = np.bincount(inv, weights=wood, minlength=len(pts)) / np.bincount(inv)
    return pts, share >= 0.5


def wood_scores(wood: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Wood precision and recall of the labels ``wood`` against ``truth`` (both bool)."""
    tp = float((wood & truth).sum())
    return tp / max(int(wood.sum()), 1), tp / max(int(truth.sum()), 1)


def slab_circle_diameter_m(points: np.ndarray, height_m: float = 1.3, band_m: float = 0.2):
    """Diameter of the algebraic (Kåsa) circle through the slab's points at ``height_m``
    above the lowest point: an estimate independent of the QSM."""
    z0 = points[:, 2].min()
    q = points[np.abs(points[:, 2] - z0 - height_m) <= band_m / 2, :2]
    q = q - q.mean(axis=0)
    a = np.column_stack([2 * q, np.ones(len(q))])
    c, *_ = np.linalg.lstsq(a, (q**2).sum(axis=1), rcond=None)
    return 2.0 * float(np.sqrt(c[2] + c[0] ** 2 + c[1] ** 2))
