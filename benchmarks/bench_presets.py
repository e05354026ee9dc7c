"""Cost and accuracy of the ``draft``, ``standard`` and ``fine`` presets of ``treesim run``.

Each preset runs the whole loop (``pipeline.run_tree``) in a fresh process on

* ``coffee``: the bundled Kentucky coffee tree (14,667 points, 3.7 m; no truth; TreeQSM's
  model of it gives DBH 7.35 cm and 21.6 L, a peer reference);
* ``sapling``: the procedural ``sapling`` preset (DBH 3.1 cm, 4.2 m, 3.0 L of wood, exact
  truth), scanned as a field cloud from three stations 4 m out at 0.02° with 2 mm range
  noise (written once, reused by every preset).

Printed per run: wall time of the loop (imports excluded) and its stages, peak memory of
the process, the reconstruction's DBH and volume (and their errors against the truth for
the sapling), and the simulated scan against the mesh (coverage) and against the field
cloud (accuracy p95, coverage). Measured figures only.

Usage: ``python benchmarks/bench_presets.py [--presets draft,standard,fine]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COFFEE = ROOT / "pipeline" / "data" / "coffee_tree" / "cloud.txt"


def make_sapling(path: Path) -> dict:
    """Scan the sapling preset into ``path``; return its truth figures."""
    from pipeline.io import write_cloud
    from pipeline.models import generate_tree
    from pipeline.scan import ScannerSpec, ring_layout, scan
    from pipeline.scene import MeshPart, Scene

    tree = generate_tree("sapling", seed=0, leaves=False)
    v, f, _ = tree.mesh(32)
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood")])
    lo, hi = scene.bounds
    stations = ring_layout(
        3,
        distance_m=4.0,
        height_m=1.5,
        centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
        base_z_m=float(lo[2]),
    )
    spec = ScannerSpec(
        horizontal_resolution_deg=0.02, vertical_resolution_deg=0.02, range_noise_sd_m=0.002
    )
    write_cloud(path, scan(scene, stations, spec).cloud)
    return tree.truth(32)


def peak_rss_mb() -> float:
    """This process's peak resident memory. ``/proc/self/status`` VmHWM, not
    ``getrusage``: Linux carries a parent's ``ru_maxrss`` into a child across fork and
    exec, so a child of a big process would report the parent's peak."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def one(preset_name: str, cloud: str, out: str) -> None:
    """Child process: run once, print a JSON line."""
    from pipeline.params import run_preset as preset
    from pipeline.run import run_tree

    t0 = time.perf_counter()
    res = run_tree(cloud, preset(preset_name), out)
    wall = time.perf_counter() - t0
    s = res.summary
    print(
        json.dumps(
            {
                "wall_s": wall,
                "timings_s": s["timings_s"],
                "peak_rss_mb": peak_rss_mb(),
                "dbh_m": s["reconstruction"]["dbh_m"],
                "volume_total_m3": s["reconstruction"]["volume_total_m3"],
                "volume_stem_m3": s["reconstruction"]["volume_stem_m3"],
                "scan_points": s["scan"]["points"],
                "vs_mesh_coverage": s["vs_mesh"]["coverage"],
                "vs_field_p95_m": s["vs_field"]["accuracy"]["p95_m"],
                "vs_field_coverage": s["vs_field"]["coverage"],
                "vs_field_chamfer_m": s["vs_field"]["chamfer_m"],
            }
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="draft,standard,fine")
    ap.add_argument("--one", nargs=3, metavar=("PRESET", "CLOUD", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        one(*args.one)
        return
    from pipeline._system import cpu_count

    with tempfile.TemporaryDirectory() as tmp:
        sapling = Path(tmp) / "sapling.ply"
        truth = make_sapling(sapling)
        print(
            f"# {time.strftime('%Y-%m-%d')}, {platform.machine()} {cpu_count()} cores, "
            f"Python {platform.python_version()}"
        )
        from pipeline.io import read_cloud

        print(
            f"# sapling field cloud: {len(read_cloud(sapling)):,} points; "
            f"truth: DBH {truth['dbh_m'] * 100:.2f} cm, "
            f"volume {truth['volume_total_m3'] * 1000:.2f} L "
            f"(stem {truth['volume_stem_m3'] * 1000:.2f} L)"
        )
        head = (
            f"{'tree':8} {'preset':8} {'time s':>7} {'recon':>6} {'scan':>6} {'cmp':>6} "
            f"{'report':>6} {'MB':>6} {'points':>8} {'DBH cm':>7} {'vol L':>7} "
            f"{'dDBH mm':>8} {'dvol %':>7} {'cov mesh':>8} {'p95 fld mm':>10} {'cov fld':>7}"
        )
        print(head)
        for tree, cloud in (("coffee", COFFEE), ("sapling", sapling)):
            for name in args.presets.split(","):
                out = Path(tmp) / f"{tree}-{name}"
                proc = subprocess.run(
                    [sys.executable, __file__, "--one", name, str(cloud), str(out)],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                t = r["timings_s"]
                ddbh = dvol = "–"
                if tree == "sapling":
                    ddbh = f"{(r['dbh_m'] - truth['dbh_m']) * 1000:+.1f}"
                    dvol = f"{(r['volume_total_m3'] / truth['volume_total_m3'] - 1) * 100:+.1f}"
                print(
                    f"{tree:8} {name:8} {t['total']:7.1f} {t['reconstruct']:6.1f} "
                    f"{t['scan']:6.1f} {t['compare_mesh'] + t['compare_field']:6.1f} "
                    f"{t['report']:6.1f} {r['peak_rss_mb']:6.0f} {r['scan_points']:8,} "
                    f"{r['dbh_m'] * 100:7.2f} {r['volume_total_m3'] * 1000:7.2f} "
                    f"{ddbh:>8} {dvol:>7} {r['vs_mesh_coverage'] * 100:7.1f}% "
                    f"{r['vs_field_p95_m'] * 1000:10.1f} {r['vs_field_coverage'] * 100:6.1f}%",
                    flush=True,
                )


if __name__ == "__main__":
    main()
