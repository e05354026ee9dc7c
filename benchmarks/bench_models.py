"""Tree models: generation time, triangle counts and mesh volume error per facet count.

Measures, for every species preset (seed 0, the preset's default leaves):

1. generation time of the cylinder table and leaves (median of ``--repeat`` runs);
2. for 8, 16 and 32 facets per ring: the time to mesh the wood as mitred tubes, the wood
   and leaf triangle counts, and the wood mesh's enclosed volume against the table's
   analytic (frustum) volume, next to the part the inscribed polygon alone explains,
   (n / 2 pi) sin(2 pi / n) - 1, and the rest in parts per million (what the mitred
   joints of the tapering frusta add);
3. the bundled coffee tree's TreeQSM table meshed both ways (separate prisms, mitred
   tubes) at the same facet counts;
4. level of detail (:mod:`treesim.models.lod`) for the coffee tree seen from a ring of
   four stations at ``--lod-distance-m`` (10 m) with a ``--lod-step-deg`` (0.04 degree)
   scanner, against the largest of ``--facets``: planning time, mesh time and triangles
   with and without LOD, the facets chosen, the ratio of the meshes' inscribed-prism
   volumes, and the largest distance from the LOD mesh to the uniform one (200 000
   sampled points), in mm and over the rule's bound (tolerance x the point spacing at
   the sampled point's cylinder).

Usage: ``python benchmarks/bench_models.py [--repeat N] [--facets 8,16,32]
[--lod-distance-m 10] [--lod-step-deg 0.04]``. Prints measured figures only.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from treesim.geometry.sampling import sample_surface  # noqa: E402
from treesim.geometry.triangles import point_to_mesh_distances  # noqa: E402
from treesim.models import (  # noqa: E402
    SPECIES,
    cylinders_to_mesh,
    generate_tree,
    mesh_volume,
    plan_lod,
    read_cylinders,
    tubes_to_mesh,
)
from treesim.scan.stations import ring_around  # noqa: E402

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
    ap.add_argument("--lod-distance-m", type=float, default=10.0, help="station ring radius")
    ap.add_argument("--lod-step-deg", type=float, default=0.04, help="scanner angular step")
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
    print()
    bench_lod(table, max(facet_counts), args)


def bench_lod(table, max_facets: int, args: argparse.Namespace) -> None:
    """Level of detail for ``table`` from four stations: section 4 of the module notes."""
    lo = np.minimum(table.start, table.end).min(axis=0)
    hi = np.maximum(table.start, table.end).max(axis=0)
    ring = ring_around(np.array([lo, hi]), 4, distance_m=args.lod_distance_m, height_m=1.5)
    stations = np.array([s.position_m for s in ring])
    step = math.radians(args.lod_step_deg)
    plan_s, plan = timed(
        lambda: plan_lod(table, stations, step, max_facets=max_facets), args.repeat
    )
    print(
        f"coffee tree, level of detail: 4 stations at {args.lod_distance_m:g} m, "
        f"{args.lod_step_deg:g} deg step, max {max_facets} facets, tolerance "
        f"{plan.tolerance:g} x spacing; plan {plan_s * 1e3:.1f} ms; nearest-station distance "
        f"{plan.distance_m.min():.2f}-{plan.distance_m.max():.2f} m, spacing "
        f"{plan.spacing_m.min() * 1e3:.2f}-{plan.spacing_m.max() * 1e3:.2f} mm"
    )
    print(
        f"{'joints':9} {'mesh s':>7} {'lod s':>7} {'triangles':>10} {'lod tris':>10} "
        f"{'saved':>7} {'vol ratio':>9} {'max d mm':>9} {'d/bound':>8}  facets meshed"
    )
    for joints in ("separate", "miter"):
        mesh_s, (v, f) = timed(
            lambda j=joints: cylinders_to_mesh(table, facets=max_facets, joints=j), args.repeat
        )
        lod_s, (lv, lf) = timed(
            lambda j=joints: cylinders_to_mesh(table, facets=plan.facets, joints=j), args.repeat
        )
        about = plan.describe(joints=joints)
        origin = lv.min(axis=0)
        pts, tri = sample_surface(lv - origin, lf, 200_000, seed=0)
        d = point_to_mesh_distances(pts, v - origin, f, nthreads=0)
        if joints == "miter":
            row = tubes_to_mesh(table, facets=plan.facets).face_cylinder[tri]
        else:
            row = np.searchsorted(np.cumsum(4 * plan.facets), tri, side="right")
        ratio = float((d / (plan.tolerance * plan.spacing_m[row])).max())
        hist = " ".join(f"{k}:{c}" for k, c in about["meshed_facets_histogram"].items())
        print(
            f"{joints:9} {mesh_s:7.3f} {lod_s:7.3f} {len(f):10,} {len(lf):10,} "
            f"{1 - len(lf) / len(f):7.1%} {about['prism_volume_ratio']:9.4f} "
            f"{d.max() * 1e3:9.3f} {ratio:8.3f}  {hist}"
        )


if __name__ == "__main__":
    main()
