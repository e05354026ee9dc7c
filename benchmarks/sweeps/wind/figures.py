"""The wind sweep's figures for the docs: per tree and wind, the reconstruction's errors
against the exact truth (DBH, stem, branch and total volume), the simulated scan against
the truth mesh (AVOHD accuracy/completeness means, coverage at τ) and against the still
reconstruction (vs_mesh), and the windy field scan's wind_displacement_m.

    python benchmarks/sweeps/wind/figures.py   # after the sweep (reads points/ and trees/)
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent


def main() -> None:
    import treesim as ts

    doc = json.loads((HERE / "sweep.json").read_text())
    windy = {(t["id"], t["wind_speed_m_s"]) for t in doc.get("trees_in_wind", [])}
    rows = list(csv.DictReader(open(HERE / "sweep.csv", newline="")))
    print(
        "tree          U m/s  DBH err  Vstem err  Vbranch err  Vtotal err  "
        "truth acc/compl mm  truth cov  mesh acc mm  mesh cov  field disp p50/p95 mm  time s"
    )
    for r in rows:
        if r["status"] != "ok":
            print(r["tree"], r["scan.scanner.wind_speed_m_s"], r["status"])
            continue
        u = float(r["scan.scanner.wind_speed_m_s"])
        run = json.loads((HERE / "points" / r["id"] / "run.json").read_text())["reconstruction"]
        folder = HERE / "trees" / r["tree"]
        if (r["tree"], u) in windy:
            (folder,) = (HERE / "trees").glob(f"wind-{u:g}-*/{r['tree']}")
        truth = json.loads((folder / "tree.json").read_text())["truth"]
        field = ts.read_cloud(folder / "field.ply")
        d = np.asarray(field.fields.get("wind_displacement_m", np.zeros(1)))
        rel = {
            k: run[f"volume_{k}_m3"] / truth[f"volume_{k}_m3"] - 1
            for k in ("stem", "branch", "total")
        }
        print(
            f"{r['tree']:<13} {u:>5g}  {(run['dbh_m'] / truth['dbh_m'] - 1):+7.1%}  "
            f"{rel['stem']:+9.1%}  {rel['branch']:+11.1%}  {rel['total']:+10.1%}  "
            f"{float(r['vs_truth_accuracy_mean_m']) * 1e3:8.1f}/"
            f"{float(r['vs_truth_completeness_mean_m']) * 1e3:<8.1f}  "
            f"{float(r['vs_truth_coverage']):9.1%}  "
            f"{float(r['vs_mesh_accuracy_mean_m']) * 1e3:11.1f}  "
            f"{float(r['vs_mesh_coverage']):8.1%}  "
            f"{np.percentile(d, 50) * 1e3:10.1f}/{np.percentile(d, 95) * 1e3:<10.1f}  "
            f"{float(r['time_total_s']):6.1f}"
        )


if __name__ == "__main__":
    main()
