"""``run_batch``: every executor gives the same figures, failures are isolated, results
are reused by hash, and a killed or interrupted batch resumes without corrupt output."""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import shared_path
from tests.run.conftest import PINNED_DBH_ROUNDING_M, SAPLING0_DRAFT_DBH_M
from treesim.batch import (
    SUMMARY_COLUMNS,
    TIME_COLUMNS,
    BatchProgress,
    discover_inputs,
    run_batch,
)
from treesim.cli.progress import BatchProgressBar as ProgressBar
from treesim.errors import InputFormatError, InvalidParameterError
from treesim.executors import Executor, detect_available, plan_executor
from treesim.params import to_toml

ROOT = Path(__file__).resolve().parents[2]

#: Columns that may differ between two runs of the same trees (how, when, how long).
VOLATILE = {"reused", "input", *TIME_COLUMNS}


def figures(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in VOLATILE} for r in rows]


def result_files(out: Path) -> dict[str, int]:
    """mtime (ns) of every finished tree's result.json."""
    return {
        p.parent.name: p.stat().st_mtime_ns for p in sorted((out / "trees").glob("*/result.json"))
    }


def assert_no_corrupt_output(out: Path) -> None:
    """Every folder in trees/ is a finished result (result.json) or a recorded failure."""
    for d in (out / "trees").iterdir():
        if d.name.endswith(".failed"):
            assert (d / "error.json").is_file(), d
        else:
            assert (d / "result.json").is_file(), d
            assert (d / "run.json").is_file() and (d / "report.html").is_file(), d


# -- executors ----------------------------------------------------------------------------
def test_detect_available_lists_inline_and_local():
    found = detect_available()
    assert found[:2] == [Executor.INLINE, Executor.LOCAL]
    assert all(e.is_available() for e in found)


def test_plans_keep_workers_times_threads_within_the_cores():
    from treesim._system import cpu_count

    cores = cpu_count()
    for workers in range(1, cores + 1):
        plan = plan_executor("local", workers=workers)
        assert plan.workers * plan.threads <= cores
        assert plan.threads >= 1
    assert plan_executor("inline").threads == cores
    assert plan_executor("local", n_tasks=1).workers == 1
    with pytest.raises(InvalidParameterError, match="unknown executor"):
        plan_executor("threads")
    with pytest.raises(InvalidParameterError, match="dask"):
        plan_executor("local", scheduler="tcp://x:8786")


@pytest.fixture(scope="module")
def inline_reference(saplings, quick, tmp_path_factory):
    out = tmp_path_factory.mktemp("batch") / "inline"
    return run_batch([saplings["sapling0"]], quick, out, executor="inline")


