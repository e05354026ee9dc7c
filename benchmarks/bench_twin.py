"""Field plots: the twin made from a plot's cloud, and the simulator checked against the scan.

Two sections, each with the commands a user would type (``treesim plot from-cloud``,
``treesim plot scan --stations-from``, ``treesim plan``, ``treesim validate``):

* ``synthetic``: a generated 30-tree stand (aspen and balsam fir) on a 15° slope, scanned
  from 5 known stations with the RIEGL VZ-400's noise and written as an E57 with its poses
  (``tests/plot/field_plot.py``). The twin made from that E57 is held to the generator's
  truth (trees of DBH >= 10 cm found, none invented, positions, DBH, the DTM under the
  trees); then the twin is scanned from the stations read from the E57 with the same
  scanner, and ``treesim validate`` sets that scan beside the field scan.
* ``pine``: the real TreeLS pine plot (``../shared/data/plots``): its twin, each tree's
  DBH against a circle fitted to a 10 cm slab of its own stem at 1.3 m above the DTM
  (``tests/reconstruct/slab_reference.py``, independent of treesim's stems and QSM), then
  stations planned on the twin (``treesim plan``), the twin scanned from them and the
  validation of that simulated rescan against the real plot.

Usage: ``python benchmarks/bench_twin.py [--section synthetic|pine|all]
[--workdir DIR] [--resolution-deg 0.2] [--docs]``. Prints measured figures only; ``--docs``
writes the printout into docs/validation.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import treesim as ts  # noqa: E402
from tests.plot.field_plot import make_field_plot, match  # noqa: E402

PINE = ROOT.parent / "shared" / "data" / "plots" / "treels_pine_plot" / "pine_plot.laz"


def treesim(*args: str) -> str:
    """Run ``treesim ARGS`` as a user would; return its output (stop on failure)."""
    cmd = [sys.executable, "-m", "treesim.cli", *args]
    shown = [a.replace(str(ROOT.parent) + "/", "../") for a in args]
    shown = [a.replace("../main/", "") for a in shown]
    print("$ treesim " + " ".join(shown), flush=True)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        print(r.stdout[-3000:], r.stderr[-3000:])
        raise SystemExit(f"treesim {args[0]} failed ({r.returncode})")
    print(f"  ({time.perf_counter() - t0:.0f} s)")
    return r.stdout


def _twin_rows(twin: Path) -> list[dict]:
    return json.loads((twin / "from_cloud.json").read_text())["trees"]


def _validation(folder: Path) -> dict:
    return json.loads((folder / "validation.json").read_text())


def _print_validation(v: dict) -> None:
    print(f"  {v['summary']}")
    for g, d in v["density"]["per_station"].items():
        shape = d.get("range_profile_difference")
        print(
            f"  station {g}: {d['points_real']:,} field / {d['points_simulated']:,} simulated "
            f"points, density ratio {d['density_ratio']:.3f}"
            + ("" if shape is None else f", range-profile difference {shape:.3f}")
        )
    trees = v.get("trees") or []
    if trees:
        diff = np.array([t["coverage_difference_points"] for t in trees if t["points_real"]])
        print(
            f"  coverage per tree, simulated - field: median {np.median(diff):+.1f} points, "
            f"|max| {np.abs(diff).max():.1f} points over {len(diff)} trees"
        )
        for part in ("stem", "crown"):
            d = [
                t[part]["coverage_difference_points"]
                for t in trees
                if t["points_real"]
                and t.get(part)
                and t[part]["coverage_difference_points"] is not None
            ]
            if d:
                print(
                    f"  {part} coverage, simulated - field: median {np.median(d):+.1f} points, "
                    f"|max| {np.abs(d).max():.1f} points over {len(d)} trees"
                )
    verdict = v.get("verdict") or {}
    if verdict.get("parts"):
        print(f"  by part: {verdict['parts']}")
    for w in v.get("warnings", []):
        print(f"  warning: {w}")


def synthetic(work: Path, resolution_deg: float) -> None:
    print(f"== synthetic: 30 trees on a 15° slope, 5 stations, VZ-400 noise, {resolution_deg}°")
    t0 = time.perf_counter()
    fp = make_field_plot(work / "field", resolution_deg=resolution_deg)
    print(f"field campaign simulated in {time.perf_counter() - t0:.0f} s: {fp.e57.name}")
    twin = work / "twin"
    treesim(
        "plot", "from-cloud", str(fp.e57), "-o", str(twin), "--preset", "draft", "--no-progress"
    )
    rows = _twin_rows(twin)
    truth = fp.truth
    true_xy = np.array([[t["x_m"], t["y_m"]] for t in truth])
    found = json.loads((twin / "from_cloud.json").read_text())
    all_found = rows + found["left_out"]
    found_xy = np.array([[r["x_m"], r["y_m"]] for r in all_found])
    m = match(found_xy, true_xy, 0.10)
    big = [i for i, t in enumerate(truth) if t["dbh_m"] >= 0.10]
    hit = [i for i in big if m[i] >= 0]
    invented = len(all_found) - len({int(j) for j in m if j >= 0})
    pos = [np.linalg.norm(found_xy[m[i]] - true_xy[i]) for i in hit]
    slab = [all_found[m[i]]["slab_dbh_m"] - truth[i]["dbh_m"] for i in hit]
    qsm = [
        all_found[m[i]]["qsm_dbh_m"] - truth[i]["dbh_m"]
        for i in hit
        if all_found[m[i]].get("qsm_dbh_m")
    ]
    print(
        f"trees of DBH >= 10 cm found within 10 cm: {len(hit)} of {len(big)}; invented: "
        f"{invented}; in the twin: {len(rows)}, left out: {len(found['left_out'])}"
    )
    print(f"position error: max {max(pos) * 100:.1f} cm, median {np.median(pos) * 100:.1f} cm")
    print(
        f"DBH error, stem slab circle: max |{np.abs(slab).max() * 100:.2f}| cm, "
        f"mean {np.mean(slab) * 100:+.2f} cm"
    )
    print(
        f"DBH error, QSM: max |{np.abs(qsm).max() * 100:.2f}| cm, mean {np.mean(qsm) * 100:+.2f} cm"
    )
    from treesim.plot._surface import surface_from_dtm

    dtm = surface_from_dtm(twin / "dtm.asc")
    terrain = ts.read_plot(fp.plot_file).terrain
    err = dtm(true_xy[:, 0], true_xy[:, 1]) - terrain.height_at(true_xy[:, 0], true_xy[:, 1])
    print(f"DTM under the trees: max |error| {np.abs(err).max() * 100:.2f} cm")
    sim = work / "sim"
    scanner = ["--instrument", "riegl-vz400", "--noise", "--resolution-deg", str(resolution_deg)]
    treesim("plot", "scan", str(twin), "-o", str(sim), "--stations-from", str(fp.e57), *scanner)
    val = work / "validation"
    treesim(
        "validate", str(fp.e57), str(sim / "plot_scan.laz"), "--plot", str(twin / "plot.toml"),
        "-o", str(val),
    )  # fmt: skip
    print("validation, the twin's scan from the E57's stations against the field scan:")
    _print_validation(_validation(val))


def pine(work: Path, resolution_deg: float) -> None:
    from tests.reconstruct.slab_reference import fit_slab
    from treesim.plot._surface import surface_from_dtm

    print("== pine: the TreeLS pine plot (real TLS, 10 x 10 m, ground included)")
    twin = work / "pine_twin"
    treesim("plot", "from-cloud", str(PINE), "-o", str(twin), "--no-progress")
    rows = _twin_rows(twin)
    left = json.loads((twin / "from_cloud.json").read_text())["left_out"]
    print(f"trees in the twin: {len(rows)}, left out: {len(left)}")
    dtm = surface_from_dtm(twin / "dtm.asc")
    worst = 0.0
    clean: list[tuple[float, float | None]] = []  # (stems' DBH / ref - 1, QSM's) on clean slabs
    for r in rows:
        pts = ts.read_cloud(twin / r["field_cloud"]).points
        z0 = float(dtm(np.array([r["x_m"]]), np.array([r["y_m"]]))[0])
        slab = fit_slab(
            pts, z_m=z0 + 1.3, height_m=1.3, centre_xy=(r["x_m"], r["y_m"]),
            radius_m=r["slab_dbh_m"] / 2,
        )  # fmt: skip
        ref = slab.diameter_m
        qsm = r.get("qsm_dbh_m")
        if ref and qsm:
            worst = max(worst, abs(qsm / ref - 1))
        if ref and slab.verdict == "clean":
            clean.append((r["slab_dbh_m"] / ref - 1, qsm / ref - 1 if qsm else None))
        print(
            f"  tree {r['tree_id']:>2}: reference slab {_cm(ref)} ({slab.verdict}), stems "
            f"{_cm(r['slab_dbh_m'])}, QSM {_cm(qsm)}"
            + (f" ({(qsm / ref - 1) * 100:+.1f} %)" if ref and qsm else "")
            + f", height {r['height_m']:.1f} m"
        )
    print(f"largest |QSM DBH / reference - 1|: {worst * 100:.1f} %")
    if clean:
        st = np.array([c[0] for c in clean])
        qs = np.array([c[1] for c in clean if c[1] is not None])
        print(
            f"on the {len(clean)} clean reference slabs: the twin's DBH (stem slab circle) within "
            f"3 % for {int((np.abs(st) <= 0.03).sum())}, largest |error| "
            f"{np.abs(st).max() * 100:.1f} %; "
            f"the QSM's within 3 % for {int((np.abs(qs) <= 0.03).sum())} of {len(qs)}, largest "
            f"{np.abs(qs).max() * 100:.1f} %"
        )
    plan = work / "pine_plan"
    treesim(
        "plan", "--plot", str(twin / "plot.toml"), "-o", str(plan), "--resolution-deg",
        str(resolution_deg), "--no-verify",
    )  # fmt: skip
    n = len((plan / "stations.csv").read_text().strip().splitlines()) - 1
    print(f"stations planned on the twin: {n}")
    sim = work / "pine_sim"
    treesim(
        "plot", "scan", str(twin), "-o", str(sim), "--stations-from",
        str(plan / "stations.csv"), "--instrument", "riegl-vz400", "--noise",
        "--resolution-deg", str(resolution_deg),
    )  # fmt: skip
    val = work / "pine_validation"
    treesim(
        "validate", str(PINE), str(sim / "plot_scan.laz"), "--plot", str(twin / "plot.toml"),
        "-o", str(val),
    )  # fmt: skip
    print("validation, the simulated rescan from the planned stations against the real plot")
    print("(different stations: this measures how the planned design differs from the field's)")
    _print_validation(_validation(val))


def _cm(v: float | None) -> str:
    return "–" if not v else f"{v * 100:.1f} cm"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--section", choices=["synthetic", "pine", "all"], default="all")
    ap.add_argument("--workdir", type=Path, default=ROOT / "out" / "bench_twin")
    ap.add_argument("--resolution-deg", type=float, default=0.2)
    args = ap.parse_args()
    print(
        f"bench_twin ({date.today()}, {platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()})"
    )
    # a fresh folder: treesim reuses a finished twin, scan or reconstruction it finds, and
    # this script measures making them
    shutil.rmtree(args.workdir, ignore_errors=True)
    args.workdir.mkdir(parents=True)
    if args.section in ("synthetic", "all"):
        synthetic(args.workdir, args.resolution_deg)
    if args.section in ("pine", "all"):
        if PINE.is_file():
            pine(args.workdir, args.resolution_deg)
        else:
            print(f"pine: skipped, {PINE} not found (the project's shared data)")


if __name__ == "__main__":
    from benchmarks import docs_part

    with docs_part.recording(docs_part.from_argv("bench-twin"), "bench_twin.py"):
        main()
