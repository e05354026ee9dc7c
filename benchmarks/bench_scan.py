"""Scan throughput and memory: treesim's pipeline against raw Open3D casting.

Measures, in one run on a ~100k-triangle tree (the bundled coffee tree's TreeQSM model
meshed at 24 facets per ring):

1. ``pipeline.scan`` (what ``treesim scan`` runs) at 0.02°, three stations: rays/s, points/s;
2. raw ``RaycastingScene.cast_rays`` on exactly the same rays (the windowed pulses from
   the same stations, float32, near the origin), in the same chunk size: rays/s;
3. the ratio (target: the pipeline keeps >= 70 % of the raw rate);
4. the whole-field-of-view cast for comparison (rays it would cast, and its time at a
   coarser resolution so it stays short);
5. peak memory (max RSS of a fresh process) of a three-station scan at 0.005°
   (target: < 2 GiB), and of ``treesim scan`` end to end at that resolution.

Usage: ``python benchmarks/bench_scan.py [--quick]``. Prints measured figures only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.models import cylinders_to_mesh, read_cylinders  # noqa: E402
from pipeline.scan import ScannerSpec, ring_layout, scan  # noqa: E402
from pipeline.scan.rays import box_window, directions, pulse_angles, windowed_grid  # noqa: E402
from pipeline.scene import MeshPart, Scene  # noqa: E402

SAMPLE = ROOT / "pipeline" / "data" / "coffee_tree" / "QSM_treeqsm_v2.4.1_cylinders.csv"


def tree_scene(facets: int = 24) -> Scene:
    v, f = cylinders_to_mesh(read_cylinders(SAMPLE), facets=facets)
    return Scene([MeshPart(vertices=v, faces=f, label="wood", name="coffee")])


def stations_for(scene: Scene):
    lo, hi = scene.bounds
    return ring_layout(
        3,
        distance_m=10.0,
        height_m=1.5,
        centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
        base_z_m=lo[2],
    )


def raw_cast(scene: Scene, stations, spec: ScannerSpec, chunk: int) -> tuple[int, float, int]:
    """Cast the pipeline's windowed pulses with bare Open3D; returns (rays, seconds, hits)."""
    import open3d as o3d

    origin = 0.5 * (scene.bounds[0] + scene.bounds[1])
    v = scene.vertices - origin
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(
        o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(scene.faces.astype(np.uint32))
    )
    rc.cast_rays(o3d.core.Tensor(np.array([[0, 0, 0, 0, 0, 1]], np.float32)))  # build BVH
    total, hits, elapsed = 0, 0, 0.0
    for k, st in enumerate(stations):
        o = st.position - origin
        rel = (v - o) @ st.rotation
        grid = windowed_grid(spec, box_window(rel.min(axis=0), rel.max(axis=0)))
        for a in range(0, grid.n_pulses, chunk):
            lines, cols = grid.indices(a, min(grid.n_pulses, a + chunk))
            az, el = pulse_angles(spec, k, lines, cols)
            d = directions(az, el) @ st.rotation.T
            rays = np.empty((len(d), 6), np.float32)
            rays[:, :3] = o
            rays[:, 3:] = d
            t = o3d.core.Tensor(rays)
            t0 = time.perf_counter()
            ans = rc.cast_rays(t)
            elapsed += time.perf_counter() - t0
            hits += int(np.isfinite(ans["t_hit"].numpy()).sum())
            total += len(d)
    return total, elapsed, hits


#: Appended to a child's code: print the child's own peak resident memory (VmHWM, KiB) as
#: its last line. Not ``getrusage(RUSAGE_CHILDREN)`` in the parent: Linux carries the
#: parent's ``ru_maxrss`` (which holds the mesh already) into a child across fork and exec.
_PRINT_PEAK = (
    "\nimport pathlib\n"
    "print('VmHWM', [l.split()[1] for l in pathlib.Path('/proc/self/status').read_text()"
    ".splitlines() if l.startswith('VmHWM:')][0])\n"
)


