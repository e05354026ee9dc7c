"""The job store on SQLite and Postgres: atomic claims, leases, fencing, expiry, the
schema Alembic builds, pagination. Known answers: N jobs claimed by many claimants
concurrently are each claimed exactly once."""

from __future__ import annotations

import multiprocessing
import sqlite3
import subprocess
import sys
import threading
import time

import pytest

from treesim.service.jobs.store import Store, metadata

from .conftest import store_url


def _job(store: Store, **kw) -> dict:
    args = dict(process="run", inputs={}, parameters={}, max_attempts=2, time_limit_s=60.0)
    args.update(kw)
    return store.create_job(**args)


def test_the_migrated_schema_is_the_tables_the_code_uses(store):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    with store.engine.connect() as conn:
        assert compare_metadata(MigrationContext.configure(conn), metadata) == []
    Store(store.url)  # a second open (another process starting) migrates nothing, fails nothing


_HOLD_LOCK = """
import sys
from filelock import FileLock
with FileLock(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()
"""


def test_a_sqlite_store_migrates_only_once_another_process_frees_the_lock(tmp_path):
    """Opening a SQLite store waits while another process holds the migration lock file
    (as a second server starting at the same moment would), and migrates once it is freed:
    a portable lock (filelock), no POSIX-only fcntl."""
    db = tmp_path / "jobs.db"
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLD_LOCK, str(db.with_suffix(".migrate.lock"))],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        opened = threading.Event()

        def open_store() -> None:
            Store(f"sqlite:///{db}").dispose()
            opened.set()

        threading.Thread(target=open_store, daemon=True).start()
        assert not opened.wait(1.5), "the store migrated while another process held the lock"
        assert not db.exists()  # nothing touched the database yet
        holder.stdin.close()
        assert holder.wait(10) == 0
        assert opened.wait(60), "the store did not migrate after the lock was freed"
    finally:
        if holder.poll() is None:
            holder.kill()
    with sqlite3.connect(db) as conn:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"alembic_version", "jobs", "uploads"} <= tables


def test_the_clock_is_the_databases(store):
    assert abs(store.ping() - time.time()) < 60


def test_claim_takes_the_oldest_job_and_leases_it(store):
    first = _job(store)
    _job(store)
    c = store.claim("w1", 30)
    assert c is not None and c.id == first["id"] and c.attempt == 1
    row = store.job(first["id"])
    assert row["status"] == "running" and row["worker_id"] == "w1"
    assert row["lease_expires"] == pytest.approx(store.ping() + 30, abs=5)
    assert store.claim("w2", 30).id != first["id"]
    assert store.claim("w3", 30) is None


