"""The batch accepts plots: a plot folder (or plot.toml) gives one summary row per tree."""

from __future__ import annotations

import csv
import io
from dataclasses import replace

from pipeline.batch import discover_inputs, run_batch
from pipeline.cli import main
from pipeline.cli.progress import BatchProgressBar
from pipeline.params import run_preset


def test_a_plot_in_a_batch_gives_a_row_per_tree_and_is_reused(tmp_path, capsys):
    out = str(tmp_path / "in" / "p1")
    argv = ["plot", "generate", "--species", "sapling", "--stems-per-ha", "300",
            "--radius-m", "4", "--seed", "2", "--facets", "8", "-o", out]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    trees, skipped = discover_inputs([tmp_path / "in"])
    # the plot's own files (trees.csv, map.png) are not taken for trees
    assert [(t.id, t.kind) for t in trees] == [("p1", "plot")] and skipped == []
    p = run_preset("draft")
    p = replace(p, scan=replace(p.scan, n_stations=2, distance_m=1.0))
    log = io.StringIO()
    bar = BatchProgressBar(log, tty=False)
    r = run_batch([tmp_path / "in"], p, tmp_path / "out", progress=bar)
    # the log counts the inputs (one plot), the summary its trees
    assert log.getvalue().startswith(
        "batch: 1 input (1 plot), 0 unchanged (not run again), 1 to run\n"
    )
    assert "batch: 1/1 inputs" in log.getvalue() and r.tally("trees").startswith("2 trees: 2 run")
    assert [(row["id"], row["tree_id"], row["status"]) for row in r.rows] == [
        ("p1", 1, "ok"),
        ("p1", 2, "ok"),
    ]
    figs = list(csv.DictReader(open(tmp_path / "out" / "trees" / "p1" / "tree_figures.csv")))
    for row, fig in zip(r.rows, figs, strict=True):
        assert row["scan_points"] == int(fig["points"]) > 0
        assert row["vs_mesh_coverage"] == float(fig["coverage"])
    again = run_batch([tmp_path / "in"], p, tmp_path / "out")
    assert [row["reused"] for row in again.rows] == [True, True]
    summary = list(csv.DictReader(open(tmp_path / "out" / "summary.csv")))
    assert [s["tree_id"] for s in summary] == ["1", "2"]
