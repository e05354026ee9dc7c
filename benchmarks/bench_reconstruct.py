"""Reconstruction cost and accuracy: QSM, screened Poisson and ball pivoting.

Measures, in one run (issue 5's Benchmark section):

1. **Real trees** (``../shared/data/trees/``; skipped with a note when absent): for each
   cloud and each method (``qsm``, ``poisson``, ``bpa``, default parameters), a fresh
   child process reads the cloud and runs ``reconstruct()``: read time, reconstruct time
   (preparation included), the child's wall time (start-up and imports included), peak
   memory (``ru_maxrss`` of the child itself, and of the pymeshlab worker it spawns for
   ``poisson``/``bpa``), and the figures (DBH, total volume, triangles, watertight).
2. **A ~100k-point tree end to end with qsm**: the ``aspen`` preset (leaf-off, 17 m) is
   scanned from three stations at the angular resolution that leaves about 100k points
   after preparation (calibrated from a coarse scan; the actual count is printed), then a
   fresh child runs ``reconstruct()`` on it. Target: ``qsm`` under 30 s for 100k points
   on 2 cores.
3. **The speed/accuracy curve** on the ``sapling`` preset (leaf-off, three stations,
   0.04°): ``qsm`` at 8, 16, 32 and 64 facets per ring and ``poisson`` at depths 6, 7, 8
   and 9 (``--quick``: 8 and 32 facets, depths 6 and 8): reconstruct time, triangles, and
   the reconstructed-vs-true-mesh AVOHD. Both directions are exact point-to-triangle
   distances from :func:`treesim.compare.compare`: *accuracy* samples the reconstructed
   surface (seeded, one sample per 2 mm², at most 400k) and measures each sample to the
   true mesh (the 32-facet generator mesh that was scanned); *completeness* samples the
   true mesh the same way and measures each sample to the reconstructed mesh. Hausdorff
   is the larger of the two maxima. For ``qsm`` also the error of the total volume
   (cylinder table, and the closed mesh's enclosed volume) against the generator's truth.

4. **Points scaling** (issue 13): the ``old-tupelo`` preset (leaf-off, 29.6 m) scanned
   with the RIEGL VZ-400's noise model (3 mm range noise, 0.0005° jitter) from three
   stations, at the angular resolutions that give about 100k, 500k, 1.5 M and 5 M points
   (``--quick``: 100k and 500k; 0.04° gives about 0.71 M, and the count goes with the
   inverse square of the step). Each size runs ``reconstruct()`` (qsm, default
   parameters) in a fresh child process: wall time, CPU time (user + system) and peak
   RSS (``ru_maxrss`` of the child), then the fitted log-log slope of each against the
   number of points (1: linear). Target: the 1.44 M-point cloud under 50 s and 1 GB.

Usage: ``python benchmarks/bench_reconstruct.py [--quick] [--sections ...]``
(``--quick``: two real trees, fewer settings and sizes; ``--sections scaling`` runs only
section 4). Prints measured figures and ratios only, and its own wall time at the end
(section 4 is the longest: the 5 M-point scan and reconstruction; a child running over
``CHILD_TIMEOUT_S`` is stopped and reported).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TREES = ROOT.parent / "shared" / "data" / "trees"
REAL = [
    "coffee_tree/cloud.txt",
    "adtree/tree7.xyz",
    "adtree/Lille_2.xyz",
    "archi_tree2/Tree_2_point_cloud.las",
    "treels_pine/pine.laz",
]
METHODS = ("qsm", "poisson", "bpa")
TARGET_POINTS = 100_000
SCALING_POINTS = (100_000, 500_000, 1_500_000, 5_000_000)
SCALING_POINTS_QUICK = (100_000, 500_000)
SCALING_PRESET = "old-tupelo"
SCALING_INSTRUMENT = "riegl-vz400"
SCALING_TARGET_S = 50.0
SCALING_TARGET_MIB = 1024.0
SECTIONS = ("real", "100k", "curve", "scaling")
#: A child still running after this is stopped and reported as timed out (s).
CHILD_TIMEOUT_S = 900.0
TARGET_QSM_S = 30.0
CURVE_RES_DEG = 0.04
SAMPLE_SPACING_M = 0.002
MAX_SAMPLES = 400_000


# -------------------------------------------------------------------------- helpers
def table(headers: list[str], rows: list[list[Any]]) -> None:
    """Print rows under headers, columns right-aligned (the first left-aligned)."""
    cells = [[str(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(headers)]

    def line(r: list[str]) -> str:
        pairs = enumerate(zip(r, widths, strict=True))
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in pairs)

    print(line(headers))
    print("  ".join("-" * w for w in widths))
    for r in cells:
        print(line(r))


def fmt(v: Any, scale: float = 1.0, digits: int = 2) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return "yes" if v else "no"
    return f"{v * scale:,.{digits}f}"


def preset_scene(name: str):
    """(tree, scene, stations) of a leaf-off preset, meshed at 32 facets."""
    from treesim.models import generate_tree
    from treesim.scan import ring_layout
    from treesim.scene import MeshPart, Scene

    tree = generate_tree(name, seed=0, leaves=False)
    v, f, _ = tree.mesh(32)
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood", name=name)])
    lo, hi = scene.bounds
    stations = ring_layout(
        3,
        distance_m=max(10.0, 0.5 * (hi[2] - lo[2])),
        height_m=1.5,
        centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
        base_z_m=lo[2],
    )
    return tree, scene, stations


def scan_points(scene, stations, res_deg: float) -> np.ndarray:
    from treesim.scan import ScannerSpec, scan

    spec = ScannerSpec(horizontal_resolution_deg=res_deg, vertical_resolution_deg=res_deg)
    return scan(scene, stations, spec).cloud.points


def prepared_count(points: np.ndarray) -> int:
    from treesim.cloud import Cloud
    from treesim.reconstruct import PrepareParams
    from treesim.reconstruct.preprocess import prepare

    return len(prepare(Cloud(points), PrepareParams()).points)


# ------------------------------------------------------------ the child process
def child(source: str, method: str, write_to: str = "") -> None:
    """Run in a fresh process: read ``source`` (a cloud file or .npy), reconstruct it,
    optionally write the outputs, and print one JSON line with timings, figures and the
    peak RSS of this process and of its (pymeshlab) children."""
    from treesim.reconstruct import ReconstructParams, reconstruct

    out: dict[str, Any] = {}
    try:
        t0 = time.perf_counter()
        if source.endswith(".npy"):
            cloud = np.load(source)
        else:
            from treesim.io import read_cloud

            cloud = read_cloud(source)
        out["read_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        model = reconstruct(cloud, ReconstructParams(method=method))
        out["reconstruct_s"] = time.perf_counter() - t0
        if write_to:
            t0 = time.perf_counter()
            model.write(write_to)
            out["write_s"] = time.perf_counter() - t0
        keys = ("dbh_m", "height_m", "volume_total_m3", "n_triangles", "watertight")
        keys += ("points_input", "points_used", "n_cylinders", "leaves_present")
        out["figures"] = {k: model.figures.get(k) for k in keys}
        out["timings_s"] = model.timings_s
    except Exception as e:  # reported in the table, not raised
        out["error"] = f"{type(e).__name__}: {e}"
    usage = resource.getrusage(resource.RUSAGE_SELF)
    out["cpu_s"] = usage.ru_utime + usage.ru_stime
    out["rss_self_mib"] = usage.ru_maxrss / 1024
    out["rss_children_mib"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(json.dumps(out, default=float))


def run_child(source: Path, method: str, write_to: Path | None = None) -> dict[str, Any]:
    code = (
        f"import sys; sys.path.insert(0, {str(ROOT)!r}); "
        "from benchmarks.bench_reconstruct import child; "
        f"child({str(source)!r}, {method!r}, {str(write_to or '')!r})"
    )
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            cwd=str(ROOT),
            timeout=CHILD_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired:  # reported in the table, the other sizes go on
        return {"error": f"timed out after {CHILD_TIMEOUT_S:.0f} s", "wall_s": CHILD_TIMEOUT_S}
    wall = time.perf_counter() - t0
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": f"child exited {proc.returncode}: {tail}", "wall_s": wall}
    res = json.loads(lines[-1])
    res["wall_s"] = wall
    return res


# ---------------------------------------------------------------------- sections
def real_trees(quick: bool) -> None:
    print("\n== 1. real trees: each method in a fresh child process (default parameters)")
    if not TREES.is_dir():
        print(f"skipped: {TREES} is absent (the shared data set is not mounted here)")
        return
    names = REAL[:2] if quick else REAL
    rows, errors = [], []
    for rel in names:
        path = TREES / rel
        if not path.is_file():
            print(f"skipped {rel}: not found")
            continue
        for method in METHODS:
            r = run_child(path, method)
            if "error" in r:
                rows.append([rel, method, *["-"] * 10, "error"])
                errors.append(f"{rel} {method}: {r['error']}")
                continue
            f = r["figures"]
            vol = f["volume_total_m3"]
            rows.append(
                [
                    rel,
                    method,
                    f"{f['points_input']:,}",
                    f"{f['points_used']:,}",
                    fmt(r["read_s"], digits=3),
                    fmt(r["reconstruct_s"]),
                    fmt(r["wall_s"]),
                    fmt(r["rss_self_mib"], digits=0),
                    fmt(r["rss_children_mib"], digits=0) if method != "qsm" else "-",
                    fmt(f["dbh_m"], 100),
                    fmt(vol, 1000, 1),
                    f"{f['n_triangles']:,}",
                    fmt(f["watertight"]),
                ]
            )
    table(
        [
            "cloud",
            "method",
            "points in",
            "points used",
            "read (s)",
            "reconstruct (s)",
            "child wall (s)",
            "peak RSS (MiB)",
            "worker RSS (MiB)",
            "DBH (cm)",
            "volume (L)",
            "triangles",
            "watertight",
        ],
        rows,
    )
    for e in errors:
        print(f"failed: {e}")
    print(
        "reconstruct (s) includes preparation; child wall adds interpreter start-up, imports "
        "and reading; worker RSS: the pymeshlab child process (poisson/bpa), whose ru_maxrss "
        "Linux floors at the parent's RSS when it was spawned (fork, then exec), so equal "
        "figures mean the worker stayed at or below its parent. Volume is given "
        "only for closed meshes (qsm: the cylinder table). Coffee tree, peer QSMs of the "
        "same cloud: TreeQSM 21.6 L and DBH 7.35 cm, SimpleForest 30.0 L."
    )


def hundred_k(quick: bool) -> None:
    print(f"\n== 2. ~{TARGET_POINTS // 1000}k-point tree end to end with qsm (aspen, leaf-off)")
    t0 = time.perf_counter()
    tree, scene, stations = preset_scene("aspen")
    coarse = 0.2
    n_coarse = prepared_count(scan_points(scene, stations, coarse))
    res = round(coarse * (n_coarse / TARGET_POINTS) ** 0.5, 4)
    t1 = time.perf_counter()
    pts = scan_points(scene, stations, res)
    scan_s = time.perf_counter() - t1
    print(
        f"aspen: {scene.n_triangles:,} triangles, height {tree.truth(32)['height_m']:.1f} m; "
        f"calibration: {n_coarse:,} prepared points at {coarse}° -> {res}°; scan at {res}° "
        f"from 3 stations: {len(pts):,} points in {scan_s:.1f} s "
        f"(setup and calibration {t1 - t0:.1f} s)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "aspen.npy"
        np.save(src, pts)
        r = run_child(src, "qsm", Path(tmp) / "out")
    if "error" in r:
        print(f"qsm failed: {r['error']}")
        return
    f, ts = r["figures"], r["timings_s"]
    fit_s = ts["reconstruct"] - ts.get("mesh", 0.0)
    print(
        f"prepared cloud: {f['points_used']:,} points (of {f['points_input']:,}); "
        f"{f['n_cylinders']:,} cylinders, {f['n_triangles']:,} triangles, watertight "
        f"{fmt(f['watertight'])}"
    )
    table(
        [
            "stage",
            "time (s)",
        ],
        [
            ["prepare", fmt(ts["prepare"])],
            [
                f"wood/leaf separation (auto; leaves found: {fmt(f.get('leaves_present'))})",
                fmt(ts.get("separate_leaves")),
            ],
            ["QSM fit", fmt(fit_s)],
            ["mesh", fmt(ts.get("mesh"))],
            ["reconstruct() total", fmt(r["reconstruct_s"])],
            ["write tree.ply/cylinders.csv/tree.json", fmt(r.get("write_s"))],
            ["child process wall (start-up, imports, load .npy)", fmt(r["wall_s"])],
        ],
    )
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(
        f"qsm reconstruct() on {f['points_used']:,} prepared points: {r['reconstruct_s']:.1f} s "
        f"on {cores} cores (target < {TARGET_QSM_S:.0f} s for 100k points on 2 cores; "
        f"ratio {r['reconstruct_s'] / TARGET_QSM_S:.2f} of the budget); "
        f"peak RSS {r['rss_self_mib']:.0f} MiB"
    )


def _area(v: np.ndarray, f: np.ndarray) -> float:
    t = v[f]
    return 0.5 * float(np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


def _samples(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, float]:
    """Seeded surface samples, one per SAMPLE_SPACING_M² (at most MAX_SAMPLES), and the
    effective spacing (m)."""
    from treesim.geometry import sample_surface

    area = _area(v, f)
    n = int(min(MAX_SAMPLES, max(1000, np.ceil(area / SAMPLE_SPACING_M**2))))
    pts, _ = sample_surface(v, f, n, seed=0)
    return pts, (area / n) ** 0.5


def _to_mesh(points: np.ndarray, v: np.ndarray, f: np.ndarray):
    """Exact point-to-triangle distance stats of ``points`` to the mesh (the accuracy
    direction of :func:`treesim.compare.compare`; its own completeness is minimised)."""
    from treesim.cloud import Cloud
    from treesim.compare import CompareParams, compare

    params = CompareParams(sample_spacing_m=1.0, min_samples=1000, max_samples=1000, seed=0)
    return compare(Cloud(points), (v, f), params=params).accuracy


def curve(quick: bool) -> None:
    from treesim.cloud import Cloud
    from treesim.reconstruct import ReconstructParams, reconstruct

    facets = (8, 32) if quick else (8, 16, 32, 64)
    depths = (6, 8) if quick else (6, 7, 8, 9)
    print(f"\n== 3. speed/accuracy on the sapling preset (leaf-off, 3 stations, {CURVE_RES_DEG}°)")
    tree, scene, stations = preset_scene("sapling")
    truth = tree.truth(32)
    tv, tf = scene.vertices, scene.faces
    cloud = Cloud(scan_points(scene, stations, CURVE_RES_DEG))
    true_pts, true_sp = _samples(tv, tf)
    print(
        f"sapling: true mesh {len(tf):,} triangles (32 facets), {_area(tv, tf):.3f} m², "
        f"volume {truth['volume_total_m3'] * 1000:.3f} L (cylinders); scan {len(cloud):,} "
        f"points; completeness samples {len(true_pts):,} on the true mesh "
        f"({true_sp * 1000:.1f} mm spacing)"
    )
    settings = [ReconstructParams(method="qsm", facets=k) for k in facets]
    settings += [ReconstructParams(method="poisson", poisson_depth=d) for d in depths]
    reconstruct(cloud, settings[0])  # warm imports and caches
    rows = []
    for p in settings:
        t0 = time.perf_counter()
        m = reconstruct(cloud, p)
        secs = time.perf_counter() - t0
        rec_pts, rec_sp = _samples(m.vertices, m.faces)
        acc = _to_mesh(rec_pts, tv, tf)
        comp = _to_mesh(true_pts, m.vertices, m.faces)
        haus = max(acc.max_m, comp.max_m)
        fig = m.figures
        v_err = m_err = None
        if p.method == "qsm":
            v_err = fig["volume_total_m3"] / truth["volume_total_m3"] - 1
            m_err = fig["mesh_volume_m3"] / truth["volume_total_m3"] - 1
        rows.append(
            [
                p.method,
                p.facets if p.method == "qsm" else p.poisson_depth,
                fmt(secs),
                f"{len(m.faces):,}",
                fmt(rec_sp, 1000, 1),
                fmt(acc.mean_m, 1000),
                fmt(acc.p95_m, 1000),
                fmt(comp.mean_m, 1000),
                fmt(comp.p95_m, 1000),
                fmt(haus, 1000, 1),
                fmt(v_err, 100, 1),
                fmt(m_err, 100, 1),
            ]
        )
    table(
        [
            "method",
            "facets|depth",
            "time (s)",
            "triangles",
            "sample spacing (mm)",
            "acc mean (mm)",
            "acc p95 (mm)",
            "compl mean (mm)",
            "compl p95 (mm)",
            "Hausdorff (mm)",
            "V err (%)",
            "V mesh err (%)",
        ],
        rows,
    )
    print(
        "acc: reconstructed-surface samples to the true mesh; compl: true-mesh samples to the "
        "reconstructed mesh (both exact point-to-triangle). V err: the QSM cylinder table's "
        "total volume vs the truth; V mesh err: the closed QSM mesh's enclosed volume vs the "
        "same truth (the polygon's share of the difference depends on the facets)."
    )


def instrument_points(scene, stations, res_deg: float) -> np.ndarray:
    """Points of a scan at ``res_deg`` with the scaling instrument's noise model."""
    from treesim.params.scanner import instrument
    from treesim.scan import scan

    spec = instrument(SCALING_INSTRUMENT).spec(
        noise=True, horizontal_resolution_deg=res_deg, vertical_resolution_deg=res_deg
    )
    return scan(scene, stations, spec).cloud.points


