"""``treesim model generate | list | from-qsm`` through ``treesim.cli.main``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from treesim.cli import main
from treesim.io import load_mesh
from treesim.models import (
    SPECIES as PRESETS,
)
from treesim.models import (
    CylinderTable,
    generate_tree,
    read_cylinders,
    write_cylinders,
)

TRUTH_NAMES = (
    "dbh_m",
    "height_m",
    "volume_total_m3",
    "volume_stem_m3",
    "volume_branch_m3",
    "n_cylinders",
    "branches_per_order",
)


def _one_line_error(capsys, *fragments: str) -> None:
    err = capsys.readouterr().err.strip()
    assert err.startswith("treesim: error:") and "\n" not in err, err
    for fragment in fragments:
        assert fragment in err, err


def test_generate_writes_mesh_table_and_truth(tmp_path: Path, capsys) -> None:
    out = tmp_path / "trees" / "tree.obj"
    rc = main(
        ["model", "generate", "--species", "sapling", "--leaves", "--seed", "3", "-o", str(out)]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "sapling (seed 3)" in printed and "tree.truth.json" in printed
    table_path = tmp_path / "trees" / "tree.cylinders.csv"
    truth_path = tmp_path / "trees" / "tree.truth.json"
    assert out.is_file() and out.with_suffix(".mtl").is_file()
    assert table_path.is_file() and truth_path.is_file()

    expected = generate_tree("sapling", seed=3, leaves=True)
    # The cylinder table is the generator's, exactly.
    assert read_cylinders(table_path).identical(expected.cylinders)
    truth = json.loads(truth_path.read_text())
    reference = expected.truth(32)
    for name in TRUTH_NAMES[:-1]:
        assert truth[name] == reference[name], name
    assert truth["branches_per_order"] == {
        str(k): v for k, v in reference["branches_per_order"].items()
    }
    assert truth["species"] == "sapling" and truth["seed"] == 3 and truth["facets"] == 32
    assert truth["leaves"] is True and truth["n_leaves"] == expected.n_leaves > 0
    assert abs(truth["mesh_volume_error"]) < 0.01
    assert truth["files"] == {"mesh": "tree.obj", "cylinders": "tree.cylinders.csv"}
    assert truth["params"]["name"] == "sapling"
    # The OBJ keeps the parts: a wood group and a leaf group, with every triangle.
    parts = {p.label: p for p in load_mesh(out)}
    assert set(parts) == {"wood", "leaf"}
    assert len(parts["wood"].faces) == truth["n_triangles_wood"]
    assert len(parts["leaf"].faces) == truth["n_triangles_leaf"]
    wood = expected.wood_mesh(32)
    np.testing.assert_allclose(
        np.sort(parts["wood"].vertices[:, 2]), np.sort(wood.vertices[:, 2]), atol=1e-12, rtol=0
    )


def test_generate_is_reproducible_and_writes_ply(tmp_path: Path) -> None:
    paths = []
    for k in range(2):
        out = tmp_path / f"run{k}" / "tree.ply"
        argv = ["model", "generate", "--species", "balsam-fir", "--facets", "8", "-o", str(out)]
        assert main(argv) == 0
        paths.append(out)
    for name in ("tree.ply", "tree.cylinders.csv"):
        assert (paths[0].parent / name).read_bytes() == (paths[1].parent / name).read_bytes()
    parts = {p.label: p for p in load_mesh(paths[0])}
    assert set(parts) == {"wood", "leaf"}  # conifers keep their shoots by default
    truth = json.loads((paths[0].parent / "tree.truth.json").read_text())
    assert truth["facets"] == 8 and truth["n_triangles_wood"] == len(parts["wood"].faces)


def test_generate_without_leaves(tmp_path: Path) -> None:
    out = tmp_path / "fir.obj"
    assert (
        main(["model", "generate", "--species", "balsam-fir", "--no-leaves", "-o", str(out)]) == 0
    )
    assert {p.label for p in load_mesh(out)} == {"wood"}
    truth = json.loads((tmp_path / "fir.truth.json").read_text())
    assert truth["n_leaves"] == 0 and truth["leaves"] is False


def test_list_shows_every_preset_with_figures(capsys) -> None:
    assert main(["model", "list", "--facets", "8"]) == 0
    out = capsys.readouterr().out
    assert "DBH cm" in out and "height m" in out and "triangles" in out
    lines = {line.split()[0]: line for line in out.splitlines()[2:] if line.strip()}
    for name, params in PRESETS.items():
        assert name in lines
        assert params.description in lines[name]
        truth = generate_tree(name, seed=0).truth(8)
        assert f"{truth['dbh_m'] * 100:.1f}" in lines[name]
        assert f"{truth['n_cylinders']:,}" in lines[name]
    assert main(["model", "list", "--sources", "--facets", "8"]) == 0
    assert capsys.readouterr().out.count("Weber & Penn") >= len(PRESETS)


@pytest.mark.parametrize(
    ("argv", "fragments"),
    [
        (["--species", "oak", "-o", "t.obj"], ["unknown species 'oak'", "aspen"]),
        (["--species", "sapling", "-o", "t.xyz"], ["t.xyz", ".obj"]),
    ],
)
def test_generate_bad_input_is_one_line_and_nonzero(
    argv: list[str], fragments: list[str], tmp_path: Path, capsys, monkeypatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["model", "generate", *argv]) == 1
    _one_line_error(capsys, *fragments)
    assert not list(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize(
    ("argv", "fragments"),
    [
        (["-o", "t.obj"], ["--species"]),
        (["--species", "sapling", "--facets", "2", "-o", "t.obj"], ["--facets", ">= 3", "'2'"]),
        (["--species", "sapling", "--seed", "-4", "-o", "t.obj"], ["--seed", ">= 0", "'-4'"]),
    ],
)
def test_generate_usage_errors_exit_2(argv, fragments, tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(["model", "generate", *argv])
    assert info.value.code == 2
    _one_line_error(capsys, *fragments)
    assert not list(tmp_path.iterdir())  # nothing written


def _small_table() -> CylinderTable:
    return CylinderTable.from_endpoints(
        [[0, 0, 0], [0, 0, 1.0], [0.05, 0, 0.5]],
        [[0, 0, 1.0], [0.1, 0, 2.0], [0.8, 0, 0.9]],
        [0.1, 0.09, 0.03],
        parent=[-1, 0, 0],
        branch=[1, 1, 2],
        branch_order=[0, 0, 1],
    )


def test_from_qsm_joints(tmp_path: Path, capsys) -> None:
    table_path = write_cylinders(tmp_path / "t.csv", _small_table())
    out = tmp_path / "t.ply"
    assert main(["model", "from-qsm", str(table_path), "--facets", "10", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "miter joints" in printed
    assert "1 of 1 branch starts sunk into their parents" in printed
    mitred = load_mesh(out)[0]
    # Two tubes: the stem (2 sides, 2 caps, an annulus at its 0.1 -> 0.09 m radius step)
    # and the branch (its side, the plug's side reaching back into the stem, 2 caps),
    # 2 triangles per facet each.
    assert len(mitred.faces) == (2 + 2 + 2 + 1 + 1 + 2 + 2 + 2) * 10
    # the plug runs back along the branch's axis to where it passes closest to the
    # stem's (the z axis): x = 0 at z = 0.5 - 0.05 * 0.4 / 0.75; its base ring, of the
    # branch's 0.03 m radius, lies inside the 0.1 m stem
    v = mitred.vertices
    base = v[np.abs(v[:, 0]) < 0.03 + 1e-9]
    base = base[np.abs(base[:, 2] - (0.5 - 0.05 * 0.4 / 0.75)) < 0.03 + 1e-9]
    assert len(base) >= 10
    assert main(["model", "from-qsm", str(table_path), "--joints", "separate", "-o", str(out)]) == 0
    assert len(load_mesh(out)[0].faces) == 3 * 4 * 32


def test_from_qsm_bad_tables(tmp_path: Path, capsys) -> None:
    assert main(["model", "from-qsm", str(tmp_path / "absent.csv"), "-o", "x.ply"]) == 1
    _one_line_error(capsys, "not found")
    bad = tmp_path / "bad.csv"
    bad.write_text(
        "radius,length,start_x,start_y,start_z,axis_x,axis_y,axis_z,parent,branch,branch_order\n"
        "0.1,1,0,0,0,0,0,1,0,1,0\n"
        "-0.1,1,0,0,1,0,0,1,1,1,0\n"
    )
    assert main(["model", "from-qsm", str(bad), "-o", str(tmp_path / "x.ply")]) == 1
    _one_line_error(capsys, "row 2", "radius_m is -0.1")
    assert main(["model", "from-qsm", str(bad), "-o", str(tmp_path / "x.stl")]) == 1
    _one_line_error(capsys, "x.stl")
