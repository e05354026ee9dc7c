"""AVOHD comparison speed: ``treesim.compare`` against pymeshlab's Hausdorff filter.

One run, same data for both: the bundled coffee tree's TreeQSM model meshed at 24 facets
per ring (~100k triangles) and 1M points sampled on its surface with 2 mm Gaussian noise
(seeded). Both directions:

1. accuracy, every point to the mesh: treesim (Open3D picks a triangle in float32, the
   distance is recomputed exactly in float64) against
   ``get_hausdorff_distance(cloud -> mesh, samplevert=True, sampleface=False,
   samplenum=N, maxdist=large)`` (the cloud handed over as a vertex-only mesh);
2. completeness, the mesh to the cloud, with 1M surface samples on each side: treesim
   (seeded area-uniform samples, k-d tree) against ``get_hausdorff_distance(mesh ->
   cloud, samplevert=False, sampleface=True, samplenum=N, maxdist=large)``.

treesim's time is the whole ``compare()`` call (BVH and k-d tree builds, spacing
estimate, sampling, statistics, splits); pymeshlab's is its two filter calls, its mesh
set-up reported apart. Each is run ``--repeat`` times and the fastest run is reported
(the median too): on a shared 2-core machine other processes inflate single runs by up
to 2x. The points come in face order, spatially coherent like a scan's scan lines
(``--shuffle`` for random order, which slows both tools). Prints seconds, seconds per
million points and the ratio (target: treesim at least 5x faster), plus the agreement
of the two results.

Usage: ``python benchmarks/bench_compare.py [--points N] [--repeat R] [--shuffle]``.
Prints measured figures only.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from treesim.cloud import Cloud  # noqa: E402
from treesim.compare import CompareParams, compare  # noqa: E402
from treesim.geometry import sample_surface  # noqa: E402
from treesim.models import cylinders_to_mesh, read_cylinders  # noqa: E402

SAMPLE = ROOT / "pipeline" / "data" / "coffee_tree" / "QSM_treeqsm_v2.4.1_cylinders.csv"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000, help="cloud points (default 1e6)")
    ap.add_argument("--facets", type=int, default=24, help="facets per cylinder ring")
    ap.add_argument("--threads", type=int, default=0, help="threads (0: all cores)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each tool (default 3)")
    ap.add_argument("--shuffle", action="store_true", help="points in random order")
    args = ap.parse_args()
    n = args.points
    reps = max(1, args.repeat)

    v, f = cylinders_to_mesh(read_cylinders(SAMPLE), facets=args.facets)
    pts, _ = sample_surface(v, f, n, seed=1)
    pts += np.random.default_rng(2).normal(scale=0.002, size=pts.shape)
    if args.shuffle:
        pts = pts[np.random.default_rng(3).permutation(n)]
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    area_m2 = float(area.sum())
    print(
        f"data: coffee tree mesh, {len(f):,} triangles ({args.facets} facets), {area_m2:.3f} m²; "
        f"{n:,} points on it with 2 mm noise, {'random' if args.shuffle else 'face'} order; "
        f"{os.cpu_count()} cores; best of {reps} runs"
    )

    # -- treesim --------------------------------------------------------------------
    params = CompareParams(
        sample_spacing_m=math.sqrt(area_m2 / n), max_samples=n, nthreads=args.threads
    )
    runs = []
    for _ in range(reps):
        t0 = time.perf_counter()
        res = compare(Cloud(pts), (v, f), params=params)
        runs.append((time.perf_counter() - t0, res.timings_s))
    t_treesim, tm = min(runs, key=lambda r: r[0])
    med = float(np.median([r[0] for r in runs]))
    t_acc = tm["accuracy"]
    t_comp = tm["sampling"] + tm["completeness"]
    print(
        f"treesim  compare(): {t_treesim:6.2f} s for both directions (median {med:.2f} s; "
        f"{res.completeness.n:,} surface samples)"
    )
    print(
        f"         accuracy {t_acc:5.2f} s ({t_acc / n * 1e6:.2f} s per million points); "
        f"completeness {t_comp:5.2f} s incl. sampling; cloud index + spacing "
        f"{tm['cloud_index']:5.2f} s"
    )

    # -- pymeshlab -------------------------------------------------------------------
    import pymeshlab

    t0 = time.perf_counter()
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=pts))  # id 0: the cloud, vertices only
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=v, face_matrix=f))  # id 1: the mesh
    t_setup = time.perf_counter() - t0
    big = pymeshlab.PureValue(1e3)  # the default (50 % of the diagonal) drops far points
    pm_runs = []
    for _ in range(reps):
        t0 = time.perf_counter()
        acc = ms.get_hausdorff_distance(
            sampledmesh=0, targetmesh=1, samplevert=True, sampleface=False, samplenum=n, maxdist=big
        )
        t1 = time.perf_counter()
        comp = ms.get_hausdorff_distance(
            sampledmesh=1, targetmesh=0, samplevert=False, sampleface=True, samplenum=n, maxdist=big
        )
        t2 = time.perf_counter()
        pm_runs.append((t2 - t0, t1 - t0, t2 - t1))
    t_pm, t_pm_acc, t_pm_comp = min(pm_runs)
    pm_med = float(np.median([r[0] for r in pm_runs]))
    print(
        f"pymeshlab Hausdorff: {t_pm:6.2f} s for both directions (median {pm_med:.2f} s; mesh "
        f"set-up {t_setup:.2f} s not counted)"
    )
    print(
        f"         accuracy {t_pm_acc:5.2f} s ({t_pm_acc / n * 1e6:.2f} s per million points); "
        f"completeness {t_pm_comp:5.2f} s ({comp['n_samples']:,} samples)"
    )

    # -- ratio and agreement ---------------------------------------------------------
    print(
        f"ratio: treesim is {t_pm / t_treesim:.1f}x faster (pymeshlab time / treesim time, "
        f"fastest runs; {pm_med / med:.1f}x on the medians)"
    )
    print(
        f"         accuracy alone: {t_pm_acc / t_acc:.1f}x; completeness alone: "
        f"{t_pm_comp / t_comp:.1f}x"
    )
    a = res.accuracy
    print(
        "agreement, accuracy (mm): "
        f"mean {a.mean_m * 1e3:.6f} vs {acc['mean'] * 1e3:.6f}, "
        f"max {a.max_m * 1e3:.6f} vs {acc['max'] * 1e3:.6f}, "
        f"RMS {a.rms_m * 1e3:.6f} vs {acc['RMS'] * 1e3:.6f} (treesim vs pymeshlab, "
        f"{acc['n_samples']:,} points)"
    )
    c = res.completeness
    print(
        "agreement, completeness (mm, different random samples): "
        f"mean {c.mean_m * 1e3:.4f} vs {comp['mean'] * 1e3:.4f}, "
        f"max {c.max_m * 1e3:.4f} vs {comp['max'] * 1e3:.4f}"
    )


if __name__ == "__main__":
    main()
