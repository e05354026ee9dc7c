"""``treesim plot from-cloud A B ... -o OUT``: many field plots, one twin each (issue 23).

Two good plots (the small generated field plot of ``field_plot.py``, and a plot of one of
its trees with its ground, moved by a projected offset) and one cloud without ground (the
field plot's ground points dropped): two twins whose trees stand where the generator put
them, one failure with its reason, exit 1; a second run reuses both twins without
rewriting a file; one file keeps the one-twin layout.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import treesim as ts
from treesim.cli import main
from treesim.errors import EmptyInputError, InputFormatError, InvalidParameterError
from treesim.twin import TwinParams, finished_twin, plots_from_clouds
from treesim.twin.many import discover_plots

from .field_plot import small_field_plot

#: The second plot's projected offset (m).
OFFSET = np.array([5e5, 5e6, 200.0])
#: A twin's tree stands within this of a true tree (as tests/plot/test_twin.py holds).
POSITION_M = 0.15
DRAFT = ["--preset", "draft", "--executor", "inline", "--no-progress"]


def _cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(argv))
    return rc, out.getvalue(), err.getvalue()


def _mtimes(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*")}


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    """The small field plot (``field_plot.SMALL_PLOT``), made once per test run."""
    return small_field_plot(tmp_path_factory)


@pytest.fixture(scope="module")
def clouds(field, tmp_path_factory) -> Path:
    """plot_a (the field plot), plot_b (its first tree with the ground around it, moved by
    OFFSET), noground (the field plot without its ground); one.laz (plot_b unmoved) beside
    the folder."""
    folder = tmp_path_factory.mktemp("clouds")
    shutil.copy2(field.laz, folder / "plot_a.laz")
    cloud = ts.read_cloud(field.laz)
    one = cloud.subset(_one_tree(cloud, field.truth[0]))
    ts.write_cloud(folder / "plot_b.laz", ts.Cloud(one.points + OFFSET))
    ts.write_cloud(folder / "noground.laz", cloud.subset(cloud.fields["tree_id"] > 0))
    ts.write_cloud(folder.parent / f"{folder.name}_one.laz", one)
    return folder


def _one_tree(cloud, tree: dict) -> np.ndarray:
    """The points of ``tree`` and of the ground (tree_id 0) within 2.5 m of its stem."""
    near = np.hypot(cloud.points[:, 0] - tree["x_m"], cloud.points[:, 1] - tree["y_m"]) < 2.5
    return near & np.isin(cloud.fields["tree_id"], [0, tree["tree_id"]])


@pytest.fixture(scope="module")
def first(clouds, tmp_path_factory):
    out = tmp_path_factory.mktemp("twins")
    rc, stdout, stderr = _cli("plot", "from-cloud", str(clouds), "-o", str(out), *DRAFT)
    return out, rc, stdout, stderr


def _rows(out: Path) -> dict[str, dict[str, str]]:
    with open(out / "plots.csv", newline="", encoding="utf-8") as fh:
        return {r["id"]: r for r in csv.DictReader(fh)}


@pytest.mark.slow
def test_two_plots_made_one_failed_with_its_reason(field, first) -> None:
    out, rc, stdout, stderr = first
    assert rc == 1, stdout + stderr
    rows = _rows(out)
    assert list(rows) == ["noground", "plot_a", "plot_b"]  # the folder's files, sorted
    bad = rows["noground"]
    assert bad["status"] == "failed" and bad["error_class"] == "InputFormatError"
    assert "no ground" in bad["error"]
    assert "failed: noground" in stdout and "no ground" in stdout
    assert "Traceback" not in stdout + stderr
    assert (out / "noground" / "error.json").is_file()
    summary = json.loads((out / "plots.json").read_text())
    assert summary["counts"] == {"ok": 2, "reused": 0, "failed": 1}
    true_xy = np.array([[t["x_m"], t["y_m"]] for t in field.truth])
    for pid, shift, n_true in (("plot_a", 0.0, len(true_xy)), ("plot_b", OFFSET[:2], 1)):
        row = rows[pid]
        assert row["status"] == "ok" and row["folder"] == pid and row["error"] == ""
        plot = ts.read_plot(out / pid / "plot.toml")
        assert int(row["trees"]) == len(plot.trees) >= max(n_true - 1, 1)
        assert int(row["trees"]) + int(row["left_out"]) <= n_true
        for tree in plot.trees:  # each twin tree stands where the generator put one
            d = np.linalg.norm(true_xy[:n_true] + shift - [tree.x_m, tree.y_m], axis=1)
            assert d.min() < POSITION_M, (pid, tree.tree_id, d.min())


@pytest.mark.slow
def test_a_second_run_reuses_both_twins_and_rewrites_nothing(clouds, first) -> None:
    out, *_ = first
    before = {pid: _mtimes(out / pid) for pid in ("plot_a", "plot_b")}
    res = plots_from_clouds([clouds], out, TwinParams(preset="draft"), executor="inline")
    assert [r["status"] for r in res.rows] == ["failed", "reused", "reused"]
    assert res.n_failed == 1 and res.n_reused == 2
    assert "no ground" in res.failed[0]["error"]
    for pid in ("plot_a", "plot_b"):
        assert _mtimes(out / pid) == before[pid], pid
    assert _rows(out)["plot_a"]["status"] == "reused"


@pytest.mark.slow
def test_other_settings_or_a_touched_cloud_are_not_reused(clouds, first) -> None:
    out, *_ = first
    draft = TwinParams(preset="draft")
    assert finished_twin(clouds / "plot_a.laz", out / "plot_a", draft) is not None
    assert finished_twin(clouds / "plot_b.laz", out / "plot_a", draft) is None
    assert finished_twin(clouds / "plot_a.laz", out / "plot_a", TwinParams(facets=12)) is None
    touched = out.parent / "touched.laz"
    shutil.copy2(clouds / "plot_a.laz", touched)
    st = touched.stat()
    os.utime(touched, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert finished_twin(touched, out / "plot_a", draft) is None


@pytest.mark.slow
def test_one_file_keeps_the_one_twin_layout(clouds, tmp_path) -> None:
    one = clouds.parent / f"{clouds.name}_one.laz"
    rc, stdout, stderr = _cli("plot", "from-cloud", str(one), "-o", str(tmp_path), *DRAFT)
    assert rc == 0, stdout + stderr
    assert (tmp_path / "plot.toml").is_file() and (tmp_path / "from_cloud.json").is_file()
    assert not (tmp_path / "plots.csv").exists() and not (tmp_path / one.stem).exists()
    # the same command again: the finished twin is reused, nothing rewritten
    before = _mtimes(tmp_path)
    rc, stdout, _ = _cli("plot", "from-cloud", str(one), "-o", str(tmp_path), *DRAFT)
    assert rc == 0 and "reused" in stdout
    assert _mtimes(tmp_path) == before
    # many plots are not written into one plot's twin
    with pytest.raises(InvalidParameterError, match="twin of one plot"):
        plots_from_clouds([clouds / "plot_a.laz", clouds / "plot_b.laz"], tmp_path)


# ------------------------------------------------------------------ finding the plots
def test_discovery_skips_hidden_and_treesim_folders_and_names_like_a_batch(tmp_path) -> None:
    root = tmp_path / "field"
    for rel in ("north/plot.laz", "south/plot.laz", "east.las", ".cache/x.laz",
                "old_twin/trees/tree_0001.laz", "old_twin/plot_labelled.laz",
                "stand/tree.ply"):  # fmt: skip
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"not read")
    (root / "old_twin" / "from_cloud.json").write_text("{}")
    (root / "stand" / "plot.toml").write_text("")
    (root / "cylinders.csv").write_text("radius_m,length_m\n0.1,1.0\n")
    plots, skipped = discover_plots([root, root / "east.las"])
    assert [(p.id, p.path.relative_to(root).as_posix()) for p in plots] == [
        ("east", "east.las"),
        ("north-plot", "north/plot.laz"),
        ("south-plot", "south/plot.laz"),
    ]
    assert [p.name for p, _ in skipped] == ["cylinders.csv"]


def test_discovery_refuses_what_is_not_there_or_not_a_cloud(tmp_path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(EmptyInputError, match="no point cloud"):
        discover_plots([tmp_path / "empty"])
    with pytest.raises(InputFormatError, match="not found"):
        discover_plots([tmp_path / "missing.laz"])
    (tmp_path / "notes.docx").write_text("x")
    with pytest.raises(InputFormatError, match="not a point cloud"):
        discover_plots([tmp_path / "notes.docx"])


def test_the_cli_says_what_is_wrong_in_one_line(tmp_path) -> None:
    (tmp_path / "empty").mkdir()
    rc, stdout, stderr = _cli("plot", "from-cloud", str(tmp_path / "empty"), "-o",
                              str(tmp_path / "out"), *DRAFT)  # fmt: skip
    assert rc == 1 and "no point cloud" in stderr and "Traceback" not in stderr
    # one plot's twin is not written among many plots' twins
    (tmp_path / "twins").mkdir()
    (tmp_path / "twins" / "plots.json").write_text("{}")
    rc, _, stderr = _cli("plot", "from-cloud", str(tmp_path / "p1.laz"), "-o",
                         str(tmp_path / "twins"), *DRAFT)  # fmt: skip
    assert rc == 1 and "twins of many plots" in stderr and "twins/p1" in stderr
