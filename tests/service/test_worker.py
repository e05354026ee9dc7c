"""The worker in-process, on real jobs (``run`` with the draft preset on the bundled tree):
a job past its time limit is stopped and failed, a killed job process is retried and then
succeeds, a dismissed job's process is stopped and its files removed, a stopped worker hands
its job back, an input gone from the data folder fails the job without a retry."""

from __future__ import annotations

import multiprocessing
import os
import shutil
import signal
import time
from pathlib import Path

import pytest

from treesim.service.jobs.store import Store
from treesim.service.jobs.worker import Worker

from .conftest import BUNDLED_CLOUD

pytestmark = pytest.mark.slow


@pytest.fixture
def rig(settings):
    """(settings, store, worker not yet started, the bundled tree as an upload)."""
    settings = settings.model_copy(update={"workers": 1, "job_threads": 1})
    store = Store(settings.db_url)
    rel = Path("uploads") / "ab" / "tree.txt"
    (settings.data_dir / rel).parent.mkdir(parents=True)
    shutil.copy(BUNDLED_CLOUD, settings.data_dir / rel)
    rec, _ = store.add_upload(
        {
            "sha256": "ab" * 32,
            "filename": "cloud.txt",
            "format": "xyz",
            "kind": "cloud",
            "size_bytes": BUNDLED_CLOUD.stat().st_size,
            "n_points": 1,
            "info": {"bounds": [[0, 0, 0], [1, 1, 1]], "fields": []},
            "path": rel.as_posix(),
        }
    )
    worker = Worker(settings, store)
    yield settings, store, worker, rec
    worker.stop(timeout=30)
    store.dispose()


def _submit(store: Store, upload: dict, *, time_limit_s: float = 600.0, attempts: int = 3):
    return store.create_job(
        process="run",
        inputs={
            "cloud": {
                "upload": upload["id"],
                "path": upload["path"],
                "filename": "cloud.txt",
                "kind": "cloud",
            }
        },
        parameters={"preset": "draft"},
        max_attempts=attempts,
        time_limit_s=time_limit_s,
        links=[("cloud", upload["id"], None)],
    )["id"]


def _wait(store: Store, job_id: str, until, timeout_s: float = 180) -> dict:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        job = store.job(job_id)
        if until(job):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} never got there: {store.job(job_id)}")


def _job_processes() -> list[multiprocessing.Process]:
    return [p for p in multiprocessing.active_children() if p.name.startswith("treesim-job-")]


def _ended(job: dict) -> bool:
    return job["status"] in ("successful", "failed", "dismissed")


def _leftovers(jobdir: Path) -> list[str]:
    return sorted(p.name for p in jobdir.iterdir()) if jobdir.exists() else []


def test_a_job_past_its_time_limit_is_stopped_and_failed(rig):
    settings, store, worker, upload = rig
    job_id = _submit(store, upload, time_limit_s=1.0)
    worker.start()
    job = _wait(store, job_id, _ended, 60)
    assert job["status"] == "failed"
    assert job["error"]["type"].endswith("time-limit")
    assert "time limit" in job["error"]["detail"]
    assert job["attempt"] == 1  # a time limit is not retried
    time.sleep(0.5)
    assert _job_processes() == []
    assert _leftovers(settings.data_dir / "jobs" / job_id) == []


def test_a_killed_job_process_is_retried_and_succeeds(rig):
    settings, store, worker, upload = rig
    job_id = _submit(store, upload)
    worker.start()
    # kill the job's process once it is working (past start-up, mid-reconstruction)
    _wait(store, job_id, lambda j: j["status"] == "running" and (j["progress"] or 0) > 0, 120)
    (proc,) = _job_processes()
    os.kill(proc.pid, signal.SIGKILL)
    job = _wait(store, job_id, _ended)
    assert job["status"] == "successful", job["error"]
    assert job["attempt"] == 2
    names = {r["name"] for r in job["results"]}
    assert {"run.json", "report.html", "scan.laz", "tree.ply"} <= names
    jobdir = settings.data_dir / "jobs" / job_id
    assert _leftovers(jobdir) == ["results"]  # the killed attempt's folder is gone
    on_disk = {
        p.relative_to(jobdir / "results").as_posix()
        for p in (jobdir / "results").rglob("*")
        if p.is_file()
    }
    assert on_disk == names


def test_dismissing_a_running_job_stops_it_and_removes_its_files(rig):
    settings, store, worker, upload = rig
    job_id = _submit(store, upload)
    worker.start()
    _wait(store, job_id, lambda j: j["status"] == "running" and len(_job_processes()) == 1, 60)
    store.dismiss(job_id)
    t0 = time.monotonic()
    while _job_processes() and time.monotonic() - t0 < 20:
        time.sleep(0.1)
    assert _job_processes() == [], "the dismissed job's process still runs"
    time.sleep(1.0)  # the slot cleans up after stopping the process
    assert store.job(job_id)["status"] == "dismissed"
    assert _leftovers(settings.data_dir / "jobs" / job_id) == []


def test_a_stopping_worker_hands_its_job_back(rig):
    settings, store, worker, upload = rig
    job_id = _submit(store, upload)
    worker.start()
    _wait(store, job_id, lambda j: j["status"] == "running", 60)
    worker.stop(timeout=30)
    job = store.job(job_id)
    assert job["status"] == "accepted" and job["worker_id"] is None
    assert _job_processes() == []
    # the next worker takes it up; the handed-back attempt does not count against the limit
    nxt = Worker(settings, store)
    nxt.start()
    try:
        job = _wait(store, job_id, _ended)
    finally:
        nxt.stop()
    assert job["status"] == "successful", job["error"]


def test_an_input_gone_from_the_data_folder_fails_without_retry(rig):
    settings, store, worker, upload = rig
    (settings.data_dir / upload["path"]).unlink()
    job_id = _submit(store, upload)
    worker.start()
    job = _wait(store, job_id, _ended, 30)
    assert job["status"] == "failed" and job["attempt"] == 1
    assert job["error"]["field"] == "inputs.cloud"
    assert "gone" in job["error"]["detail"]
