"""Hidden surface and closed junctions, measured on the bundled coffee tree.

The loop of ``treesim demo`` (the ``standard`` preset: the bundled field cloud
reconstructed, the QSM meshed with per-cylinder facets for the scan, three stations,
compared with the scanned mesh), once for each way of meshing the QSM:

* ``separate``: a closed frustum per cylinder (treesim before issue #13): end caps buried
  in the next cylinder, notches at bends and junctions;
* ``tubes``: :func:`treesim.models.branch_tubes`, one closed mitred tube per branch,
  each branch's start sunk into its parent (what ``reconstruct`` and ``run`` mesh now).

Each scanned cloud is compared with its mesh keeping every bit of surface
(``--hidden-surface keep``) and leaving out the surface inside other closed parts
(``drop``, the default now). Prints per mesh: area, triangles, closed parts, the share
of area inside other parts, coverage and completeness p95 both ways, and the time of the
hidden-surface test. The figures on the manual's validation page (docs/validation.md) come
from this script (``--docs`` writes them there).

Usage: ``python benchmarks/bench_hidden.py [--preset standard]``. Prints measured figures
only.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from treesim.cloud import LABEL_CODES  # noqa: E402
from treesim.compare import compare  # noqa: E402
from treesim.io import read_cloud  # noqa: E402
from treesim.models import (  # noqa: E402
    branch_tubes,
    cylinders_to_mesh,
    sink_branches,
    tubes_to_mesh,
)
from treesim.params import run_preset  # noqa: E402
from treesim.reconstruct import reconstruct  # noqa: E402
from treesim.run import lod_plan  # noqa: E402
from treesim.scan import stations_for  # noqa: E402
from treesim.scene import Scene  # noqa: E402
from treesim.steps import scan_scene  # noqa: E402

CLOUD = ROOT / "pipeline" / "data" / "coffee_tree" / "cloud.txt"


def _area(v: np.ndarray, f: np.ndarray) -> float:
    t = v[f]
    return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


def _mesh(table, facets, how: str) -> tuple[np.ndarray, np.ndarray]:
    if how == "separate":
        return cylinders_to_mesh(table, facets=facets)
    tubes, _ = branch_tubes(table, facets=facets)
    return tubes.vertices, tubes.faces


def _scan_mesh(table, facets: int, how: str, stations, spec) -> tuple[np.ndarray, np.ndarray]:
    """The mesh the run scans (lod auto): facets per row from the projected size."""
    rows = table if how == "separate" else sink_branches(table).table
    plan = lod_plan(rows, stations, spec, facets)
    if how == "separate":
        return cylinders_to_mesh(rows, facets=plan.facets)
    tubes = tubes_to_mesh(rows, facets=plan.facets)
    return tubes.vertices, tubes.faces


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="standard", help="run preset (default standard)")
    ap.add_argument("--threads", type=int, default=0, help="threads (0: all cores)")
    args = ap.parse_args()
    params = run_preset(args.preset)
    threads = args.threads or (os.cpu_count() or 1)
    field = read_cloud(CLOUD)
    rp = replace(params.reconstruct, prepare=replace(params.reconstruct.prepare, threads=threads))
    model = reconstruct(field, rp)
    table, facets = model.cylinders, int(rp.facets)
    sp = params.scan
    print(
        f"# {time.strftime('%Y-%m-%d')}, {platform.machine()} {os.cpu_count()} cores, "
        f"Python {platform.python_version()}; coffee tree, preset {args.preset}, "
        f"{table.n_cylinders} cylinders, {facets} facets"
    )
    print(
        "mesh      | model mesh: area m², triangles | scanned mesh: triangles, closed parts, "
        "hidden area | points | keep: coverage, p95 | drop: coverage, p95 | hidden test"
    )
    for how in ("separate", "tubes"):
        v, f = _mesh(table, facets, how)
        scene = Scene.from_labelled_mesh(v, f, np.full(len(f), LABEL_CODES["wood"], np.uint8))
        stations, _ = stations_for(scene.bounds, sp)
        sv, sf = _scan_mesh(table, facets, how, stations, sp.scanner)
        lod_scene = Scene.from_labelled_mesh(
            sv, sf, np.full(len(sf), LABEL_CODES["wood"], np.uint8)
        )
        cloud = scan_scene(lod_scene, stations, sp, threads=threads).cloud
        cp = replace(params.compare, nthreads=threads)
        keep = compare(cloud, lod_scene, params=replace(cp, hidden_surface="keep"))
        drop = compare(cloud, lod_scene, params=cp)
        hid = drop.reference_info["hidden_surface"]
        print(
            f"{how:9s} | {_area(v, f):.3f} m², {len(f):,} | {len(sf):,}, {hid['closed_parts']} "
            f"of {hid['parts']}, {100 * hid['area_share']:.1f} % | {len(cloud):,} | "
            f"{100 * keep.coverage:.1f} %, {1e3 * keep.completeness.p95_m:.2f} mm | "
            f"{100 * drop.coverage:.1f} %, {1e3 * drop.completeness.p95_m:.2f} mm | "
            f"{drop.timings_s['hidden_surface']:.2f} s ({hid['samples_drawn']:,} samples)"
        )


if __name__ == "__main__":
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("bench-hidden"), "bench_hidden.py"):
        main()
