"""Scan throughput, beam cost and memory: ``treesim scan`` against a plain Open3D cast.

Measured in one run, side by side, on the same trees and stations:

1. **Single ray per pulse.** A sparse tree (the ``aspen`` species, leaf-off, meshed at 8
   facets: ~41k triangles, close to the 39k-triangle birch of issue 11) scanned from one
   station 15 m away at 0.01°:

   * a plain Open3D load-and-cast in this process: read the mesh file, build the
     ``RaycastingScene``, cast every pulse of the exact window rectangle (what the scene's
     bounding box subtends), in chunks; its rate is window pulses per second;
   * ``treesim scan`` end to end in a fresh process (start-up, load, cast, LAZ written);
     its rate is the same window's pulses per second of wall time;
   * the ratio (target >= 0.7) and the ratio to HELIOS++ 2.2.2's single-ray rate as
     issue 11 quotes it (~358k pulses/s; target >= 10; a constant, not measured here: see
     ``HELIOS_PULSES_PER_S``).
2. **Beam divergence** (0.3 mrad), in this process: the brute force at 19 sub-rays
   (``beam_sampling="full"``), adaptive sampling and the edge model
   (``beam_sampling="edge"``) against treesim's own single-ray scan of the same scene
   (target <= 2×), on the bundled coffee tree's TreeQSM model (24 facets, 10 m, 0.01°)
   and the aspen (0.02°), with how many pulses got sub-rays and why, and each model's
   errors against the 127-sub-ray footprint reference on one window; then the brute
   force's and the edge model's errors on held-out trees, none of the edge model's
   constants set on them (``tests/scan/beam_agreement.py``; not with ``--quick``).
3. **Memory.** Peak RSS of ``treesim scan`` (fresh process each) at 0.04°, 0.01° and
   0.005°: it must not grow with the number of points written.

Usage: ``python benchmarks/bench_scan.py [--quick] [--docs]`` (``--quick``: coarser
settings, for a smoke run; ``--docs``: also write the figures into ``docs/validation.md``
between ``<!-- bench-scan:begin -->`` and ``<!-- bench-scan:end -->``). Prints measured
figures only.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import docs_part  # noqa: E402
from tests.scan.beam_agreement import generated_scene  # noqa: E402
from tests.scan.beam_agreement import station_before as station_at  # noqa: E402
from treesim.io.mesh import write_mesh  # noqa: E402
from treesim.models import cylinders_to_mesh, read_cylinders  # noqa: E402
from treesim.scan import ScannerSpec, Station, scan  # noqa: E402
from treesim.scan.footprint import (  # noqa: E402
    ERROR_NAMES,
    REFERENCE_SUBRAYS,
    footprint_errors,
    partial_pulses,
    reference_spec,
    window_spec,
)
from treesim.scan.rays import box_window, windowed_grid  # noqa: E402
from treesim.scene import MeshPart, Scene  # noqa: E402

COFFEE = ROOT / "pipeline" / "data" / "coffee_tree" / "QSM_treeqsm_v2.4.1_cylinders.csv"
#: HELIOS++ 2.2.2, one ray per pulse: ~358k pulses/s. Not measured by this script or any
#: file in the repository: the figure is quoted from issue 11's text ("Measured on this
#: machine (2 cores) with a 39k-triangle birch mesh scanned from 15 m at 0.01°: ... HELIOS++
#: 2.2.2 on a comparable scene runs ~358 k pulses/s with one ray per pulse and ~112 k
#: pulses/s with its 19-sub-ray beam"), which records neither the scene file nor the survey
#: nor the command. HELIOS++ is not on PyPI (../shared/notes/reconstruction.md), so this
#: benchmark cannot re-measure it; the ratio it prints divides by this constant.
HELIOS_PULSES_PER_S = 358e3
#: The part of docs/validation.md this benchmark writes with ``--docs``.
DOCS_PART = "bench-scan"


def aspen_scene() -> Scene:
    return generated_scene("aspen", seed=0)


def coffee_scene() -> Scene:
    v, f = cylinders_to_mesh(read_cylinders(COFFEE), facets=24, joints="miter")
    return Scene([MeshPart(vertices=v, faces=f, label="wood", name="coffee")])


def plain_open3d(mesh_path: Path, station: Station, spec: ScannerSpec, chunk: int) -> dict:
    """Read the mesh, build the scene, cast the exact window rectangle; timed whole."""
    import open3d as o3d
    import trimesh

    t0 = time.perf_counter()
    m = trimesh.load(mesh_path, force="mesh", process=False)
    v = np.asarray(m.vertices, dtype=np.float64)
    origin = 0.5 * (v.min(axis=0) + v.max(axis=0))
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(
        o3d.core.Tensor((v - origin).astype(np.float32)),
        o3d.core.Tensor(np.asarray(m.faces, dtype=np.uint32)),
    )
    o = np.asarray(station.position_m) - origin
    rel = (v - origin) - o
    grid = windowed_grid(spec, box_window(rel.min(axis=0), rel.max(axis=0)), margin_steps=0)
    el = np.radians(spec.vertical_fov_deg[0] + grid.lines * spec.vertical_resolution_deg)
    az = np.radians(spec.horizontal_fov_deg[0] + grid.columns * spec.horizontal_resolution_deg)
    hits = 0
    per_col = max(1, chunk // len(el))
    ce, se = np.cos(el), np.sin(el)
    for a in range(0, len(az), per_col):
        cz, sz = np.cos(az[a : a + per_col]), np.sin(az[a : a + per_col])
        rays = np.empty((len(cz), len(el), 6), dtype=np.float32)
        rays[..., :3] = o
        rays[..., 3] = cz[:, None] * ce[None, :]
        rays[..., 4] = sz[:, None] * ce[None, :]
        rays[..., 5] = se[None, :]
        ans = rc.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6)))
        hits += int(np.isfinite(ans["t_hit"].numpy()).sum())
    secs = time.perf_counter() - t0
    return {"pulses": grid.n_pulses, "hits": hits, "s": secs}


_PRINT_PEAK = (
    "\nimport pathlib\n"
    "print('VmHWM', [l.split()[1] for l in pathlib.Path('/proc/self/status').read_text()"
    ".splitlines() if l.startswith('VmHWM:')][0])\n"
)


def cli_scan(mesh: Path, out: Path, station: Station, res: float, extra=()) -> dict:
    """``treesim scan`` in a fresh interpreter: wall time, its own peak RSS, its summary."""
    argv = ["treesim", "scan", str(mesh), "-o", str(out), "--resolution-deg", str(res)]
    argv += ["--station", ",".join(f"{c:.6f}" for c in station.position_m), *extra]
    code = (
        "import runpy, sys\n"
        f"sys.argv = {argv!r}\n"
        "try:\n"
        "    runpy.run_module('treesim.cli', run_name='__main__')\n"
        "except SystemExit as e:\n"
        "    assert not e.code, e.code\n"
    ) + _PRINT_PEAK
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=str(ROOT), check=True
    )
    wall = time.perf_counter() - t0
    peak = int(done.stdout.strip().splitlines()[-1].split()[1]) / 2**20
    summary = json.loads(out.with_suffix(".json").read_text())
    return {"s": wall, "peak_gib": peak, "summary": summary}


def plain_fresh(mesh: Path, station: Station, res: float) -> float:
    """:func:`plain_open3d` in a fresh interpreter that imports only what it needs (numpy,
    Open3D, trimesh, the window's arithmetic): wall seconds of the whole process, the
    start-up ``treesim scan`` pays included."""
    code = (
        "from __future__ import annotations\n"
        "import sys, time\n"
        f"sys.path.insert(0, {str(ROOT)!r})\n"
        "import numpy as np\n"
        "from treesim.params import ScannerSpec\n"
        "from treesim.scan.rays import box_window, windowed_grid\n"
        "from treesim.scan.stations import Station\n"
        + inspect.getsource(plain_open3d)
        + f"spec = ScannerSpec(horizontal_resolution_deg={res!r}, "
        f"vertical_resolution_deg={res!r})\n"
        f"plain_open3d({str(mesh)!r}, Station(position_m={tuple(station.position_m)!r}), spec, "
        "1 << 19)\n"
    )
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], cwd=str(ROOT), check=True, capture_output=True)
    return time.perf_counter() - t0


def end_to_end(name: str, scene: Scene, station: Station, res: float, tmp: Path) -> dict:
    """``treesim scan`` end to end against the plain Open3D load-and-cast of the same
    window (best of 2 each, alternated), printed; the figures."""
    spec = ScannerSpec(horizontal_resolution_deg=res, vertical_resolution_deg=res)
    mesh = write_mesh(tmp / f"{name}.ply", scene.vertices, scene.faces)
    plains, runs = [], []
    for _ in range(2):
        plains.append(plain_open3d(mesh, station, spec, 1 << 19))
        runs.append(cli_scan(mesh, tmp / f"{name}.laz", station, res))
    plain = min(plains, key=lambda r: r["s"])
    cli = min(runs, key=lambda r: r["s"])
    fresh = plain_fresh(mesh, station, res)
    sm = cli["summary"]
    window = sm["pulses_window"]
    print(f"\n== {name} ({scene.n_triangles:,} triangles): one ray per pulse at {res}°, best of 2")
    print(
        f"plain Open3D load-and-cast of the window: {plain['pulses']:,} pulses, "
        f"{plain['hits']:,} hits, {plain['s']:.2f} s: {plain['pulses'] / plain['s'] / 1e6:.2f} "
        "M pulses/s"
    )
    rate = window / cli["s"]
    ratio = rate / (plain["pulses"] / plain["s"])
    print(
        f"treesim scan end to end (process, load, cast, LAZ written): {window:,} window "
        f"pulses, {sm['pulses_cast']:,} cast, {sm['points']:,} points, {cli['s']:.2f} s "
        f"(load {sm['timings_s']['load']:.2f}, scan+write {sm['timings_s']['scan']:.2f}, "
        f"finish {sm['timings_s']['write']:.2f}): {rate / 1e6:.2f} M pulses/s"
    )
    print(
        f"end-to-end ratio, {name}: treesim / plain cast {ratio:.2f} (target >= 0.7); "
        f"against the plain cast in a fresh process too (its start-up and imports, "
        f"{fresh:.2f} s): {rate / (plain['pulses'] / fresh):.2f}"
    )
    fig = {"plain": plain, "cli": cli, "ratio": ratio, "plain_fresh_s": fresh, "mesh": mesh}
    return {**fig, "ratio_fresh": rate / (plain["pulses"] / fresh)}


#: Pulses (single-ray, after the cull) of the window the footprint reference is cast on.
REF_BUDGET_PULSES = 250_000
#: The beam models measured against the footprint reference, as ``ScannerSpec`` changes.
BEAM_MODELS = {
    "full 19": {"beam_sampling": "full"},
    "adaptive 19": {},
    "edge": {"beam_sampling": "edge"},
}
#: How each error figure is printed: (heading, scale, format).
ERROR_FORMAT = {
    "count_mismatch": ("returns/pulse differ", 100.0, "{:.2f} %"),
    "multi_share_error": ("multi-return share error", 100.0, "{:.3f} pt"),
    "range_mean_m": ("range mean", 1e3, "{:.3f} mm"),
    "range_p99_m": ("range p99", 1e3, "{:.2f} mm"),
    "position_mean_m": ("position mean", 1e3, "{:.3f} mm"),
    "position_p99_m": ("position p99", 1e3, "{:.2f} mm"),
    "intensity_mean": ("intensity mean", 1.0, "{:.1f}"),
    "intensity_p99": ("intensity p99", 1.0, "{:.0f}"),
    "unmatched_intensity": ("unmatched intensity", 100.0, "{:.4f} %"),
}


#: Times the single ray and the edge model are scanned, the best time kept: each takes
#: under 2 s, and one run on this shared host can read 0.1 s high (the single ray's
#: 0.29 s against 0.17-0.19 s on 2026-11-28). The brute force and adaptive run once.
BEST_OF = 3


def _timed(scene: Scene, station: Station, spec: ScannerSpec, repeat: int = 1):
    """The scan of ``spec`` and its best time (s) of ``repeat`` runs."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        r = scan(scene, [station], spec)
        best = min(best, time.perf_counter() - t0)
    return r, best


def reference_window(one, budget: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """The single-ray scan's angular window, its azimuth narrowed about its centre to
    about ``budget`` cast pulses (the reference's 127 sub-rays each cost a ray)."""
    st = one.station_stats[0]
    el = st.elevation_window_deg
    az = st.azimuth_window_deg or (0.0, 360.0)
    f = min(1.0, budget / max(st.pulses_cast, 1))
    mid, half = 0.5 * (az[0] + az[1]), 0.5 * f * (az[1] - az[0])
    return (mid - half, mid + half), (el[0], el[1])


def beam_case(name: str, scene: Scene, station: Station, res: float, ref_check: bool) -> dict:
    """The beam at 0.3 mrad: single ray, brute force and adaptive at 19 sub-rays timed on
    the whole scan, and each model's errors against the footprint reference (127
    sub-rays, :mod:`treesim.scan.footprint`) on one window of pulses, the same for all."""
    base = ScannerSpec(horizontal_resolution_deg=res, vertical_resolution_deg=res)
    beam = base.with_(beam_divergence_mrad=0.3, subrays=19, return_mode="all")
    coarse = {"horizontal_resolution_deg": 1.0, "vertical_resolution_deg": 1.0}
    scan(scene, [station], base.with_(**coarse))
    # the edge model's first scan in a process imports numba and loads its compiled
    # kernels (compiles them, the first time after an install): once per process, timed
    # apart from the scans compared
    _, t_first = _timed(scene, station, beam.with_(beam_sampling="edge", **coarse))
    print(f"\nthe edge model's first use in this process (a 1° scan): {t_first:.2f} s")
    one, t_one = _timed(scene, station, base, BEST_OF)
    times, runs = {}, {}
    for model, change in BEAM_MODELS.items():
        repeat = BEST_OF if model == "edge" else 1
        runs[model], times[model] = _timed(scene, station, beam.with_(**change), repeat)
    window = one.summary()["pulses_window"]
    print(
        f"\n== beam 0.3 mrad, {name} ({scene.n_triangles:,} triangles), {res}°: whole scan "
        f"(single ray and edge: best of {BEST_OF})"
    )
    print(
        f"single ray:   {one.rays_cast:>11,} rays, {len(one.cloud):>9,} points, "
        f"{t_one:6.2f} s ({window / t_one / 1e6:.2f} M window pulses/s)"
    )
    for model, r in runs.items():
        print(
            f"{model + ':':<13} {r.rays_cast:>11,} rays, {len(r.cloud):>9,} returns, "
            f"{times[model]:6.2f} s: {times[model] / t_one:5.2f}× the single-ray time "
            "(target <= 2)"
        )
    b = runs["adaptive 19"].lod["beam"]
    print(
        f"adaptive: {b['pulses_subrays']:,} of {b['pulses_cast']:,} pulses got sub-rays "
        f"({json.dumps(b['reasons'])})"
    )
    e = runs["edge"].lod["beam"]
    print(
        f"edge: {e['pulses_subrays']:,} of {e['pulses_cast']:,} pulses left to the 19 "
        f"sub-rays ({json.dumps(e['reasons'])})"
    )
    az, el = reference_window(one, REF_BUDGET_PULSES)
    wbeam = window_spec(beam, az, el)
    ref, t_ref = _timed(scene, station, reference_spec(wbeam))
    n_ref = ref.station_stats[0].pulses_cast
    print(
        f"footprint reference ({REFERENCE_SUBRAYS} sub-rays, every pulse) on the window "
        f"azimuth {wbeam.horizontal_fov_deg[0]:.2f} to {wbeam.horizontal_fov_deg[1]:.2f}°, "
        f"elevation {wbeam.vertical_fov_deg[0]:.2f} to {wbeam.vertical_fov_deg[1]:.2f}°: "
        f"{n_ref:,} pulses ({n_ref / max(one.station_stats[0].pulses_cast, 1):.0%} of the "
        f"scan's), {len(ref.cloud):,} returns, {t_ref:.1f} s"
    )
    split = partial_pulses(ref.cloud, wbeam)
    print(
        f"pulses whose footprint is split (several returns, or part missed): {split:,} "
        f"({split / max(n_ref, 1):.1%} of the window's); adaptive gives sub-rays to "
        f"{b['pulses_subrays'] / max(b['pulses_cast'], 1):.1%} of the scan's"
    )
    errors = {
        m: footprint_errors(scan(scene, [station], wbeam.with_(**c)).cloud, ref.cloud)
        for m, c in BEAM_MODELS.items()
    }
    if ref_check:
        dense = scan(scene, [station], reference_spec(wbeam, 2 * REFERENCE_SUBRAYS + 1))
        errors[f"reference {REFERENCE_SUBRAYS}"] = footprint_errors(ref.cloud, dense.cloud)
        print(f"(the reference's own error: against {2 * REFERENCE_SUBRAYS + 1} sub-rays)")
    print_errors(errors, int(errors["full 19"]["pulses"]))
    return {
        "res": res,
        "t_one": t_one,
        "t_first": t_first,
        "times": times,
        "rays": {"one": one.rays_cast, **{m: r.rays_cast for m, r in runs.items()}},
        "beam": b,
        "edge": e,
        "errors": errors,
        "ref_pulses": n_ref,
        "split_share": split / max(n_ref, 1),
    }


def held_out() -> dict:
    """The brute force's and the edge model's errors against the footprint reference on
    the held-out trees' windows (``tests/scan/beam_agreement.py``: trees none of the edge
    model's constants were set on), printed; a tree whose data is absent is left out."""
    import pytest

    from tests.scan.beam_agreement import held_out_windows

    out = {}
    for name, make in held_out_windows().items():
        try:
            scene, st, w = make()
        except pytest.skip.Exception as why:
            print(f"\n== held out: {name}: left out ({why})")
            continue
        ref = scan(scene, st, reference_spec(w)).cloud
        errors = {
            m: footprint_errors(scan(scene, st, w.with_(beam_sampling=s)).cloud, ref)
            for m, s in (("full 19", "full"), ("edge", "edge"))
        }
        print(
            f"\n== held out: {name} ({scene.n_triangles:,} triangles), "
            f"{w.horizontal_resolution_deg}°, window azimuth {w.horizontal_fov_deg[0]:g} to "
            f"{w.horizontal_fov_deg[1]:g}°, elevation {w.vertical_fov_deg[0]:g} to "
            f"{w.vertical_fov_deg[1]:g}°"
        )
        print_errors(errors, int(errors["full 19"]["pulses"]))
        out[name] = {"res": w.horizontal_resolution_deg, "errors": errors}
    return out


def print_errors(errors: dict[str, dict[str, float]], pulses: int) -> None:
    """Each model's errors against the reference, one line per figure."""
    print(f"errors against the footprint reference ({pulses:,} pulses with a return):")
    print(f"{'':<26}" + "".join(f"{m:>16}" for m in errors))
    for key, (head, scale, fmt) in ERROR_FORMAT.items():
        print(f"{head:<26}" + "".join(f"{fmt.format(e[key] * scale):>16}" for e in errors.values()))
    for model in [m for m in ("adaptive 19", "edge") if m in errors]:
        worse = [
            ERROR_FORMAT[k][0]
            for k in ERROR_NAMES
            if errors[model][k] > errors["full 19"][k] * (1 + 1e-9) + 1e-12
        ]
        print(
            f"{model}'s errors no larger than the 19-sub-ray brute force's on every figure: "
            f"{not worse}" + (f" (larger: {', '.join(worse)})" if worse else "")
        )


def docs_table(f: dict) -> str:
    """The manual's scanner speed-and-memory table from this run's figures."""
    plain_rate = f["plain"]["pulses"] / f["plain"]["s"]
    sm = f["cli"]["summary"]
    rate = sm["pulses_window"] / f["cli"]["s"]
    mem = f["memory"]
    ab, cb = f["beam_aspen"], f["beam_coffee"]
    co = f["e2e"]["coffee"]
    rows = [
        (
            f"aspen ({f['triangles']:,} triangles) from 15 m at {f['res']}°, one ray per "
            "pulse: the window",
            f"{sm['pulses_window'] / 1e6:.1f} M pulses; {sm['pulses_cast'] / 1e6:.1f} M cast "
            f"after the occupancy cull; {sm['points'] / 1e6:.2f} M points",
        ),
        (
            "plain Open3D load-and-cast of that window (in-process)",
            f"{f['plain']['s']:.2f} s, {plain_rate / 1e6:.1f} M pulses/s",
        ),
        (
            "`treesim scan` end to end (process start, load, cast, LAZ written)",
            f"{f['cli']['s']:.2f} s, {rate / 1e6:.1f} M pulses/s: **{rate / plain_rate:.2f}×** "
            f"the plain cast (issue 11's target 0.7×), **{rate / HELIOS_PULSES_PER_S:.0f}×** "
            "HELIOS++ 2.2.2's single-ray rate as issue 11 quotes it (~358 k pulses/s, not "
            "measured here; target 10×)",
        ),
        (
            f"coffee TreeQSM ({f['coffee_triangles']:,} triangles) from 10 m at {f['res']}°: "
            "`treesim scan` end to end against the plain load-and-cast",
            f"{co['cli']['s']:.2f} s against {co['plain']['s']:.2f} s "
            f"({co['cli']['summary']['pulses_window'] / 1e6:.1f} M window pulses, "
            f"{co['cli']['summary']['points'] / 1e6:.2f} M points): **{co['ratio']:.2f}×** (a "
            "small scan: the interpreter and Open3D's import are most of it)",
        ),
        (
            "the plain load-and-cast in a fresh process too (Python, numpy, Open3D and "
            "trimesh imported), aspen / coffee",
            " / ".join(f"{e['plain_fresh_s']:.2f} s" for e in f["e2e"].values())
            + ": `treesim scan` at "
            + " / ".join(f"{e['ratio_fresh']:.2f}×" for e in f["e2e"].values())
            + " its rate",
        ),
        (
            "the same scan in-process (`treesim.steps.scan_files`)",
            f"{f['inproc_s']:.2f} s: {f['plain']['s'] / f['inproc_s']:.2f}× the plain cast; "
            "the rest of the end-to-end time is the interpreter and its imports",
        ),
        (
            "peak RSS of `treesim scan` at " + " / ".join(f"{r}°" for r, _ in mem),
            " / ".join(f"{m['peak_gib']:.2f}" for _, m in mem)
            + " GiB for "
            + " / ".join(_count(m["summary"]["points"]) for _, m in mem)
            + " points",
        ),
        (
            "the edge model's kernels compiled by numba with an empty cache "
            "(`warm_edge_model()`, a fresh process: numba's import, the compilation, one "
            "coarse scan)",
            f"{f['compile_s']:.1f} s, once per install (cached after)",
        ),
        *(beam_rows(f["beam_coffee"], f"coffee TreeQSM from 10 m at {cb['res']}°")),
        *(beam_rows(f["beam_aspen"], f"aspen from 15 m at {ab['res']}°")),
    ]
    head = (
        f"`python benchmarks/bench_scan.py --docs` measured these side by side in one run "
        f"and wrote this table: {f['when']} (a shared host, load average {f['load']} over "
        "the run: expect ±15 %; treesim's modules byte-compiled first, as an installed "
        "package's are).\n\n"
        "| what | figure |\n|---|---|\n"
    )
    table = head + "\n".join(f"| {a} | {b} |" for a, b in rows)
    return table + "\n\n" + error_table(f)


def beam_rows(c: dict, where: str) -> list[tuple[str, str]]:
    """The speed table's rows of one tree's beam figures."""
    t = c["times"]
    cost = "; ".join(f"{m} {s:.2f} s (**{s / c['t_one']:.1f}×**)" for m, s in t.items())
    return [
        (
            f"beam 0.3 mrad, {where}: single ray {c['t_one']:.2f} s (it and edge: best of "
            f"{BEST_OF} scans; the others one)",
            f"{cost}; target ≤ 2× the single ray; adaptive gave sub-rays to "
            f"{_count(c['beam']['pulses_subrays'])} of {_count(c['beam']['pulses_cast'])} pulses "
            f"({c['beam']['pulses_subrays'] / max(c['beam']['pulses_cast'], 1):.0%}), where "
            f"the reference splits {c['split_share']:.0%} of the pulses of its window; edge "
            f"left {_count(c['edge']['pulses_subrays'])} "
            f"({c['edge']['pulses_subrays'] / max(c['edge']['pulses_cast'], 1):.0%}) to the "
            f"sub-rays; the edge model's first use in the process (numba's import, its "
            f"compiled kernels loaded) {c['t_first']:.2f} s more, once, not counted; rays "
            f"cast: edge {c['rays']['edge'] / c['rays']['one']:.1f}× the single ray's",
        )
    ]


def error_table(f: dict) -> str:
    """Each beam model's errors against the footprint reference, per tree."""
    heads = [ERROR_FORMAT[k][0] for k in ERROR_FORMAT]
    out = [
        f"Errors against the footprint reference ({REFERENCE_SUBRAYS} sub-rays per pulse on "
        "the same footprint, `treesim.scan.footprint`), on one window of each scan, the same "
        "for every model; the last row of the coffee tree and the aspen is the reference's "
        f"own error against {2 * REFERENCE_SUBRAYS + 1} sub-rays. Held out: trees none of "
        "the edge model's constants were set on (`tests/scan/beam_agreement.py`), the brute "
        "force and the edge model. Intensities in counts of 65,535; pt: percentage points.\n",
        "| tree, model | " + " | ".join(heads) + " |",
        "|---" * (len(heads) + 1) + "|",
    ]
    for tree, key in (("coffee", "beam_coffee"), ("aspen", "beam_aspen")):
        c = f[key]
        for model, e in c["errors"].items():
            cells = [fmt.format(e[k] * sc) for k, (_, sc, fmt) in ERROR_FORMAT.items()]
            label = f"{tree} {c['res']}° ({_count(c['ref_pulses'])} pulses), {model}"
            out.append(f"| {label} | " + " | ".join(cells) + " |")
    for tree, c in f.get("held_out", {}).items():
        for model, e in c["errors"].items():
            cells = [fmt.format(e[k] * sc) for k, (_, sc, fmt) in ERROR_FORMAT.items()]
            label = f"held out: {tree} {c['res']}° ({_count(e['pulses'])} pulses), {model}"
            out.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def _count(n: int) -> str:
    """A count the way the manual writes it: 77 k, 1.2 M."""
    return f"{n / 1e6:.1f} M" if n >= 1e6 else f"{n / 1e3:.0f} k"


def byte_compile() -> None:
    """Byte-compile treesim's modules, as ``pip install`` does for an installed package.

    This checkout is installed editable: its modules compile from source at each start
    where nothing wrote their bytecode (``PYTHONDONTWRITEBYTECODE`` set, as on the
    developers' machines), ~0.05 s of each ``treesim scan`` that a user's install does
    not pay. ``__pycache__`` is ignored by git."""
    import compileall

    ok = compileall.compile_dir(str(ROOT / "pipeline"), quiet=1)
    print(f"treesim's modules byte-compiled first, as an installed package's are: {bool(ok)}")


def speed_parts(fig: dict, quick: bool, res: float, aspen_at, coffee_at) -> None:
    """Parts 1 and 3: end to end against the plain cast, in-process, and memory."""
    (scene, st), (coffee, coffee_st) = aspen_at, coffee_at
    spec = ScannerSpec(horizontal_resolution_deg=res, vertical_resolution_deg=res)
    byte_compile()
    with tempfile.TemporaryDirectory() as tmp:
        print(f"tree: aspen (seed 0, 8 facets), {scene.n_triangles:,} triangles; station 15 m out")
        e2e = {
            "aspen": end_to_end("aspen", scene, st, res, Path(tmp)),
            "coffee": end_to_end("coffee tree TreeQSM", coffee, coffee_st, res, Path(tmp)),
        }
        mesh = e2e["aspen"]["mesh"]
        fig.update(plain=e2e["aspen"]["plain"], cli=e2e["aspen"]["cli"], e2e=e2e)
        aspen = e2e["aspen"]["cli"]
        helios = aspen["summary"]["pulses_window"] / aspen["s"] / HELIOS_PULSES_PER_S
        print(
            "\nend-to-end ratios, treesim scan / plain cast (target >= 0.7): "
            + ", ".join(f"{k} {v['ratio']:.2f}" for k, v in e2e.items())
            + f"; the aspen vs HELIOS++ single ray (~358k pulses/s): {helios:.1f}x (target >= 10)"
        )
        from treesim.params import ScanParams
        from treesim.steps import scan_files

        inproc = []
        for _ in range(2):
            t0 = time.perf_counter()
            scan_files(
                [mesh], ScanParams(scanner=spec), Path(tmp) / "in.laz", stations=[st.position_m]
            )
            inproc.append(time.perf_counter() - t0)
        fig["inproc_s"] = min(inproc)
        print(
            f"the same scan in this process (treesim.steps.scan_files: load, cast, LAZ "
            f"written; no interpreter start or imports): {min(inproc):.2f} s, ratio to the "
            f"plain cast {fig['plain']['s'] / min(inproc):.2f}"
        )

        print("\n== peak memory of treesim scan (fresh process each)")
        fig["memory"] = []
        for r in (0.04, 0.01, 0.005) if not quick else (0.08, 0.04):
            m = cli_scan(mesh, Path(tmp) / "mem.laz", st, r)
            fig["memory"].append((r, m))
            s = m["summary"]
            print(
                f"{r}°: {s['points']:>10,} points, {s['rays_cast']:>11,} rays, {m['s']:6.1f} s, "
                f"peak RSS {m['peak_gib']:.2f} GiB"
            )


def cold_compile() -> float:
    """Seconds a fresh process takes to compile the edge model's kernels with an empty
    numba cache (:func:`treesim.scan.warmup.warm_edge_model`, its own figure: numba's
    import, the compilation and one coarse scan)."""
    code = "from treesim.scan.warmup import warm_edge_model; print(warm_edge_model())"
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
    s = float(out.stdout.strip().splitlines()[-1])
    print(f"\nthe edge model's kernels compiled with an empty numba cache: {s:.1f} s (once)")
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="coarser settings, for a smoke run")
    ap.add_argument(
        "--docs",
        "--readme",
        dest="docs",
        action="store_true",
        help="write the figures into docs/validation.md's speed-and-memory table (not --quick)",
    )
    ap.add_argument(
        "--beam-only", action="store_true", help="only the beam's costs and errors (part 2)"
    )
    ap.add_argument(
        "--no-ref-check",
        dest="ref_check",
        action="store_false",
        help="skip the reference's own error (against twice its sub-rays; slow)",
    )
    args = ap.parse_args()
    if args.quick and args.docs:
        ap.error("--docs takes the full run's figures, not --quick's")
    if args.beam_only and args.docs:
        ap.error("--docs needs every part, not --beam-only")
    res = 0.04 if args.quick else 0.01
    when = (
        f"{date.today()} on {platform.machine()} with {os.cpu_count()} cores, "
        f"python {sys.version.split()[0]}"
    )
    print(f"date: {when}")
    scene = aspen_scene()
    st = station_at(scene, 15.0)
    fig: dict = {"when": when, "res": res, "triangles": scene.n_triangles}
    load0 = os.getloadavg()[0]
    coffee = coffee_scene()
    coffee_st = station_at(coffee, 10.0)
    if not args.beam_only:
        speed_parts(fig, args.quick, res, (scene, st), (coffee, coffee_st))
    fig["coffee_triangles"] = coffee.n_triangles
    fig["compile_s"] = cold_compile()
    fig["beam_coffee"] = beam_case("coffee tree TreeQSM", coffee, coffee_st, res, args.ref_check)
    fig["beam_aspen"] = beam_case("aspen", scene, st, 0.04 if args.quick else 0.02, args.ref_check)
    if not args.quick:
        fig["held_out"] = held_out()
    fig["load"] = f"{load0:.1f} to {os.getloadavg()[0]:.1f}"
    print(f"\nload average (1 min) at the start and the end: {fig['load']}")
    if args.docs:
        docs_part.write_part(DOCS_PART, docs_table(fig))
        print(f"\nwrote {docs_part.VALIDATION.relative_to(ROOT)}'s {DOCS_PART} part")


if __name__ == "__main__":
    main()
