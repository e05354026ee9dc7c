"""Cost and accuracy of the ``draft``, ``standard`` and ``fine`` presets of ``treesim run``.

Each preset runs the whole loop (``pipeline.run_tree``) in a fresh process on

* ``coffee``: the bundled Kentucky coffee tree (14,667 points, 3.7 m; no truth; TreeQSM's
  model of it gives DBH 7.35 cm and 21.6 L, a peer reference);
* ``sapling``: the procedural ``sapling`` preset (DBH 3.1 cm, 4.2 m, 3.0 L of wood, exact
  truth), scanned as a field cloud from three stations 4 m out at 0.02° with 2 mm range
  noise (written once, reused by every preset).

Printed per run: wall time of the loop and its stages (imports and the first use of the
lazily imported libraries, open3d and matplotlib, are done before the timed region), peak
memory of the process, the reconstruction's DBH and volume (and their errors against the truth for
the sapling), and the simulated scan against the mesh (coverage) and against the field
cloud (accuracy p95, coverage). Measured figures only.

Usage: ``python benchmarks/bench_presets.py [--presets draft,standard,fine] [--write]``;
``--write`` also writes the measured table to ``pipeline/data/preset_measurements.txt``
(the text ``treesim run --help`` prints).
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
MEASUREMENTS = ROOT / "pipeline" / "data" / "preset_measurements.txt"


def machine() -> str:
    """CPU model, cores, Python and open3d versions, for the table's heading."""
    import open3d

    from pipeline._system import cpu_count

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f"{cpu} ({platform.machine()}), {cpu_count()} cores, "
        f"Python {platform.python_version()}, open3d {open3d.__version__}"
    )


def settings_rows(names: list[str]) -> list[str]:
    """What each preset sets, from the presets themselves."""
    import math

    from pipeline.params import run_preset as preset

    rows = ["  preset    scan step  facets  mesh volume vs cylinders  voxel  mesh samples"]
    for name in names:
        p = preset(name)
        n = p.reconstruct.facets
        held = (n / (2 * math.pi)) * math.sin(2 * math.pi / n) - 1
        vol = f"{held * 100:.2g} %"
        samples = p.compare.max_samples
        samples_txt = f"{samples // 1_000_000}M" if samples >= 1_000_000 else f"{samples // 1000}k"
        rows.append(
            f"  {name:9} {p.scan.scanner.horizontal_resolution_deg:.2f} deg   {n:<7} "
            f"{vol:<25} {p.reconstruct.prepare.voxel_size_m * 1000:>2.0f} mm  <= {samples_txt}"
        )
    return rows


def table_text(names: list[str], results: dict, truth: dict, n_sapling: int) -> str:
    """The measurements in the layout of ``treesim run --help``'s preset table."""
    lines = [
        f"Presets: what they set, and their cost and accuracy as measured on "
        f"{time.strftime('%Y-%m-%d')} with",
        f"benchmarks/bench_presets.py ({machine()};",
        "one tree per process; time of the whole loop with its reports, imports and the first",
        "use of open3d and matplotlib excluded; 'p95 sim->field': 95 % of the simulated points",
        "lie this close to the field cloud):",
        "",
        *settings_rows(names),
        "",
        "  bundled coffee tree (14,667 points, 3.7 m; no truth):",
        "  preset    time    peak mem  simulated points  p95 sim->field  wood volume",
    ]
    for name in names:
        r = results[("coffee", name)]
        lines.append(
            f"  {name:9} {r['timings_s']['total']:4.1f} s  {r['peak_rss_mb']:4.0f} MB   "
            f"{r['scan_points']:>9,}            {r['vs_field_p95_m'] * 1000:4.1f} mm        "
            f"{r['volume_total_m3'] * 1000:4.1f} L"
        )
    lines += [
        "",
        f"  procedural sapling (truth: DBH {truth['dbh_m'] * 100:.2f} cm, "
        f"{truth['volume_total_m3'] * 1000:.2f} L) scanned at 0.02 deg, 2 mm noise",
        f"  ({n_sapling:,} points):",
        "  preset    time    peak mem  simulated points  p95 sim->field  DBH error  volume error",
    ]
    for name in names:
        r = results[("sapling", name)]
        ddbh = (r["dbh_m"] - truth["dbh_m"]) * 1000
        dvol = (r["volume_total_m3"] / truth["volume_total_m3"] - 1) * 100
        lines.append(
            f"  {name:9} {r['timings_s']['total']:4.1f} s  {r['peak_rss_mb']:4.0f} MB   "
            f"{r['scan_points']:>9,}             {r['vs_field_p95_m'] * 1000:3.1f} mm       "
            f"{ddbh:+.1f} mm     {dvol:+.1f} %"
        )
    report = [r["timings_s"]["report"] / r["timings_s"]["total"] for r in results.values()]
    lines += [
        "",
        f"  Drawing the two reports' plots takes {min(report) * 100:.0f}-"
        f"{max(report) * 100:.0f} % of each run.",
        "",
    ]
    return "\n".join(lines)


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


def warm_up() -> None:
    """Import everything a run imports and use the lazily loaded libraries once, so the
    timed region holds the loop's own work only. (A run of the QSM method imports open3d
    and matplotlib lazily; pymeshlab only for the surface methods, so it is not loaded
    here: it would add its memory to the peak of runs that never use it.)"""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    import open3d as o3d

    import pipeline.compare
    import pipeline.io
    import pipeline.reconstruct
    import pipeline.report
    import pipeline.scan  # noqa: F401

    # first use: matplotlib's font cache and text layout, Open3D's raycasting module
    fig, ax = plt.subplots(figsize=(2, 2), dpi=50)
    ax.plot([0, 1], [0, 1])
    ax.set_title("warm-up")
    fig.savefig(io.BytesIO(), format="png")
    plt.close(fig)
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.geometry.TriangleMesh.create_box())
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    scene.cast_rays(o3d.core.Tensor(np.array([[0.5, 0.5, -1, 0, 0, 1]], dtype=np.float32)))


def one(preset_name: str, cloud: str, out: str) -> None:
    """Child process: run once, print a JSON line."""
    from pipeline.params import run_preset as preset
    from pipeline.run import run_tree

    warm_up()
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
    ap.add_argument(
        "--write",
        action="store_true",
        help=f"write the measured table to {MEASUREMENTS.relative_to(ROOT)}",
    )
    ap.add_argument("--one", nargs=3, metavar=("PRESET", "CLOUD", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        one(*args.one)
        return
    from pipeline._system import cpu_count

    names = args.presets.split(",")
    results: dict = {}
    t_bench = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        sapling = Path(tmp) / "sapling.ply"
        truth = make_sapling(sapling)
        print(f"# {time.strftime('%Y-%m-%d')}, {machine()} ({cpu_count()} usable)")
        from pipeline.io import read_cloud

        n_sapling = len(read_cloud(sapling))
        print(
            f"# sapling field cloud: {n_sapling:,} points; "
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
            for name in names:
                out = Path(tmp) / f"{tree}-{name}"
                proc = subprocess.run(
                    [sys.executable, __file__, "--one", name, str(cloud), str(out)],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                results[(tree, name)] = r
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
    text = table_text(names, results, truth, n_sapling)
    print()
    print(text)
    print(f"# benchmark wall time {time.perf_counter() - t_bench:.0f} s")
    if args.write:
        MEASUREMENTS.write_text(text, encoding="utf-8")
        print(f"# wrote {MEASUREMENTS}")


if __name__ == "__main__":
    main()
