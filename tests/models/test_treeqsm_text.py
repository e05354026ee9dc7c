"""TreeQSM's text export (``save_model_text``): both layouts, detection and bad rows.

TreeQSM 2.4's ``save_model_text`` (version 1.1.0) writes ``cylinder_NAME.txt``: a
tab-separated header of 13 names (``radius (m)``, ..., ``start_point``,
``axis_direction``, ...) over 17 columns of ``%g`` numbers rounded to 0.1 mm; version
1.0.0 (TreeQSM 2.3) wrote ``cyl_data_NAME.txt`` without a header, 15 columns. The files
here are written the same way from known tables.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from treesim.errors import EmptyInputError, InputFormatError, ModelError
from treesim.models import TREEQSM_TEXT_COLUMNS, CylinderTable, read_cylinders

#: aRchi's TreeQSM table of its Tree_1 (tests/data/trees/PROVENANCE.md).
ARCHI_QSM = (
    Path(__file__).resolve().parents[1] / "data" / "trees" / "archi_tree1" / "Tree_1_TreeQSM.txt"
)
#: The 15 columns in the order of TreeQSM's ``cylinder`` structure, written out here by
#: hand (not taken from the reader): added and UnmodRadius before branch.
STRUCTURE_ORDER = (
    "radius", "length", "start_x", "start_y", "start_z", "axis_x", "axis_y", "axis_z",
    "parent", "extension", "added", "unmod_radius", "branch", "branch_order",
    "position_in_branch",
)  # fmt: skip

HEADER_24 = (
    "radius (m)\tlength (m)\tstart_point\taxis_direction\tparent\textension\tbranch\t"
    "branch_order\tposition_in_branch\tmad\tSurfCov\tadded\tUnmodRadius (m)"
)


def _columns(table: CylinderTable, width: int, names=None) -> list[np.ndarray]:
    """The table's columns in the export's order, rounded as TreeQSM rounds them."""
    r4 = lambda a: np.round(10000 * np.asarray(a, dtype=float)) / 10000  # noqa: E731
    n = table.n_cylinders
    cols = {
        "radius": r4(table.radius_m),
        "length": r4(table.length_m),
        **{f"start_{c}": r4(table.start[:, k]) for k, c in enumerate("xyz")},
        **{f"axis_{c}": r4(table.axis[:, k]) for k, c in enumerate("xyz")},
        "parent": table.parent + 1,
        "extension": table.extension + 1,
        "branch": table.branch,
        "branch_order": table.branch_order,
        "position_in_branch": table.position_in_branch,
        "mad": np.full(n, 0.0012),
        "surf_cov": np.full(n, 0.875),
        "added": table.added.astype(int),
        "unmod_radius": r4(table.unmod_radius_m),
    }
    return [cols[name] for name in names or TREEQSM_TEXT_COLUMNS[width]]


def _write_text(path: Path, table: CylinderTable, width: int = 17, names=None) -> Path:
    cols = _columns(table, width, names)
    lines = ["\t".join(f"{float(c[i]):g}" for c in cols) for i in range(table.n_cylinders)]
    header = [HEADER_24] if width == 17 else []
    path.write_text("\n".join(header + lines) + "\n")
    return path


def _small() -> CylinderTable:
    return CylinderTable(
        start=[[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0], [0, 0, 0.8]],
        axis=[[0, 0, 1], [0, 0, 1], [0, 0, 1], [1, 0, 0]],
        length_m=[0.5, 0.5, 0.5, 0.3],
        radius_m=[0.05, 0.04, 0.03, 0.01],
        parent=[-1, 0, 1, 1],
        branch=[1, 1, 1, 2],
        branch_order=[0, 0, 0, 1],
        position_in_branch=[1, 2, 3, 1],
        extension=[1, 2, -1, -1],
    )


@pytest.mark.parametrize("width", [17, 15])
def test_both_layouts_read_back_the_table(tmp_path: Path, width: int) -> None:
    name = "cylinder_tree.txt" if width == 17 else "cyl_data_tree.txt"
    path = _write_text(tmp_path / name, _small(), width)
    for fmt in (None, "treeqsm-txt"):  # detected from the content, or named
        table = read_cylinders(path, format=fmt)
        expected = _small()
        for field in ("start", "axis", "length_m", "radius_m"):
            np.testing.assert_array_equal(getattr(table, field), getattr(expected, field))
        for field in ("parent", "extension", "branch", "branch_order", "position_in_branch"):
            assert getattr(table, field).tolist() == getattr(expected, field).tolist(), field
        assert table.summary() == expected.summary()


def test_the_structure_order_is_told_apart_by_its_whole_number_columns(tmp_path: Path) -> None:
    """A headerless 15-column table in the ``cylinder`` structure's order reads back the
    same table as TreeQSM 2.3's order (it was read as 2.3's and refused: "column
    branch_order holds 0.05, not a whole number")."""
    small = dataclasses.replace(_small(), unmod_radius_m=[0.051, 0.042, 0.033, 0.014])
    a = read_cylinders(_write_text(tmp_path / "a.txt", small, 15))
    b = read_cylinders(_write_text(tmp_path / "b.txt", small, 15, STRUCTURE_ORDER))
    for field in ("start", "axis", "length_m", "radius_m", "unmod_radius_m", "added"):
        np.testing.assert_array_equal(getattr(b, field), getattr(a, field))
    for field in ("parent", "extension", "branch", "branch_order", "position_in_branch"):
        assert getattr(b, field).tolist() == getattr(small, field).tolist(), field
    np.testing.assert_array_equal(b.unmod_radius_m, [0.051, 0.042, 0.033, 0.014])


