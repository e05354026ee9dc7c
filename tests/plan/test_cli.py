"""``treesim plan`` on the command line: a run on one tree, and one-line errors."""

from __future__ import annotations

import json

from treesim.cli import main


def test_plan_one_species_tree(tmp_path, capsys):
    out = tmp_path / "p"
    rc = main(
        [
            "plan",
            "--species",
            "sapling",
            "--facets",
            "8",
            "--resolution-deg",
            "0.2",
            "--tolerance-m",
            "0.03",
            "--samples-per-tree",
            "300",
            "--candidate-spacing-m",
            "1",
            "--no-verify",
            "-o",
            str(out),
        ]
    )
    assert rc == 0
    d = json.loads((out / "plan.json").read_text())
    assert d["goal"]["coverage"] == 0.8 and d["instrument"]["name"] == "riegl-vz400"
    assert d["plan"]["n_stations"] == len(d["plan"]["stations"]) >= 1
    assert d["verification"] is None
    for name in ("stations.csv", "map.png", "curve.png"):
        assert (out / name).stat().st_size > 0
    assert "stations" in capsys.readouterr().out


def test_plan_errors_are_one_line(tmp_path, capsys):
    assert main(["plan", "-o", str(tmp_path / "a")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["treesim: error: give one of --plot PLOT.toml, --species NAME or MESH"]
    (tmp_path / "plot.toml").write_text("")
    assert main(["plan", "--plot", str(tmp_path / "plot.toml"), "-o", str(tmp_path / "b")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    # an empty plot file: one line naming it and what it lacks
    assert len(err) == 1 and err[0].startswith("treesim: error: ")
    assert "plot.toml: no trees" in err[0]
    assert main(["plan", "--plot", str(tmp_path / "absent.toml"), "-o", str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("treesim: error: --plot")
    rc = main(
        ["plan", "--species", "sapling", "--max-field-time-min", "1", "-o", str(tmp_path / "c")]
    )
    assert rc == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "less than one station" in err[0]


def test_plan_a_generated_plot_file(tmp_path, capsys):
    """``plot generate`` writes the files ``plan --plot`` reads: every tree is planned."""
    plot_dir = tmp_path / "plot"
    assert (
        main(
            [
                "plot",
                "generate",
                "--species",
                "sapling",
                "--stems-per-ha",
                "400",
                "--radius-m",
                "5",
                "--seed",
                "2",
                "--facets",
                "8",
                "-o",
                str(plot_dir),
            ]
        )  # fmt: skip
        == 0
    )
    out = tmp_path / "plan"
    rc = main(
        ["plan", "--plot", str(plot_dir / "plot.toml"), "--resolution-deg", "0.3",
         "--samples-per-tree", "200", "--candidate-spacing-m", "2", "--no-verify",
         "-o", str(out)]
    )  # fmt: skip
    assert rc == 0
    d = json.loads((out / "plan.json").read_text())
    ids = [t["tree_id"] for t in d["trees"]]
    n_trees = len((plot_dir / "trees.csv").read_text().strip().splitlines()) - 1
    assert n_trees >= 2 and ids == list(range(1, n_trees + 1))
    assert d["plan"]["n_stations"] >= 1


def test_plan_one_mesh_tree_with_verification(tmp_path, capsys):
    """A tree from a mesh file, away from the origin, planned and verified (the
    verification scan asks the plot for the tree's bounds, and loads it again after
    releasing it)."""
    import numpy as np
    import trimesh

    from treesim.plan.sources import mesh_tree_plot, species_tree_plot

    parts = species_tree_plot("sapling", facets=8).tree_parts(1)
    v = np.concatenate([p.vertices for p in parts])
    off = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    f = np.concatenate([p.faces + o for p, o in zip(parts, off, strict=True)])
    path = tmp_path / "tree.ply"
    trimesh.Trimesh(v + (500.0, 300.0, 12.0), f, process=False).export(path)
    plot = mesh_tree_plot(path)
    held = plot.tree_parts(1)
    assert np.allclose(plot.tree_bounds(1)[0], v.min(axis=0) + (500.0, 300.0, 12.0))
    plot.release()
    assert plot.tree_parts(1) == held  # the parts as read, not the file read again
    out = tmp_path / "p"
    rc = main(
        ["plan", str(path), "--resolution-deg", "0.5", "--tolerance-m", "0.05",
         "--samples-per-tree", "200", "--band-samples", "60", "--candidate-spacing-m", "2",
         "--grid-spacing-m", "5", "-o", str(out)]
    )  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    d = json.loads((out / "plan.json").read_text())
    assert d["verification"]["points"] > 0 and d["trees"][0]["verified"]["points"] > 0
