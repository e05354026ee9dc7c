"""Tree models: generation time, triangle counts and mesh volume error per facet count.

Measures, for every species preset (seed 0, the preset's default leaves):

1. generation time of the cylinder table and leaves (median of ``--repeat`` runs);
2. for 8, 16 and 32 facets per ring: the time to mesh the wood as mitred tubes, the wood
   and leaf triangle counts, and the wood mesh's enclosed volume against the table's
   analytic (frustum) volume, next to the part the inscribed polygon alone explains,
   (n / 2 pi) sin(2 pi / n) - 1, and the rest in parts per million (what the mitred
   joints of the tapering frusta add);
3. the bundled coffee tree's TreeQSM table meshed both ways (separate prisms, mitred
   tubes) at the same facet counts.

Usage: ``python benchmarks/bench_models.py [--repeat N] [--facets 8,16,32]``. Prints
measured figures only.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.models import (  # noqa: E402
    SPECIES,
    cylinders_to_mesh,
    generate_tree,
    mesh_volume,
    read_cylinders,
    tubes_to_mesh,
)

SAMPLE = ROOT / "pipeline" / "data" / "coffee_tree" / "QSM_treeqsm_v2.4.1_cylinders.csv"


def timed(fn, repeat: int):
    """(median seconds, last result) of ``repeat`` calls."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def prism_error(facets: int) -> float:
    return facets * math.sin(2 * math.pi / facets) / (2 * math.pi) - 1.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing (median)")
    ap.add_argument("--facets", default="8,16,32", help="facet counts, comma-separated")
    args = ap.parse_args()
    facet_counts = [int(f) for f in args.facets.split(",")]
    print(f"# tree models on {platform.machine()} ({platform.python_version()}), seed 0")
    print()
    print(
        f"{'species':13} {'gen s':>6} {'cyl':>6} {'leaves':>7} {'facets':>6} {'mesh s':>7} "
        f"{'wood tris':>10} {'leaf tris':>10} {'vol error':>10} {'polygon':>9} {'rest ppm':>9}"
    )
    for name in SPECIES:
        gen_s, tree = timed(lambda n=name: generate_tree(n, seed=0), args.repeat)
        table = tree.cylinders
        for facets in facet_counts:
            mesh_s, wood = timed(lambda t=table, f=facets: tubes_to_mesh(t, facets=f), args.repeat)
            err = mesh_volume(wood.vertices, wood.faces) / table.total_volume_m3 - 1.0
            print(
                f"{name:13} {gen_s:6.3f} {table.n_cylinders:6,} {tree.n_leaves:7,} {facets:6} "
                f"{mesh_s:7.3f} {wood.n_triangles:10,} {len(tree.leaf_faces):10,} "
                f"{err * 100:+9.3f}% {prism_error(facets) * 100:+8.3f}% "
                f"{(err - prism_error(facets)) * 1e6:+9.1f}"
            )
    print()
    table = read_cylinders(SAMPLE)
    print(
        f"coffee tree (TreeQSM, {table.n_cylinders:,} cylinders): separate prisms vs mitred tubes"
    )
    print(
        f"{'joints':9} {'facets':>6} {'mesh s':>7} {'triangles':>10} {'pieces':>7} "
        f"{'vol error':>10}"
    )
    for facets in facet_counts:
        for joints in ("separate", "miter"):
            mesh_s, (v, f) = timed(
                lambda j=joints, n=facets: cylinders_to_mesh(table, facets=n, joints=j),
                args.repeat,
            )
            pieces = (
                tubes_to_mesh(table, facets=facets).n_tubes
                if joints == "miter"
                else table.n_cylinders
            )
            err = mesh_volume(v, f) / table.total_volume_m3 - 1.0
            print(
                f"{joints:9} {facets:6} {mesh_s:7.3f} {len(f):10,} {pieces:7,} {err * 100:+9.3f}%"
            )


if __name__ == "__main__":
    main()
