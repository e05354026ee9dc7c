"""Fixtures of the service's tests: job stores on SQLite and Postgres, settings in a
temporary data folder, a TestClient app, and real servers started as subprocesses."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from treesim.service.jobs.store import Store
from treesim.service.settings import Settings

REPO = Path(__file__).resolve().parents[2]
BUNDLED_CLOUD = REPO / "pipeline" / "data" / "coffee_tree" / "cloud.txt"
BUNDLED_QSM = REPO / "pipeline" / "data" / "coffee_tree" / "QSM_treeqsm_v2.4.1_cylinders.csv"


def in_ci() -> bool:
    """Whether this is a CI run (``CI=true``, as CI services and ``.ci/run`` set it)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1")


def postgres_unavailable(why: str) -> None:
    """Skip a Postgres test for ``why``; in CI fail instead: a CI run whose Postgres did
    not start must not pass with the Postgres tests silently skipped."""
    if in_ci():
        pytest.fail(f"CI=true, so this fails instead of skipping: {why}", pytrace=False)
    pytest.skip(why)


def postgres_or_skip() -> str:
    url = os.environ.get("TREESIM_TEST_DATABASE_URL")
    if not url:
        postgres_unavailable(
            "needs TREESIM_TEST_DATABASE_URL (a Postgres test database; .ci/run sets one up)"
        )
    return url


_SCHEMAS: list[tuple[str, str]] = []


@pytest.fixture(scope="session", autouse=True)
def _drop_test_schemas() -> Iterator[None]:
    """Drop the Postgres schemas the tests made, at the end of the session."""
    yield
    if not _SCHEMAS:
        return
    import psycopg

    with psycopg.connect(_SCHEMAS[0][0], connect_timeout=3, autocommit=True) as conn:
        for _, schema in _SCHEMAS:
            conn.execute(f"DROP SCHEMA IF EXISTS {schema} CASCADE")


def _fresh_postgres(url: str) -> str:
    """A new empty schema in the test database, so tests do not see each other's rows."""
    import psycopg

    schema = f"t_{uuid.uuid4().hex[:12]}"
    plain = url.replace("postgresql+psycopg://", "postgresql://", 1)
    try:
        with psycopg.connect(plain, connect_timeout=3, autocommit=True) as conn:
            conn.execute(f"CREATE SCHEMA {schema}")
        _SCHEMAS.append((plain, schema))
    except psycopg.OperationalError as exc:
        postgres_unavailable(f"Postgres at TREESIM_TEST_DATABASE_URL is not reachable: {exc}")
    sep = "&" if "?" in url else "?"
    return f"{url}{sep}options=-csearch_path%3D{schema}"


def store_url(kind: str, tmp_path: Path) -> str:
    if kind == "sqlite":
        return f"sqlite:///{tmp_path / 'jobs.db'}"
    url = postgres_or_skip()
    if url.startswith("postgresql://"):
        url = "postgresql+psycopg://" + url[len("postgresql://") :]
    return _fresh_postgres(url)


@pytest.fixture(params=["sqlite", "postgres"])
def store(request, tmp_path) -> Iterator[Store]:
    """A migrated, empty job store on each backend."""
    s = Store(store_url(request.param, tmp_path))
    yield s
    s.dispose()


@pytest.fixture
def settings(tmp_path) -> Settings:
    """Settings in a temporary data folder, with a short lease and fast polls."""
    return Settings(
        data_dir=tmp_path / "data",
        workers=0,
        lease_s=4.0,
        poll_interval_s=0.2,
        api_token=None,
        database_url=None,
    )


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """``treesim serve`` (or ``treesim worker``) in its own process group."""

    def __init__(self, args: list[str], env: dict[str, str], log: Path) -> None:
        self.args = args
        self.env = env
        self.log = log
        self.proc: subprocess.Popen | None = None

    def start(self) -> Server:
        fh = open(self.log, "ab")  # noqa: SIM115 - closed with the process
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "treesim.cli", *self.args],
            env=self.env,
            stdout=fh,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        return self

    def kill9(self) -> None:
        """SIGKILL the whole process group: the server, its worker and job processes."""
        assert self.proc is not None
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)


def service_env(data_dir: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("TREESIM_")}
    env.update(
        TREESIM_DATA_DIR=str(data_dir),
        TREESIM_LEASE_S="4",
        TREESIM_POLL_INTERVAL_S="0.2",
        TREESIM_JOB_THREADS="1",
        PYTHONUNBUFFERED="1",
    )
    env.update(extra)
    return env


def wait_ready(
    base: str, proc: subprocess.Popen, log: Path, path: str = "/readyz", timeout_s: float = 60
) -> None:
    """Until ``path`` answers 200 (``/readyz``: with a live worker; ``/healthz``: the API)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if proc.poll() is not None:
            raise AssertionError(f"the server exited ({proc.returncode}):\n{log.read_text()}")
        try:
            if httpx.get(f"{base}{path}", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise AssertionError(f"no 200 from {path} within {timeout_s} s:\n{log.read_text()}")


@pytest.fixture
def serve(tmp_path) -> Iterator:
    """``serve(data_dir, workers=1, **env)`` → (base URL, Server); stopped at the end."""
    started: list[Server] = []

    def start(data_dir: Path, *, workers: int = 1, wait: bool = True, **env: str):
        port = free_port()
        log = tmp_path / f"serve-{port}.log"
        srv = Server(
            ["serve", "--port", str(port), "--workers", str(workers), "--log-level", "warning"],
            service_env(data_dir, **env),
            log,
        ).start()
        started.append(srv)
        base = f"http://127.0.0.1:{port}"
        if wait:
            wait_ready(base, srv.proc, log, "/readyz" if workers else "/healthz")
        return base, srv

    yield start
    for s in started:
        s.stop()


def wait_job(client: httpx.Client, job_id: str, timeout_s: float = 240, until=None) -> dict:
    """Poll a job until it ends (or ``until(status)`` is true)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        j = client.get(f"/v1/jobs/{job_id}").json()
        if (until or (lambda s: s["status"] in ("successful", "failed", "dismissed")))(j):
            return j
        time.sleep(0.25)
    raise AssertionError(f"job {job_id} still {j['status']} after {timeout_s} s: {j}")
