"""CylinderTable: reading, validating, measuring and writing QSM cylinder tables."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from treesim.errors import EmptyInputError, InputFormatError, ModelError, TreesimError
from treesim.models import TREESIM_COLUMNS, CylinderTable, read_cylinders, write_cylinders

# ---------------------------------------------------------------------------- helpers

TREEQSM_HEADER = (
    "radius,length,start_x,start_y,start_z,axis_x,axis_y,axis_z,parent,extension,added,"
    "unmod_radius,branch,branch_order,position_in_branch,surf_cov,mad"
)


def _treeqsm_rows() -> list[list[str]]:
    """A valid 4-row TreeQSM table: a 3-cylinder stem and one branch off row 2."""
    text = """
        0.05,0.5,0,0,0,  0,0,1, 0,2,0,0.05,1,0,1,1,0
        0.04,0.5,0,0,0.5,0,0,1, 1,3,0,0.04,1,0,2,1,0
        0.03,0.5,0,0,1,  0,0,1, 2,0,0,0.03,1,0,3,1,0
        0.01,0.3,0,0,0.8,1,0,0, 2,0,0,0.01,2,1,1,1,0
    """
    return [[c.strip() for c in line.split(",")] for line in text.split("\n") if line.strip()]


def _write_treeqsm(path: Path, rows: list[list[str]], header: str = TREEQSM_HEADER) -> Path:
    path.write_text(header + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return path


def _column(name: str) -> int:
    return TREEQSM_HEADER.split(",").index(name)


def _stem(
    z0: float = 0.0, radii: tuple[float, ...] = (0.1, 0.09, 0.08, 0.07, 0.06)
) -> CylinderTable:
    """A vertical stem of 0.5 m cylinders starting at z0, one branch."""
    n = len(radii)
    return CylinderTable(
        start=np.column_stack([np.zeros(n), np.zeros(n), z0 + 0.5 * np.arange(n)]),
        axis=np.tile([0.0, 0.0, 1.0], (n, 1)),
        length_m=np.full(n, 0.5),
        radius_m=np.array(radii),
        parent=np.arange(n) - 1,
        branch=np.ones(n),
        branch_order=np.zeros(n),
        position_in_branch=np.arange(n) + 1,
    )


# ---------------------------------------------------------------------------- coffee tree


@pytest.mark.shared_data
def test_coffee_treeqsm_matches_published_figures(treeqsm_csv: Path) -> None:
    table = read_cylinders(treeqsm_csv)
    assert table.n_cylinders == 1136
    assert table.total_volume_m3 * 1e3 == pytest.approx(21.6, abs=0.1)
    assert table.stem_volume_m3 * 1e3 == pytest.approx(10.8, abs=0.1)
    assert table.dbh_m() * 1e2 == pytest.approx(7.35, abs=0.05)
    assert table.stem_volume_m3 + table.branch_volume_m3 == pytest.approx(table.total_volume_m3)
    assert table.height_m == pytest.approx(3.7, abs=0.1)
    # Georeferenced-ish coordinates are kept as they are.
    assert table.start[:, 2].min() == pytest.approx(253.887)

    summary = table.summary()
    assert set(summary) == {
        "dbh_m",
        "height_m",
        "volume_total_m3",
        "volume_stem_m3",
        "volume_branch_m3",
        "n_cylinders",
        "branches_per_order",
    }
    assert summary["n_cylinders"] == 1136
    assert summary["branches_per_order"][0] == 1
    assert sum(summary["branches_per_order"].values()) == np.unique(table.branch).size
    # The file's parent column is 1-based; the table's is 0-based, -1 for the root.
    assert table.parent[0] == -1 and table.parent[1] == 0
    assert read_cylinders(treeqsm_csv, format="treeqsm").identical(table)


@pytest.mark.shared_data
def test_coffee_simpleforest(simpleforest_csv: Path) -> None:
    table = read_cylinders(simpleforest_csv)
    assert table.n_cylinders == 1149
    pi_r2_l = math.pi * float(np.sum(table.radius_m**2 * table.length_m))
    assert pi_r2_l * 1e3 == pytest.approx(30.0, abs=0.2)
    assert table.total_volume_m3 == pytest.approx(pi_r2_l)

    with simpleforest_csv.open() as fh:
        rows = list(csv.DictReader(fh, skipinitialspace=True))
    ids = [int(r["ID"]) for r in rows]
    # Derived lengths agree with the file's own length column (6 decimals there).
    file_length = np.array([float(r["length"]) for r in rows])
    np.testing.assert_allclose(table.length_m, file_length, atol=1e-5, rtol=0)
    # parentID is mapped ID -> row; SimpleForest children start where their parent ends.
    for i, r in enumerate(rows):
        pid = int(r["parentID"])
        assert table.parent[i] == (-1 if pid == -1 else ids.index(pid))
    child = table.parent >= 0
    np.testing.assert_allclose(
        table.start[child], table.end[table.parent[child]], atol=1e-5, rtol=0
    )
    assert table.branches_per_order()[0] == 1
    np.testing.assert_array_equal(table.branch_order, [int(r["branchOrder"]) for r in rows])


@pytest.mark.shared_data
def test_coffee_round_trip_is_exact(treeqsm_csv: Path, tmp_path: Path) -> None:
    table = read_cylinders(treeqsm_csv)
    out = write_cylinders(tmp_path / "coffee.csv", table)
    back = read_cylinders(out)
    assert back.identical(table)
    with out.open() as fh:
        header = next(csv.reader(fh))
    assert tuple(header) == TREESIM_COLUMNS


# ---------------------------------------------------------------------------- round trip


def test_round_trip_exact_with_georeferenced_frusta_and_tags(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    n = 50
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    table = CylinderTable(
        start=rng.uniform(-5, 5, (n, 3)) + [512_345.678, 5_432_109.876, 254.0],
        axis=axis,
        length_m=rng.uniform(0.01, 0.3, n),
        radius_m=rng.uniform(0.002, 0.1, n),
        end_radius_m=rng.uniform(0.002, 0.1, n),
        parent=np.arange(n) - 1,
        branch=np.arange(n) // 10 + 1,
        branch_order=np.arange(n) // 10,
        position_in_branch=np.arange(n) % 10 + 1,
        tag=rng.choice(["measured", "interpolated", "modelled"], n),
        extension=np.where(np.arange(n) < n - 1, np.arange(n) + 1, -1),
        added=rng.random(n) < 0.3,
        unmod_radius_m=rng.uniform(0.002, 0.1, n),
    ).validate()
    out = write_cylinders(tmp_path / "t.csv", table)
    back = read_cylinders(out)
    assert back.identical(table)
    assert np.array_equal(back.start, table.start)  # bit for bit, not approx
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows[0]["parent"] == "0" and rows[1]["parent"] == "1"  # 1-based, 0 = none
    assert {r["tag"] for r in rows} <= {"measured", "interpolated", "modelled"}


def test_defaults_fill_optional_columns() -> None:
    table = _stem()
    np.testing.assert_array_equal(table.end_radius_m, table.radius_m)
    np.testing.assert_array_equal(table.unmod_radius_m, table.radius_m)
    assert list(table.tag) == ["measured"] * 5
    assert (table.extension == -1).all() and not table.added.any()
    assert table.start.dtype == np.float64 and table.parent.dtype == np.int64
    with pytest.raises(ValueError):
        table.radius_m[0] = 1.0  # stored read-only


# ---------------------------------------------------------------------------- measures


def test_dbh_picks_the_crossing_stem_cylinder() -> None:
    table = _stem(z0=100.0)
    # base z = 100; 101.3 lies in the third cylinder (101.0..101.5).
    assert table.dbh_m() == pytest.approx(0.16)
    assert table.dbh_m(height_m=0.2) == pytest.approx(0.2)
    # Above the stem: the nearest (top) cylinder.
    assert table.dbh_m(height_m=10.0) == pytest.approx(0.12)
    assert table.height_m == pytest.approx(2.5)


def test_dbh_interpolates_frusta_and_ignores_branches() -> None:
    stem = _stem()
    table = CylinderTable(
        start=np.vstack([stem.start, [[0.0, 0.0, -1.0]]]),  # a low branch sets no base
        axis=np.vstack([stem.axis, [[1.0, 0.0, 0.0]]]),
        length_m=np.append(stem.length_m, 0.2),
        radius_m=np.append(stem.radius_m, 0.01),
        end_radius_m=np.append(stem.radius_m - 0.01, 0.01),
        parent=np.append(stem.parent, 0),
        branch=np.append(stem.branch, 2),
        branch_order=np.append(stem.branch_order, 1),
        position_in_branch=np.append(stem.position_in_branch, 1),
    ).validate()
    # 1.3 m is 60 % up the third cylinder, tapering 0.08 -> 0.07.
    assert table.dbh_m() == pytest.approx(2 * (0.08 - 0.6 * 0.01))
    assert table.branches_per_order() == {0: 1, 1: 1}


def test_dbh_without_stem_raises() -> None:
    stem = _stem()
    table = CylinderTable(
        start=stem.start,
        axis=stem.axis,
        length_m=stem.length_m,
        radius_m=stem.radius_m,
        parent=stem.parent,
        branch=stem.branch,
        branch_order=np.ones(5),
        position_in_branch=stem.position_in_branch,
    )
    with pytest.raises(ModelError, match="no stem"):
        table.dbh_m()
    assert table.summary()["dbh_m"] is None


def test_volumes_and_lengths() -> None:
    table = _stem(radii=(0.1, 0.1))
    assert table.volume_m3 == pytest.approx([math.pi * 0.01 * 0.5] * 2)
    assert table.total_length_m == pytest.approx(1.0)
    assert table.branch_volume_m3 == 0.0
    np.testing.assert_allclose(table.end, [[0, 0, 0.5], [0, 0, 1.0]])
    cone_like = CylinderTable(
        start=[[0.0, 0.0, 0.0]],
        axis=[[0.0, 0.0, 1.0]],
        length_m=[2.0],
        radius_m=[0.2],
        end_radius_m=[0.1],
        parent=[-1],
        branch=[1],
        branch_order=[0],
        position_in_branch=[1],
    )
    assert cone_like.total_volume_m3 == pytest.approx(math.pi * 2.0 * (0.04 + 0.02 + 0.01) / 3)


def test_from_endpoints_derives_axis_length_and_positions() -> None:
    table = CylinderTable.from_endpoints(
        [[0, 0, 0], [0, 0, 1], [0, 0, 1]],
        [[0, 0, 1], [0, 0, 3], [2, 0, 1]],
        [0.1, 0.08, 0.02],
        parent=[-1, 0, 0],
        branch=[1, 1, 2],
        branch_order=[0, 0, 1],
    ).validate()
    np.testing.assert_allclose(table.length_m, [1, 2, 2])
    np.testing.assert_allclose(table.axis, [[0, 0, 1], [0, 0, 1], [1, 0, 0]])
    np.testing.assert_array_equal(table.position_in_branch, [1, 2, 1])


# ---------------------------------------------------------------------------- bad tables


def test_valid_handmade_treeqsm_reads(tmp_path: Path) -> None:
    table = read_cylinders(_write_treeqsm(tmp_path / "ok.csv", _treeqsm_rows()))
    assert table.n_cylinders == 4
    np.testing.assert_array_equal(table.parent, [-1, 0, 1, 1])
    np.testing.assert_array_equal(table.extension, [1, 2, -1, -1])
    assert table.branches_per_order() == {0: 1, 1: 1}


def test_missing_column_raises_model_error(tmp_path: Path) -> None:
    header = TREEQSM_HEADER.replace("radius,", "", 1)
    rows = [r[1:] for r in _treeqsm_rows()]
    path = _write_treeqsm(tmp_path / "t.csv", rows, header)
    with pytest.raises(ModelError, match="missing required column.*radius"):
        read_cylinders(path)


@pytest.mark.parametrize(
    ("column", "row", "value", "pattern"),
    [
        ("radius", 3, "-0.01", r"row 3: radius_m is -0\.01"),
        ("radius", 2, "0", r"row 2: radius_m is 0\.0"),
        ("start_y", 2, "nan", r"row 2: start .*not a finite number"),
        ("length", 4, "inf", r"row 4: length_m is .*inf.*not a finite number"),
        ("length", 1, "0", r"row 1: length_m is 0\.0"),
        ("axis_x", 4, "0", r"row 4: axis .*not 1"),
        ("parent", 4, "9", r"row 4: parent points to row 9, outside the table's rows 1\.\.4"),
        ("parent", 2, "-3", r"row 2: parent points to row -3"),
        ("parent", 2, "1.5", r"row 2: column parent holds 1\.5, not a whole number"),
        ("branch_order", 4, "-1", r"row 4: branch_order is -1"),
    ],
)
def test_bad_cell_names_the_row(
    tmp_path: Path, column: str, row: int, value: str, pattern: str
) -> None:
    rows = _treeqsm_rows()
    rows[row - 1][_column(column)] = value
    path = _write_treeqsm(tmp_path / "t.csv", rows)
    with pytest.raises(ModelError, match=pattern) as info:
        read_cylinders(path)
    assert str(path) in str(info.value)


def test_two_cycle_in_parent_links_names_the_rows(tmp_path: Path) -> None:
    rows = _treeqsm_rows()
    rows[1][_column("parent")] = "3"  # row 2 -> row 3 -> row 2
    path = _write_treeqsm(tmp_path / "t.csv", rows)
    pattern = r"row 2: the parent links form a cycle \(rows 2 -> 3 -> 2\)"
    with pytest.raises(ModelError, match=pattern):
        read_cylinders(path)


def test_self_parent_is_a_cycle() -> None:
    stem = _stem()
    parent = stem.parent.copy()
    parent[3] = 3
    bad = CylinderTable(
        start=stem.start,
        axis=stem.axis,
        length_m=stem.length_m,
        radius_m=stem.radius_m,
        parent=parent,
        branch=stem.branch,
        branch_order=stem.branch_order,
        position_in_branch=stem.position_in_branch,
    )
    with pytest.raises(ModelError, match=r"row 4: .*cycle \(rows 4 -> 4\)"):
        bad.validate()


def test_bad_tag_and_shape_mismatch() -> None:
    stem = _stem(radii=(0.1, 0.1))
    kwargs = {
        "start": stem.start,
        "axis": stem.axis,
        "length_m": stem.length_m,
        "radius_m": stem.radius_m,
        "parent": stem.parent,
        "branch": stem.branch,
        "branch_order": stem.branch_order,
        "position_in_branch": stem.position_in_branch,
    }
    with pytest.raises(ModelError, match=r"row 2: tag is 'guessed'; use one of measured"):
        CylinderTable(**kwargs, tag=["measured", "guessed"]).validate()
    with pytest.raises(ModelError, match=r"radius_m must have shape \(2,\)"):
        CylinderTable(**{**kwargs, "radius_m": [0.1, 0.1, 0.1]})


def test_unreadable_files_raise_input_format_error(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="not found"):
        read_cylinders(tmp_path / "absent.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(InputFormatError, match="empty"):
        read_cylinders(tmp_path / "empty.csv")
    (tmp_path / "other.csv").write_text("x,y,z\n1,2,3\n")
    with pytest.raises(InputFormatError, match="matches no known cylinder table"):
        read_cylinders(tmp_path / "other.csv")
    rows = _treeqsm_rows()
    rows[2][_column("radius")] = "thick"
    with pytest.raises(InputFormatError, match=r"row 3: column radius holds 'thick'"):
        read_cylinders(_write_treeqsm(tmp_path / "text.csv", rows))
    rows = _treeqsm_rows()
    rows[1] = rows[1][:-1]
    with pytest.raises(InputFormatError, match=r"row 2 has 16 fields but the header has 17"):
        read_cylinders(_write_treeqsm(tmp_path / "ragged.csv", rows))
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(InputFormatError):
        read_cylinders(tmp_path / "bin.csv")
    with pytest.raises(EmptyInputError):
        read_cylinders(_write_treeqsm(tmp_path / "header_only.csv", []))


SF_HEADER = (
    " ID, parentID, startX, startY, startZ, endX, endY, endZ, radius, length, growthLength, "
    "averagePointDistance,segmentID, parentSegmentID, branchOrder, reverseBranchOrder, branchID"
)


def _write_sf(path: Path, rows: list[str]) -> Path:
    path.write_text(SF_HEADER + "\n" + "\n".join(rows) + "\n")
    return path


def test_simpleforest_small_table(tmp_path: Path) -> None:
    # IDs need not be row numbers; a fork continues the stem and starts an order-1 branch.
    path = _write_sf(
        tmp_path / "sf.csv",
        [
            "10,-1,0,0,0,0,0,1,0.1,1,0,0,0,-1,0,1,0",
            "11,10,0,0,1,0,0,2,0.09,1,0,0,1,0,0,1,0",
            "12,10,0,0,1,1,0,1,0.02,1,0,0,2,0,1,1,1",
            "13,11,0,0,2,0,0,3,0.08,1,0,0,1,0,0,1,0",
        ],
    )
    table = read_cylinders(path)
    np.testing.assert_array_equal(table.parent, [-1, 0, 0, 1])
    np.testing.assert_array_equal(table.position_in_branch, [1, 2, 1, 3])
    np.testing.assert_array_equal(table.extension, [1, 3, -1, -1])
    assert table.branches_per_order() == {0: 1, 1: 1}
    assert table.dbh_m() == pytest.approx(0.18)


def test_simpleforest_bad_rows_are_named(tmp_path: Path) -> None:
    ok = [
        "0,-1,0,0,0,0,0,1,0.1,1,0,0,0,-1,0,1,0",
        "1,0,0,0,1,0,0,2,0.09,1,0,0,0,-1,0,1,0",
        "2,1,0,0,2,0,0,3,0.08,1,0,0,0,-1,0,1,0",
    ]
    unknown = [*ok[:2], "2,7,0,0,2,0,0,3,0.08,1,0,0,0,-1,0,1,0"]
    with pytest.raises(ModelError, match=r"row 3: parentID 7 is not the ID of any cylinder"):
        read_cylinders(_write_sf(tmp_path / "a.csv", unknown))
    cycle = ["0,-1,0,0,0,0,0,1,0.1,1,0,0,0,-1,0,1,0", "1,2,0,0,1,0,0,2,0.09,1,0,0,0,-1,0,1,0",
             "2,1,0,0,2,0,0,3,0.08,1,0,0,0,-1,0,1,0"]  # fmt: skip
    with pytest.raises(ModelError, match=r"row 2: the parent links form a cycle"):
        read_cylinders(_write_sf(tmp_path / "b.csv", cycle))
    zero = [*ok[:2], "2,1,0,0,2,0,0,2,0.08,1,0,0,0,-1,0,1,0"]
    with pytest.raises(ModelError, match=r"row 3: length_m is 0\.0"):
        read_cylinders(_write_sf(tmp_path / "c.csv", zero))
    dup = [*ok[:2], "1,1,0,0,2,0,0,3,0.08,1,0,0,0,-1,0,1,0"]
    with pytest.raises(ModelError, match=r"row 3: ID 1 already used by row 2"):
        read_cylinders(_write_sf(tmp_path / "d.csv", dup))
    missing = tmp_path / "e.csv"
    missing.write_text(SF_HEADER.replace(" branchOrder,", "") + "\n")
    with pytest.raises(ModelError, match="missing required column.*branchOrder"):
        read_cylinders(missing)


def test_errors_share_the_base_class() -> None:
    assert issubclass(ModelError, TreesimError)
    assert issubclass(InputFormatError, TreesimError)
