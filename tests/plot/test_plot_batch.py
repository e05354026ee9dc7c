"""The batch accepts plots: a plot folder (or plot.toml) gives one summary row per tree."""

from __future__ import annotations

import csv
import io
from dataclasses import replace

from treesim.batch import discover_inputs, run_batch
from treesim.cli import main
from treesim.cli.progress import BatchProgressBar
from treesim.params import run_preset


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


def test_a_changed_tree_file_runs_the_plot_again(tmp_path):
    # the plot's hash covers the files its trees are made from, not only plot.toml
    from tests.conftest import box_arrays
    from treesim.io.mesh import write_mesh
    from treesim.plot import Plot, PlotTree
    from treesim.plot.io import write_plot

    d = tmp_path / "p"
    d.mkdir()
    write_mesh(d / "stem.ply", *box_arrays((-0.1, -0.1, 0.0), (0.1, 0.1, 2.0)))
    tree = PlotTree(tree_id=1, x_m=1.0, y_m=0.0, source="mesh", path="stem.ply")
    write_plot(d / "plot.toml", Plot([tree], radius_m=3.0, base_dir=str(d)))
    p = run_preset("draft")
    p = replace(p, scan=replace(p.scan, n_stations=2, distance_m=2.0))
    first = run_batch([d / "plot.toml"], p, tmp_path / "out", executor="inline")
    assert [row["status"] for row in first.rows] == ["ok"]
    again = run_batch([d / "plot.toml"], p, tmp_path / "out", executor="inline")
    assert [row["reused"] for row in again.rows] == [True]
    write_mesh(d / "stem.ply", *box_arrays((-0.1, -0.1, 0.0), (0.1, 0.1, 2.5)))
    third = run_batch([d / "plot.toml"], p, tmp_path / "out", executor="inline")
    assert [row.get("reused", False) for row in third.rows] == [False]
    assert third.rows[0]["height_m"] != first.rows[0]["height_m"]
