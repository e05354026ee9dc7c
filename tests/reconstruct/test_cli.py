"""``treesim reconstruct`` end to end and its one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import messages
from treesim.cli import main

REQUIRED = {
    "dbh_m",
    "height_m",
    "volume_total_m3",
    "volume_stem_m3",
    "volume_branch_m3",
    "n_cylinders",
    "watertight",
}


def _write_xyz(path: Path, pts: np.ndarray) -> Path:
    np.savetxt(path, pts, fmt="%.6f")
    return path


def test_reconstruct_bundled_coffee_tree_writes_every_output(tmp_path, capsys):
    cloud = Path(__file__).resolve().parents[2] / "pipeline/data/coffee_tree/cloud.txt"
    assert main(["reconstruct", str(cloud), "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "DBH" in out and "volume" in out
    tree = json.loads((tmp_path / "tree.json").read_text())
    assert REQUIRED <= set(tree)
    assert tree["n_cylinders"] > 100 and tree["watertight"] is True
    assert (tmp_path / "tree.ply").stat().st_size > 0
    assert (tmp_path / "cylinders.csv").read_text().startswith("radius,length,start_x")
    # the mesh: one closed tube per branch (or per run between sharp bends), every branch
    # start sunk into its parent; its volume is the table's prisms plus those plugs
    from treesim.geometry import mesh_parts
    from treesim.io import load_scene
    from treesim.models import mesh_volume, read_cylinders

    scene = load_scene([tmp_path / "tree.ply"])
    parts = mesh_parts(scene.vertices, scene.faces)
    table = read_cylinders(tmp_path / "cylinders.csv")
    branches = len(np.unique(table.branch))
    assert parts.n_parts == parts.n_closed == tree["n_tubes"] >= branches
    mesh = tree["diagnostics"]["mesh"]
    assert mesh["branch_starts"] == branches - 1
    assert mesh["branch_starts_sunk"] >= 0.9 * mesh["branch_starts"]  # 67 of 67 measured
    facets = tree["params"]["facets"]
    prisms = float(table.prism_volume_m3(facets).sum())
    assert 0 < tree["junction_volume_m3"] < 0.05 * prisms
    assert tree["mesh_volume_m3"] == pytest.approx(
        mesh_volume(scene.vertices, scene.faces), rel=1e-9
    )
    assert tree["mesh_volume_m3"] == pytest.approx(prisms + tree["junction_volume_m3"], rel=1e-6)


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "treesim.cli", *args], capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    ("case", "needle"),
    [
        ("few", "points"),
        ("plane", "plane"),
        ("identical", "identical"),
        ("nan", "NaN"),
        ("missing", "not found"),
    ],
)
def test_bad_clouds_give_a_clear_one_line_error(tmp_path, case, needle):
    rng = np.random.default_rng(0)
    if case == "few":
        pts = rng.normal(size=(50, 3))
    elif case == "plane":
        pts = np.c_[rng.uniform(0, 5, (2000, 2)), np.full(2000, 1.0)]
    elif case == "identical":
        pts = np.tile([[1.0, 2.0, 3.0]], (1000, 1))
    elif case == "nan":
        pts = rng.normal(size=(2000, 3))
        pts[17, 1] = np.nan
    path = tmp_path / "c.xyz" if case != "missing" else tmp_path / "none.xyz"
    if case != "missing":
        _write_xyz(path, pts)
    res = _run(["reconstruct", str(path), "-o", str(tmp_path / "out")])
    assert res.returncode == 1
    assert "Traceback" not in res.stderr
    lines = messages(res.stderr)
    assert len(lines) == 1 and lines[0].startswith("treesim: error:"), res.stderr
    assert needle.lower() in lines[0].lower(), lines[0]
    assert not (tmp_path / "out" / "tree.json").exists()