def test_threads_claiming_at_once_each_job_exactly_once(store):
    ids = {_job(store)["id"] for _ in range(40)}
    got: list[str] = []
    lock = threading.Lock()

    def claimant(name: str) -> None:
        while (c := store.claim(name, 30)) is not None:
            with lock:
                got.append(c.id)

    threads = [threading.Thread(target=claimant, args=(f"w{i}",)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(got) == sorted(ids)  # every job once, none twice


def _claim_all(url: str, name: str, queue) -> None:
    s = Store(url, migrate=False)
    mine = []
    while (c := s.claim(name, 30)) is not None:
        mine.append(c.id)
    queue.put(mine)


def test_processes_claiming_at_once_each_job_exactly_once(store):
    ids = {_job(store)["id"] for _ in range(60)}
    ctx = multiprocessing.get_context("spawn")
    q = ctx.Queue()
    procs = [ctx.Process(target=_claim_all, args=(store.url, f"p{i}", q)) for i in range(4)]
    for p in procs:
        p.start()
    got = [i for _ in procs for i in q.get(timeout=120)]
    for p in procs:
        p.join(30)
    assert sorted(got) == sorted(ids)


def test_a_lost_lease_fences_every_later_write(store):
    job = _job(store)
    old = store.claim("w1", 0.2)
    time.sleep(0.4)
    assert store.expire_leases() == [(job["id"], "accepted")]
    new = store.claim("w2", 30)
    assert new.attempt == 2
    # the first worker wakes up: none of its writes lands
    assert not store.heartbeat(old, 30, progress=50, stage="late")
    assert not store.succeed(old, results=[{"name": "x"}], summary={})
    assert store.fail(old, {"detail": "late"}, retry=True) is None
    assert not store.release(old, "late")
    row = store.job(job["id"])
    assert (row["status"], row["attempt"], row["worker_id"]) == ("running", 2, "w2")
    assert store.heartbeat(new, 30, progress=50, stage="scanning")
    assert store.succeed(new, results=[{"name": "a.laz"}], summary={"n": 1})
    row = store.job(job["id"])
    assert row["status"] == "successful" and row["results"] == [{"name": "a.laz"}]


def test_expired_leases_use_up_the_attempts_then_fail_with_the_reason(store):
    job = _job(store, max_attempts=2)
    for attempt in (1, 2):
        c = store.claim("w", 0.1)
        assert c.attempt == attempt
        time.sleep(0.3)
        status = store.expire_leases()
        assert status == [(job["id"], "accepted" if attempt == 1 else "failed")]
    row = store.job(job["id"])
    assert row["status"] == "failed" and row["finished"] is not None
    assert "stopped renewing its lease" in row["error"]["detail"]
    assert "attempt 2 of 2" in row["error"]["detail"]
    assert store.claim("w", 30) is None
    assert {c["name"]: c["count"] for c in store.counters()}["lease_expiries"] == 2


def test_a_crash_is_retried_a_refusal_is_not(store):
    crash = _job(store, max_attempts=3)
    refused = _job(store, max_attempts=3)
    c = store.claim("w", 30)
    assert store.fail(c, {"detail": "killed by SIGKILL"}, retry=True) == "accepted"
    assert "retrying" in store.job(crash["id"])["message"]
    c2 = store.claim("w", 30)
    assert (c2.id, c2.attempt) == (crash["id"], 2)  # oldest first: the retry goes ahead
    c3 = store.claim("w", 30)
    assert c3.id == refused["id"]
    assert store.fail(c3, {"detail": "no points"}, retry=False) == "failed"
    assert store.job(refused["id"])["attempt"] == 1


def test_release_hands_the_job_back_without_spending_an_attempt(store):
    job = _job(store)
    c = store.claim("w", 30)
    assert store.release(c, "worker stopping")
    assert store.job(job["id"])["attempt"] == 0
    again = store.claim("w2", 30)
    assert again.attempt == 1
    # the attempt number is the same, the claimant is not: the first claim writes nothing
    assert not store.heartbeat(c, 30, progress=50.0)
    assert not store.succeed(c, results=[], summary={})
    assert store.job(job["id"])["progress"] == 0.0
    assert store.succeed(again, results=[], summary={})


def test_dismissing_a_running_job_takes_its_lease(store):
    job = _job(store)
    c = store.claim("w", 30)
    after, before, readers = store.dismiss(job["id"])
    assert (before, after["status"], readers) == ("running", "dismissed", [])
    assert not store.heartbeat(c, 30)


def test_an_upload_used_by_an_unfinished_job_cannot_be_deleted(store):
    up, created = store.add_upload(
        dict(
            sha256="a" * 64,
            filename="t.laz",
            format="laz",
            kind="cloud",
            size_bytes=10,
            info={},
            path="uploads/x.laz",
        )
    )
    again, created2 = store.add_upload(dict(up, id="other", filename="copy.laz"))
    assert created and not created2 and again["id"] == up["id"]  # stored once
    job = _job(store, links=[("cloud", up["id"], None)])
    rec, users = store.delete_upload(up["id"])
    assert users == [job["id"]] and store.upload(up["id"]) is not None
    c = store.claim("w", 30)
    store.fail(c, {"detail": "x"}, retry=False)
    removed = []
    rec, users = store.delete_upload(up["id"], removed.append)
    assert users == [] and removed == [rec] and store.upload(up["id"]) is None
    assert store.delete_upload(up["id"]) == (None, [])


def test_listing_pages_through_every_job_once_newest_first(store):
    ids = [_job(store)["id"] for _ in range(23)]
    seen, cursor = [], None
    while True:
        rows, cursor = store.list_jobs(limit=5, cursor=cursor)
        seen.extend(r["id"] for r in rows)
        if cursor is None:
            break
    assert sorted(seen) == sorted(ids) and len(seen) == 23
    created = [store.job(i)["created"] for i in seen]
    assert created == sorted(created, reverse=True)
    c = store.claim("w", 30)
    rows, _ = store.list_jobs(status=["running"])
    assert [r["id"] for r in rows] == [c.id]


def test_live_workers_are_those_with_a_recent_heartbeat(store):
    store.register_worker("w1", executor="local", slots=2)
    assert [w["id"] for w in store.live_workers(10)] == ["w1"]
    store.worker_stopped("w1")
    assert store.live_workers(10) == []


def test_sqlite_in_wal_mode(tmp_path):
    s = Store(store_url("sqlite", tmp_path))
    with s.engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