def test_archis_treeqsm_table_reads_as_its_provenance_measured_it() -> None:
    """aRchi's Tree_1 table (the structure's order): PROVENANCE.md's figures, measured from
    the file when it was added: 2,271 cylinders, 233 branches, trunk (branch 1) 2,035 L and
    total 3,899 L as the sum of pi r^2 l, DBH 49.4 cm."""
    t = read_cylinders(ARCHI_QSM)
    assert t.n_cylinders == 2271
    assert len(np.unique(t.branch)) == 233
    vol = np.pi * t.radius_m**2 * t.length_m
    assert vol[t.branch == 1].sum() * 1e3 == pytest.approx(2035, abs=0.5)
    assert vol.sum() * 1e3 == pytest.approx(3899, abs=0.5)
    assert t.dbh_m() * 1e2 == pytest.approx(49.4, abs=0.05)
    assert (t.branch_order[t.branch == 1] == 0).all() and t.parent[0] == -1


@pytest.mark.shared_data
@pytest.mark.parametrize("width", [17, 15])
def test_coffee_tree_from_the_text_export(treeqsm_csv: Path, tmp_path: Path, width: int) -> None:
    csv_table = read_cylinders(treeqsm_csv)
    table = read_cylinders(_write_text(tmp_path / "cylinder_coffee.txt", csv_table, width))
    assert table.n_cylinders == 1136
    assert table.total_volume_m3 * 1e3 == pytest.approx(21.6, abs=0.1)
    assert table.stem_volume_m3 * 1e3 == pytest.approx(10.8, abs=0.1)
    assert table.dbh_m() * 1e2 == pytest.approx(7.35, abs=0.05)
    assert table.branches_per_order() == csv_table.branches_per_order()
    np.testing.assert_array_equal(table.parent, csv_table.parent)


def test_bad_text_exports(tmp_path: Path) -> None:
    good = _write_text(tmp_path / "good.txt", _small()).read_text().splitlines()
    ragged = tmp_path / "ragged.txt"
    ragged.write_text("\n".join([good[0], good[1], good[2].rsplit("\t", 1)[0], *good[3:]]))
    with pytest.raises(InputFormatError, match=r"row 2 has 16 columns but row 1 has 17"):
        read_cylinders(ragged)
    odd = tmp_path / "odd.txt"
    odd.write_text("\n".join("\t".join(line.split("\t")[:16]) for line in good[1:]))
    with pytest.raises(InputFormatError, match=r"row 1 has 16 columns.*17 or 15"):
        read_cylinders(odd, format="treeqsm-txt")
    negative = tmp_path / "negative.txt"
    rows = [line.split("\t") for line in good[1:]]
    rows[2][0] = "-0.03"
    negative.write_text("\n".join([good[0], *("\t".join(r) for r in rows)]))
    with pytest.raises(ModelError, match=r"row 3: radius_m is -0.03"):
        read_cylinders(negative)
    cycle = tmp_path / "cycle.txt"
    rows = [line.split("\t") for line in good[1:]]
    rows[0][8] = "3"  # row 1's parent is row 3, whose parent chain leads back to row 1
    cycle.write_text("\n".join([good[0], *("\t".join(r) for r in rows)]))
    with pytest.raises(ModelError, match=r"parent links form a cycle"):
        read_cylinders(cycle)
    header_only = tmp_path / "header_only.txt"
    header_only.write_text(good[0] + "\n")
    with pytest.raises(EmptyInputError, match="no rows"):
        read_cylinders(header_only)