def log_slope(x: list[float], y: list[float]) -> float | None:
    """Least-squares slope of log(y) against log(x) (None with fewer than two sizes)."""
    if len(x) < 2:
        return None
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def scaling(quick: bool) -> None:
    sizes = SCALING_POINTS_QUICK if quick else SCALING_POINTS
    print(
        f"\n== 4. points scaling: {SCALING_PRESET} (leaf-off) scanned with the "
        f"{SCALING_INSTRUMENT} noise model from 3 stations, qsm in a fresh child per size"
    )
    tree, scene, stations = preset_scene(SCALING_PRESET)
    ref_res = 0.04
    n_ref = len(instrument_points(scene, stations, ref_res))
    print(f"{SCALING_PRESET}: {n_ref:,} points at {ref_res}°; resolution per size from that")
    rows, done = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for target in sizes:
            res = ref_res * (n_ref / target) ** 0.5
            t0 = time.perf_counter()
            pts = instrument_points(scene, stations, res)
            scan_s = time.perf_counter() - t0
            src = Path(tmp) / "cloud.npy"
            np.save(src, pts)
            n = len(pts)
            del pts
            r = run_child(src, "qsm")
            if "error" in r:
                rows.append([f"{n:,}", f"{res:.4f}", fmt(scan_s), *["-"] * 9, "error"])
                print(f"failed at {n:,} points: {r['error']}")
                continue
            f, ts = r["figures"], r["timings_s"]
            done.append((n, r["reconstruct_s"], r["cpu_s"], r["rss_self_mib"]))
            rows.append(
                [
                    f"{n:,}",
                    f"{res:.4f}",
                    fmt(scan_s),
                    f"{f['points_used']:,}",
                    fmt(ts["prepare"]),
                    fmt(ts.get("separate_leaves")),
                    fmt(ts["reconstruct"] - ts.get("mesh", 0.0)),
                    fmt(r["reconstruct_s"]),
                    fmt(r["cpu_s"]),
                    fmt(r["rss_self_mib"], digits=0),
                    fmt(f["dbh_m"], 100),
                    fmt(f["volume_total_m3"], 1000, 0),
                    f"{f['n_cylinders']:,}",
                ]
            )
    table(
        [
            "points",
            "step (°)",
            "scan (s)",
            "points used",
            "prepare (s)",
            "separation (s)",
            "QSM + mesh (s)",
            "reconstruct (s)",
            "child CPU (s)",
            "peak RSS (MiB)",
            "DBH (cm)",
            "volume (L)",
            "cylinders",
        ],
        rows,
    )
    n, secs, cpu, mib = (list(c) for c in zip(*done, strict=True)) if done else ([], [], [], [])
    slopes = [log_slope(n, y) for y in (secs, cpu, mib)]
    print(
        "log-log slope against points: reconstruct time "
        + ", CPU time ".join(fmt(sl) for sl in slopes[:2])
        + f", peak RSS {fmt(slopes[2])} (1 = linear)"
    )
    near = [d for d in done if 1_000_000 <= d[0] <= 2_000_000]
    for n_i, s_i, c_i, m_i in near:
        print(
            f"{n_i:,} points: {s_i:.1f} s ({s_i / SCALING_TARGET_S:.2f} of the "
            f"{SCALING_TARGET_S:.0f} s target), peak RSS {m_i:.0f} MiB "
            f"({m_i / SCALING_TARGET_MIB:.2f} of {SCALING_TARGET_MIB:.0f} MiB); CPU {c_i:.1f} s"
        )
    print(
        "reconstruct (s): reconstruct() in the child, preparation included (the wall time, "
        "which a busy machine inflates; child CPU is user + system time of the whole child, "
        "reading and imports included); peak RSS: the child's ru_maxrss."
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer trees, settings and sizes")
    ap.add_argument(
        "--sections",
        default=",".join(SECTIONS),
        help=f"comma-separated sections to run, of {', '.join(SECTIONS)} (default: all)",
    )
    args = ap.parse_args()
    chosen = [x.strip() for x in args.sections.split(",") if x.strip()]
    unknown = sorted(set(chosen) - set(SECTIONS))
    if unknown:
        ap.error(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(
        f"machine: {cores} cores usable ({os.cpu_count()} online), load average "
        f"{os.getloadavg()[0]:.2f}; python {sys.version.split()[0]}"
        + ("; --quick" if args.quick else "")
    )
    t0 = time.perf_counter()
    runs = {"real": real_trees, "100k": hundred_k, "curve": curve, "scaling": scaling}
    for name in SECTIONS:
        if name in chosen:
            runs[name](args.quick)
    print(
        f"\nbenchmark wall time: {time.perf_counter() - t0:.0f} s; load average at the end "
        "(1, 5, 15 min): {:.2f} {:.2f} {:.2f} (wall times grow with it; CPU times do not)".format(
            *os.getloadavg()
        )
    )


if __name__ == "__main__":
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("bench-reconstruct"), "bench_reconstruct.py"):
        main()