def peak_rss_of(code: str) -> tuple[float, str]:
    """Run ``code`` in a fresh interpreter (it loads what it needs itself); return its own
    peak RSS in GiB and its other output."""
    out = subprocess.run(
        [sys.executable, "-c", code + _PRINT_PEAK],
        capture_output=True,
        text=True,
        cwd=str(ROOT),
        check=True,
    )
    lines = out.stdout.strip().splitlines()
    assert lines[-1].startswith("VmHWM "), out.stdout + out.stderr
    return int(lines[-1].split()[1]) / 2**20, "\n".join(lines[:-1]).strip()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="coarser settings, for a smoke run")
    args = ap.parse_args()
    res = 0.05 if args.quick else 0.02
    fine = 0.02 if args.quick else 0.005
    print(f"machine: {os.cpu_count()} cores; python {sys.version.split()[0]}")
    t0 = time.perf_counter()
    scene = tree_scene()
    print(
        f"tree: coffee TreeQSM mesh, {scene.n_triangles:,} triangles "
        f"(built in {time.perf_counter() - t0:.2f} s)"
    )
    stations = stations_for(scene)
    spec = ScannerSpec(horizontal_resolution_deg=res, vertical_resolution_deg=res)
    chunk = 1 << 19

    scan(
        scene, stations[:1], spec.with_(horizontal_resolution_deg=1.0, vertical_resolution_deg=1.0)
    )  # warm imports
    best = None
    for _ in range(2):
        t0 = time.perf_counter()
        r = scan(scene, stations, spec, chunk_rays=chunk)
        wall = time.perf_counter() - t0
        best = (wall, r) if best is None or wall < best[0] else best
    wall, r = best
    cast_s = wall - r.bvh_build_s
    raw_best = None
    for _ in range(2):
        rays, raw_s, raw_hits = raw_cast(scene, stations, spec, chunk)
        raw_best = raw_s if raw_best is None else min(raw_best, raw_s)
    print(f"\n== scan at {res}° from 3 stations (10 m, 1.5 m high), best of 2")
    print(
        f"pipeline.scan: {r.rays_cast:,} rays, {len(r.cloud):,} points, {wall:.2f} s "
        f"(BVH build {r.bvh_build_s:.2f} s)"
    )
    print(
        f"  throughput: {r.rays_cast / cast_s / 1e6:.2f} M rays/s, "
        f"{len(r.cloud) / cast_s / 1e6:.2f} M points/s (excluding BVH build)"
    )
    print(
        f"raw cast_rays on the same rays: {rays:,} rays, {raw_hits:,} hits, {raw_best:.2f} s, "
        f"{rays / raw_best / 1e6:.2f} M rays/s"
    )
    print(f"ratio pipeline / raw rate: {raw_best / cast_s:.2f} (target >= 0.70)")
    print(
        f"full field of view would cast {r.rays_full_fov:,} rays "
        f"({r.rays_full_fov / r.rays_cast:.0f}x the windowed count)"
    )
    coarse = spec.with_(horizontal_resolution_deg=0.1, vertical_resolution_deg=0.1)
    t0 = time.perf_counter()
    rf = scan(scene, stations, coarse, window=False)
    tf = time.perf_counter() - t0
    t0 = time.perf_counter()
    rw = scan(scene, stations, coarse, window=True)
    tw = time.perf_counter() - t0
    print(
        f"at 0.1°: full FOV {rf.rays_cast:,} rays {tf:.2f} s vs window {rw.rays_cast:,} rays "
        f"{tw:.2f} s (same points: {len(rf.cloud) == len(rw.cloud)})"
    )

    print(f"\n== peak memory at {fine}° (3 stations), fresh process each")
    code = (
        "import time, sys; sys.path.insert(0, '.');"
        "from benchmarks.bench_scan import tree_scene, stations_for;"
        "from pipeline.scan import ScannerSpec, scan;"
        "s = tree_scene(); t = time.perf_counter();"
        f"r = scan(s, stations_for(s), ScannerSpec(horizontal_resolution_deg={fine}, "
        f"vertical_resolution_deg={fine}));"
        "print(r.rays_cast, len(r.cloud), round(time.perf_counter() - t, 2))"
    )
    rss, out = peak_rss_of(code)
    n_rays, n_pts, secs = out.split()
    print(
        f"pipeline.scan: {int(n_rays):,} rays, {int(n_pts):,} points in {secs} s; "
        f"peak RSS {rss:.2f} GiB (target < 2 GiB; unchunked would need "
        f"~{int(n_rays) * 200 / 2**30:.1f} GiB for rays alone)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        from pipeline.io.mesh import write_mesh

        mesh = write_mesh(Path(tmp) / "tree.ply", scene.vertices, scene.faces)
        argv = ["treesim", "scan", str(mesh), "-o", str(Path(tmp) / "scan.laz")]
        argv += ["--resolution-deg", str(fine)]
        # the CLI in a fresh interpreter that loads the mesh itself, then reports its peak
        code = (
            "import runpy, sys\n"
            f"sys.argv = {argv!r}\n"
            "try:\n"
            "    runpy.run_module('pipeline.cli', run_name='__main__')\n"
            "except SystemExit as e:\n"
            "    assert not e.code, e.code\n"
        )
        t0 = time.perf_counter()
        cli_rss, _ = peak_rss_of(code)
        cli_s = time.perf_counter() - t0
        summary = json.loads((Path(tmp) / "scan.json").read_text())
        print(
            f"treesim scan (CLI, incl. start-up, load, LAZ write): {cli_s:.1f} s, "
            f"{summary['points']:,} points; peak RSS {cli_rss:.2f} GiB"
        )


if __name__ == "__main__":
    main()
