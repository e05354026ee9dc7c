"""Leaf-on field clouds: wood/leaf separation and the QSM on a leaf-on scan (issue 13 §4).

Measures, on the ``aspen-leafon`` preset and its leaf-off twin (``aspen``; seed 0, which
the wood/leaf classifier was not fitted on), each scanned with the RIEGL VZ-400 noise
model from three stations at ``--step-deg`` degrees (default 0.08; 0.04 is the field
standard and costs about four times as much):

1. wood precision and recall of :func:`treesim.reconstruct.leafwood.separate_leaves`
   against the scanner's exact labels (points after 5 mm voxels), and its time;
2. the QSM's DBH error (mm), stem and total volume errors (%) against the generator's
   cylinder table for: the leaf-off scan, the leaf-on scan as it is
   (``--separate-leaves off``: leaves taken for twigs), the leaf-on scan separated
   (``on``); with the number of modelled leaves and their area beside the truth's.
3. On the real leaf-on Lille tree (``../shared/data/trees/adtree/Lille_2.xyz``, skipped
   when absent): circles fitted to its own stem slabs (the DBH the cloud shows), then
   DBH, volumes (and the volume in cylinders under 1 cm radius, where leaves taken for
   twigs go) and points per label with separation off and auto.

Usage: ``python benchmarks/bench_leaves.py [--step-deg 0.08] [--auto] [--lille-only]``
(``--auto``: only the table of what ``--separate-leaves auto`` reads on every preset and
real cloud, about 5 minutes; ``--lille-only``: only step 3, seconds). Prints measured
figures only; about 5 minutes at 0.08° and 10 at 0.04° on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.reconstruct.leafon import (  # noqa: E402
    labelled_voxels,
    scan_preset,
    slab_circle_diameter_m,
    wood_scores,
)
from treesim.cloud import LABEL_CODES, Cloud  # noqa: E402
from treesim.reconstruct import ReconstructParams, reconstruct  # noqa: E402
from treesim.reconstruct.leafwood import separate_leaves  # noqa: E402

TREES = Path(__file__).resolve().parents[2] / "shared" / "data" / "trees"
LILLE = TREES / "adtree" / "Lille_2.xyz"
#: Real clouds of ../shared/data/trees (PROVENANCE.md) and their condition.
REAL = (
    ("adtree/Lille_2.xyz", "leaf-on"),
    ("adtree/tree7.xyz", "leaf clumps in the top"),
    ("treels_pine/pine.laz", "needle-on crown"),
    ("coffee_tree/cloud.txt", "leaf-off"),
    ("archi_tree2/Tree_2_point_cloud.las", "leaf-off"),
)


def auto_table() -> None:
    """What ``--separate-leaves auto`` reads on each cloud: the classifier's leaf share
    (weighted; auto separates from LEAF_SHARE_CUT) and preparation's normal-spread
    ``leaf_fraction``, on the procedural presets (seed 0) at 0.04-0.12 deg and the
    real clouds."""
    from treesim.io import read_cloud
    from treesim.models import SPECIES
    from treesim.reconstruct._leaves import LEAF_SHARE_CUT, separate
    from treesim.reconstruct.preprocess import prepare

    def row(name: str, points: np.ndarray) -> None:
        p = prepare(points, normals=False)
        # what reconstruct's auto runs: the classifier, its weighted leaf share, the cut
        sep = separate(p, "auto")
        if sep is None:
            print(f"  {name:<44} too few points to classify ({len(p.points):,})")
            return
        share = sep.figures["leaf_share"]
        verdict = "separates" if sep.used else "off"
        print(
            f"  {name:<44} leaf share {share:.3f} ({verdict}, {sep.seconds:.1f} s)"
            f"  normal-spread leaf_fraction {p.leaf_fraction:.3f}",
            flush=True,
        )

    print(f"auto: separates from a leaf share of {LEAF_SHARE_CUT}")
    for name, params in SPECIES.items():
        for step in (0.04, 0.08, 0.12):
            _, cloud = scan_preset(name, step)
            cond = "leaf-on" if params.leaves_on else "leaf-off"
            row(f"{name} ({cond}) at {step} deg", cloud.points)
    for rel, cond in REAL:
        path = TREES / rel
        if path.is_file():
            row(f"{rel} ({cond})", read_cloud(path).points)
        else:
            print(f"  {rel}: skipped ({path} is absent)")


def qsm_row(label: str, points: np.ndarray, truth: dict, mode: str) -> None:
    t0 = time.perf_counter()
    fig = reconstruct(Cloud(points), ReconstructParams(separate_leaves=mode)).figures
    dt = time.perf_counter() - t0
    extra = ""
    if "n_leaves" in fig:
        extra = f", {fig['n_leaves']:,} leaves modelled ({fig['leaf_area_m2']:.1f} m²)"
    print(
        f"  {label:<28} DBH {(fig['dbh_m'] - truth['dbh_m']) * 1e3:+6.1f} mm  "
        f"stem {(fig['volume_stem_m3'] / truth['volume_stem_m3'] - 1) * 100:+6.1f} %  "
        f"total {(fig['volume_total_m3'] / truth['volume_total_m3'] - 1) * 100:+6.1f} %  "
        f"({dt:.0f} s{extra})",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--step-deg", "--step", dest="step", type=float, default=0.08, help="angular step (deg)"
    )
    ap.add_argument(
        "--auto", action="store_true", help="only the table of what auto reads on each cloud"
    )
    ap.add_argument("--lille-only", action="store_true", help="only the real Lille tree")
    args = ap.parse_args()
    print(
        f"bench_leaves ({date.today()}, {platform.processor() or platform.machine()}, "
        f"Python {platform.python_version()}); scans at {args.step} deg, VZ-400 noise, "
        "3 stations"
    )
    if args.auto:
        auto_table()
        return
    if not args.lille_only:
        procedural(args.step)
    lille()


def procedural(step: float) -> None:
    tree_on, on = scan_preset("aspen-leafon", step)
    tree_off, off = scan_preset("aspen", step)
    truth = tree_off.truth(32)
    pts, wood = labelled_voxels(on.points, on.fields["label"] == LABEL_CODES["wood"], 0.005)
    t0 = time.perf_counter()
    res = separate_leaves(pts)
    dt = time.perf_counter() - t0
    precision, recall = wood_scores(res.wood, wood)
    print(
        f"separation on aspen-leafon: {len(pts):,} points, wood precision "
        f"{precision:.3f}, recall {recall:.3f} ({dt:.1f} s, {os.cpu_count()} cores)"
    )
    print(f"QSM against the truth (leaf area of the truth: {tree_on.leaf_area_m2:.1f} m²):")
    qsm_row("aspen (leaf-off)", off.points, truth, "off")
    qsm_row("aspen-leafon, not separated", on.points, truth, "off")
    qsm_row("aspen-leafon, separated", on.points, truth, "on")


def lille() -> None:
    """Lille_2: its stem slab's own circles, then the QSM with separation off and auto."""
    if not LILLE.is_file():
        print(f"Lille: skipped ({LILLE} is absent)")
        return
    from treesim.io import read_cloud

    cloud = read_cloud(LILLE)
    heights = (0.5, 0.8, 1.0, 1.3, 1.6, 2.0, 2.4)
    circles = [slab_circle_diameter_m(cloud.points, h) * 100 for h in heights]
    print(
        "Lille_2 stem slabs (20 cm), circle diameter: "
        + ", ".join(f"{d:.1f} cm at {h} m" for h, d in zip(heights, circles, strict=True))
    )
    for mode in ("off", "auto"):
        model = reconstruct(cloud, ReconstructParams(separate_leaves=mode))
        fig, cyl = model.figures, model.cylinders
        thin = cyl.radius_m < 0.01
        twigs = float(np.sum(np.pi * cyl.radius_m[thin] ** 2 * cyl.length_m[thin]))
        labels = (
            f", {fig['points_wood']:,} wood / {fig['points_leaf']:,} leaf points"
            if "points_wood" in fig
            else ""
        )
        share = f", leaf share {fig['leaf_share']:.3f}" if "leaf_share" in fig else ""
        print(
            f"Lille_2, separation {mode}: DBH {fig['dbh_m'] * 100:.1f} cm, total "
            f"{fig['volume_total_m3']:.2f} m³ (stem {fig['volume_stem_m3']:.2f} m³, "
            f"under 1 cm radius {twigs:.2f} m³){labels}{share}"
        )


if __name__ == "__main__":
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("bench-leaves"), "bench_leaves.py"):
        main()