@pytest.mark.parametrize("executor", [e.value for e in Executor])
def test_every_executor_gives_the_same_figures(
    executor, inline_reference, saplings, quick, tmp_path
):
    if not Executor(executor).is_available():
        pytest.skip(f"the {executor} executor is not installed here (pip install 'treesim[dask]')")
    out = tmp_path / executor
    kw = {"workers": 1} if executor != "inline" else {}
    result = run_batch([saplings["sapling0"]], quick, out, executor=executor, **kw)
    assert [r["status"] for r in result.rows] == ["ok"]
    assert figures(result.rows) == figures(inline_reference.rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executor"]["kind"] == executor
    assert figures(summary["trees"]) == figures(inline_reference.rows)
    assert_no_corrupt_output(out)
    assert not (out / ".tmp").exists()


#: The shared trees the Dask batch runs again (the two quickest of the five, 10 and 15 s
#: on one core; the three others take 28-37 s each).
DASK_TREES = ("coffee_tree/cloud.txt", "adtree/tree7.xyz")


@pytest.mark.slow
def test_shared_trees_on_local_and_dask_give_identical_figures(quick, tmp_path):
    """Every shared tree through the whole loop on the local pool; two of them again on
    Dask, whose every figure must equal the local run's for the same tree. (Executor
    equality on all five cost a whole second batch, ~70 s on two cores, for the same
    comparison; test_every_executor_gives_the_same_figures holds it on a sapling too.)"""
    pytest.importorskip("distributed", reason="the dask executor needs dask[distributed]")
    trees = shared_path("trees")
    local = run_batch([trees], quick, tmp_path / "local", executor="local", workers=2)
    assert_no_corrupt_output(tmp_path / "local")
    assert [r["status"] for r in local.rows] == ["ok"] * len(local.rows), local.rows
    assert {r["id"] for r in local.rows} >= {"cloud", "tree7", "Lille_2", "pine"}
    assert len(local.rows) == 5
    # the QSM cylinder tables beside the coffee tree's cloud are not clouds
    assert {p.name for p, _ in local.skipped_files} == {
        "QSM_simpleforest.csv",
        "QSM_treeqsm_v2.4.1_cylinders.csv",
    }
    assert local.plan.workers * local.plan.threads <= os.cpu_count()
    inputs = [trees.joinpath(*rel.split("/")) for rel in DASK_TREES]
    dask = run_batch(inputs, quick, tmp_path / "dask", executor="dask", workers=2)
    assert_no_corrupt_output(tmp_path / "dask")
    by_id = {r["id"]: r for r in local.rows}
    assert [r["id"] for r in dask.rows] == ["cloud", "tree7"]
    assert figures(dask.rows) == figures([by_id[r["id"]] for r in dask.rows])


# -- failures, reuse, manifests --------------------------------------------------------
def test_a_corrupt_file_fails_alone_and_finished_trees_are_reused(saplings, quick, tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    for p in saplings.values():
        shutil.copy(p, data / p.name)
    # a LAZ file cut short (a copy that stopped half-way)
    from treesim.io import read_cloud, write_cloud

    whole = write_cloud(tmp_path / "whole.laz", read_cloud(saplings["sapling0"]))
    (data / "broken.laz").write_bytes(whole.read_bytes()[:3000])
    manifest = tmp_path / "trees.csv"
    manifest.write_text(
        "path,id,resolution_deg\n"
        "data/sapling0.ply,s0,\n"
        "data/sapling1.ply,s1,0.2\n"
        "data/broken.laz,broken,\n"
    )
    out = tmp_path / "out"
    seen: list[BatchProgress] = []
    result = run_batch([manifest], quick, out, executor="inline", progress=seen.append)
    by_id = {r["id"]: r for r in result.rows}
    assert [r["id"] for r in result.rows] == ["s0", "s1", "broken"]
    assert by_id["s0"]["status"] == by_id["s1"]["status"] == "ok"
    bad = by_id["broken"]
    assert bad["status"] == "failed"
    assert bad["error_class"] == "InputFormatError"
    assert "broken.laz" in bad["error"] and "LAS" in bad["error"]
    err = json.loads((out / "trees" / "broken.failed" / "error.json").read_text())
    assert err["error_class"] == "InputFormatError" and "Traceback" in err["traceback"]
    assert seen[-1].finished == 3 and seen[-1].failed == 1
    # per-tree settings from the manifest
    run_s1 = json.loads((out / "trees" / "s1" / "run.json").read_text())
    assert run_s1["parameters"]["scan"]["scanner"]["horizontal_resolution_deg"] == 0.2
    run_s0 = json.loads((out / "trees" / "s0" / "run.json").read_text())
    assert run_s0["parameters"]["scan"]["scanner"]["horizontal_resolution_deg"] == 0.08
    # the summary table and the index
    with open(out / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["id"] for r in rows] == ["s0", "s1", "broken"]
    assert list(rows[0]) == list(SUMMARY_COLUMNS)
    # the same cloud and preset as test_run's sapling: the same pinned DBH
    assert float(rows[0]["dbh_m"]) == pytest.approx(SAPLING0_DRAFT_DBH_M, abs=PINNED_DBH_ROUNDING_M)
    index = (out / "index.html").read_text()
    assert 'href="trees/s0/report.html"' in index and 'href="trees/s1/report.html"' in index
    assert "trees/broken.failed/error.json" in index
    assert_no_corrupt_output(out)

    # again: nothing changed, nothing runs (the failed tree is tried again)
    before = result_files(out)
    again = run_batch([manifest], quick, out, executor="inline")
    assert [r.get("reused", False) for r in again.rows] == [True, True, False]
    assert figures(again.rows) == figures(result.rows)
    assert result_files(out) == before
    # a changed setting reruns that tree only
    manifest.write_text(manifest.read_text().replace("s1,0.2", "s1,0.25"))
    third = run_batch([manifest], quick, out, executor="inline")
    assert [r.get("reused", False) for r in third.rows] == [True, False, False]
    after = result_files(out)
    assert after["s0"] == before["s0"] and after["s1"] != before["s1"]


def test_inputs_from_folders_skip_tables_and_meshes(tmp_path, saplings):
    from tests.conftest import box_arrays
    from treesim.io.mesh import write_mesh

    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    shutil.copy(saplings["sapling0"], a / "tree.ply")
    shutil.copy(saplings["sapling1"], b / "tree.ply")
    (a / "cloud.xyz").write_text("0 0 0\n1 0 0\n")
    (a / "qsm.csv").write_text("radius,length,start_x\n0.1,1,0\n")
    (a / "pts.csv").write_text("X,Y,Z\n0,0,0\n")
    write_mesh(b / "mesh.ply", *box_arrays((0, 0, 0), (1, 1, 1)))
    (b / ".hidden").mkdir()
    (b / ".hidden" / "x.xyz").write_text("0 0 0\n")
    trees, skipped = discover_inputs([tmp_path])
    assert [t.id for t in trees] == ["cloud", "pts", "a-tree", "b-tree"]
    assert {p.name: why for p, why in skipped} == {
        "qsm.csv": "a table without x, y, z columns (a QSM cylinder table?)",
        "mesh.ply": "a mesh (PLY with faces)",
    }
    with pytest.raises(InputFormatError, match="not found"):
        discover_inputs([tmp_path / "missing.laz"])
    bad = tmp_path / "m.csv"
    bad.write_text("path,colour\nx.ply,red\n")
    with pytest.raises(InvalidParameterError, match="unknown column"):
        discover_inputs([bad])


def test_progress_bar_plain_and_terminal():
    row = {"id": "t1", "status": "ok", "time_total_s": 3.5}
    p = BatchProgress(
        total=4, done=1, failed=1, reused=0, running=2, elapsed_s=7.0, eta_s=14.0, last=row
    )
    plain = io.StringIO()
    ProgressBar(plain, tty=False)(p)
    assert plain.getvalue() == (
        "batch: 4 trees, 0 unchanged (not run again), 4 to run\n"  # the first call only
        "batch: 2/4 trees · 1 failed; t1 ok in 3.5 s; ~0:14 left\n"
    )
    term = io.StringIO()
    bar = ProgressBar(term, tty=True, width=8)
    bar(p)
    bar.close()
    text = term.getvalue()
    assert text.startswith("\r[████░░░░] 2/4 trees · 1 failed · 2 running")
    assert "~0:14 left" in text and text.endswith("\n")


# -- killed and interrupted batches -----------------------------------------------------
def _start_batch(inputs: list[Path], out: Path, config: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "treesim.cli", "batch", *map(str, inputs), "-o", str(out)]
    cmd += ["--config", str(config), "--no-progress", *extra]
    return subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def _wait_for_results(proc: subprocess.Popen, out: Path, n: int, timeout_s: float = 120) -> None:
    t0 = time.monotonic()
    while not ((out / "trees").is_dir() and len(result_files(out)) >= n):
        if proc.poll() is not None:
            pytest.fail(f"the batch ended early: {proc.communicate()}")
        if time.monotonic() - t0 > timeout_s:
            proc.kill()
            pytest.fail("no tree finished in time")
        time.sleep(0.05)


@pytest.fixture()
def four_trees(tmp_path, saplings, quick):
    data = tmp_path / "data"
    data.mkdir()
    for i, name in enumerate("abcd"):
        shutil.copy(saplings[f"sapling{i % 2}"], data / f"{name}.ply")
    config = tmp_path / "quick.toml"
    config.write_text(to_toml(quick))
    return sorted(data.iterdir()), config


def test_a_killed_batch_resumes_without_redoing_finished_trees(four_trees, quick, tmp_path):
    inputs, config = four_trees
    out = tmp_path / "out"
    proc = _start_batch(inputs, out, config, "--executor", "inline")
    _wait_for_results(proc, out, 1)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    assert_no_corrupt_output(out)  # the tree it was running is only in .tmp/
    finished = result_files(out)
    assert 1 <= len(finished) < 4

    result = run_batch(inputs, quick, out, executor="inline")
    assert [r["status"] for r in result.rows] == ["ok"] * 4
    assert {r["id"] for r in result.rows if r.get("reused")} == set(finished)
    after = result_files(out)
    assert {k: after[k] for k in finished} == finished  # not redone
    assert set(after) == {"a", "b", "c", "d"}
    assert not (out / ".tmp").exists()
    assert_no_corrupt_output(out)


def test_ctrl_c_stops_the_workers_and_the_rerun_finishes_the_rest(four_trees, quick, tmp_path):
    inputs, config = four_trees
    out = tmp_path / "out"
    proc = _start_batch(inputs, out, config, "--executor", "local", "--workers", "2")
    _wait_for_results(proc, out, 1)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True
    finished = result_files(out)
    # (a worker may finish a tree just before it is stopped: kept, and reused below)
    assert {r["id"] for r in summary["trees"] if r["status"] == "ok"} <= set(finished)
    assert_no_corrupt_output(out)
    time.sleep(1.5)  # stopped workers write nothing more
    assert result_files(out) == finished

    result = run_batch(inputs, quick, out, executor="local", workers=2)
    assert [r["status"] for r in result.rows] == ["ok"] * 4
    assert {r["id"] for r in result.rows if r.get("reused")} == set(finished)
    after = result_files(out)
    assert {k: after[k] for k in finished} == finished
    assert_no_corrupt_output(out)


# -- one writer per folder ------------------------------------------------------------------
def test_a_second_batch_into_a_locked_folder_fails_and_loses_nothing(
    saplings, quick, tmp_path, monkeypatch
):
    import threading

    import treesim.batch as batch

    out = tmp_path / "out"
    run_batch([saplings["sapling0"]], quick, out, executor="inline")
    finished = result_files(out)
    assert list(finished) == ["sapling0"]
    # a batch that holds the lock, stopped inside its tree (inline: the tree runs in the
    # batch's own thread, so the patched run_tree is the one it calls)
    entered, release = threading.Event(), threading.Event()
    real_run_tree = batch.run_tree

    def held_run_tree(*args, **kwargs):
        entered.set()
        assert release.wait(120), "the test never released the holding batch"
        return real_run_tree(*args, **kwargs)

    monkeypatch.setattr(batch, "run_tree", held_run_tree)
    holder: dict = {}

    def hold() -> None:
        try:
            holder["result"] = run_batch([saplings["sapling1"]], quick, out, executor="inline")
        except BaseException as exc:  # reported by the main thread
            holder["error"] = exc

    thread = threading.Thread(target=hold)
    thread.start()
    try:
        assert entered.wait(60), holder
        in_flight = sorted((out / ".tmp").iterdir())
        assert len(in_flight) == 1 and in_flight[0].name.startswith("sapling1-")
        assert (out / ".treesim-batch.lock").is_file()
        # the second writer: a clear error before it touches anything
        with pytest.raises(InvalidParameterError, match=r"another batch is writing into .*out"):
            run_batch([saplings["sapling0"], saplings["sapling1"]], quick, out, executor="inline")
        # ... the holder's work in progress and the earlier result are untouched
        assert sorted((out / ".tmp").iterdir()) == in_flight
        assert result_files(out) == finished
    finally:
        release.set()
        thread.join(180)
    assert "error" not in holder, holder.get("error")
    assert [r["status"] for r in holder["result"].rows] == ["ok"]
    after = result_files(out)
    assert set(after) == {"sapling0", "sapling1"}
    assert after["sapling0"] == finished["sapling0"]  # the first batch's result, kept
    assert_no_corrupt_output(out)
    # the lock went with its batch: the next batch writes again (and reuses both trees)
    again = run_batch([saplings["sapling0"], saplings["sapling1"]], quick, out, executor="inline")
    assert [r.get("reused") for r in again.rows] == [True, True]


# -- a worker process that dies -------------------------------------------------------------
#: A batch script run as __main__: the spawned workers of the local pool import the main
#: module too (as __mp_main__), so the patch below is in force inside every worker. A tree
#: whose file name starts with "die" kills its worker the way the OOM killer would.
DYING_WORKER_SCRIPT = """
import os
import sys
from pathlib import Path

import treesim.batch as batch

_real_run_tree = batch.run_tree


def _run_tree(path, *args, **kwargs):
    if Path(path).name.startswith("die"):
        with open(os.environ["ATTEMPT_LOG"], "a") as fh:
            fh.write(f"{os.getpid()}\\n")
        os._exit(9)
    return _real_run_tree(path, *args, **kwargs)


batch.run_tree = _run_tree

if __name__ == "__main__":
    from treesim.params import load_config

    out = Path(sys.argv[1])
    params = load_config(sys.argv[2])
    result = batch.run_batch(sys.argv[3:], params, out, executor="local", workers=1)
    print("n_ok", result.n_ok, "n_failed", result.n_failed)
"""


@pytest.mark.slow
def test_a_dying_worker_fails_only_its_tree_after_two_attempts(four_trees, tmp_path):
    from treesim.batch import _ATTEMPTS

    assert (
        _ATTEMPTS == 2
    )  # the manual (docs/commands/batch.md): "fails only the trees it was running (tried twice)"
    inputs, config = four_trees
    # the dying tree is the largest file, so it runs first and the others run after it
    die = inputs[0].parent / "die.ply"
    die.write_bytes(inputs[0].read_bytes() + b"\n" * 4096)
    script = tmp_path / "dying_batch.py"
    script.write_text(DYING_WORKER_SCRIPT)
    log = tmp_path / "attempts.log"
    out = tmp_path / "out"
    env = {**os.environ, "ATTEMPT_LOG": str(log)}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    proc = subprocess.run(
        [sys.executable, str(script), str(out), str(config), str(die), *map(str, inputs[:2])],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "n_ok 2 n_failed 1" in proc.stdout, proc.stdout + proc.stderr[-3000:]
    # two attempts, each in its own (replaced) worker process
    pids = log.read_text().split()
    assert len(pids) == _ATTEMPTS and len(set(pids)) == _ATTEMPTS, pids
    summary = json.loads((out / "summary.json").read_text())
    by_id = {t["id"]: t for t in summary["trees"]}
    assert by_id["die"]["status"] == "failed"
    assert by_id["die"]["error_class"] == "BrokenProcessPool"
    assert "worker process died" in by_id["die"]["error"]
    assert {i: t["status"] for i, t in by_id.items() if i != "die"} == {"a": "ok", "b": "ok"}
    assert set(result_files(out)) == {"a", "b"}
    assert_no_corrupt_output(out)
    assert not (out / ".tmp").exists()


def test_a_manifest_sets_a_reference_qsm_beside_each_tree(saplings, sapling0_qsm, quick, tmp_path):
    from treesim.models import read_cylinders

    shutil.copy(saplings["sapling0"], tmp_path / "s0.ply")
    ref = shutil.copy(sapling0_qsm, tmp_path / "truth.csv")
    manifest = tmp_path / "trees.csv"
    manifest.write_text("path,id,reference_qsm\ns0.ply,s0,truth.csv\ns0.ply,gone,absent.csv\n")
    out = tmp_path / "out"
    result = run_batch([manifest], quick, out, executor="inline")
    by_id = {r["id"]: r for r in result.rows}
    truth = read_cylinders(ref).summary()
    row = by_id["s0"]
    assert row["status"] == "ok"
    assert row["reference_dbh_m"] == truth["dbh_m"]
    assert row["reference_volume_total_m3"] == truth["volume_total_m3"]
    run = json.loads((out / "trees" / "s0" / "run.json").read_text())
    assert run["reference_qsm"]["figures"]["dbh_m"] == truth["dbh_m"]
    # a missing table fails its tree alone, naming the file
    assert by_id["gone"]["status"] == "failed" and "absent.csv" in by_id["gone"]["error"]
    # the table is part of the tree's hash: changed, the tree runs again
    assert run_batch([manifest], quick, out, executor="inline").rows[0]["reused"]
    Path(ref).write_text(Path(ref).read_text() + "\n")
    assert not run_batch([manifest], quick, out, executor="inline").rows[0].get("reused")
