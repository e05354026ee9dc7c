"""Faults that must not be 500s nor leave work outside the data folder (issue 24, part 2).

Each test reproduces one fault the issue lists: a zip bomb, a full disk, ...; the oracle
is the limit or status the issue asks for, not anything the code computed.
"""

from __future__ import annotations

import errno
import io
import re
import zipfile
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

import treesim.service.plots as plots
from treesim.errors import ResourceLimitError
from treesim.service.app import create_app
from treesim.service.settings import Settings

from .conftest import BUNDLED_CLOUD

PROBLEM = "application/problem+json"
LIMIT = 2_000_000
_TOML = 'radius_m = 5.0\ntrees = "trees.csv"\n'
_CSV = "tree_id,x_m,y_m,species\n1,1.0,0.0,sapling\n"


def _bomb(inflated: int) -> bytes:
    """A small zip whose ``zeros.bin`` inflates to ``inflated`` bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("plot.toml", _TOML)
        z.writestr("trees.csv", _CSV)
        z.writestr("zeros.bin", b"\0" * inflated)
    return buf.getvalue()


def _parts(data_dir: Path) -> list[Path]:
    """The partial uploads in the data folder."""
    return sorted(data_dir.rglob("*.part")) if data_dir.exists() else []


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.exists()) if root.exists() else []


@pytest.fixture
def app_settings(tmp_path) -> Settings:
    return Settings(
        data_dir=tmp_path / "data",
        workers=0,
        api_token=None,
        database_url=None,
        poll_interval_s=0.2,
        max_upload_bytes=LIMIT,
    )


@pytest.fixture
def watched_tmp(tmp_path, monkeypatch) -> Path:
    """The system temp folder, as the app and its spawned inspector see it."""
    d = tmp_path / "systemp"
    d.mkdir()
    monkeypatch.setenv("TMPDIR", str(d))
    return d


def _problem(r, status: int) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    body = r.json()
    assert body["status"] == status
    assert body["type"].startswith("/problems#"), body
    return body


# -- 1. plot archives inspected inside the data folder, streamed within the limit ---------------
def test_a_zip_bomb_is_refused_and_nothing_lands_outside_the_data_folder(app_settings, watched_tmp):
    bomb = _bomb(50 * LIMIT)  # 100 MB of zeros in a ~100 kB zip
    assert len(bomb) < LIMIT
    with TestClient(create_app(app_settings)) as client:
        body = _problem(client.post("/v1/uploads?filename=bomb.zip", content=bomb), 422)
    assert "unpacks to" in body["detail"]
    assert _files(watched_tmp) == []  # the system temp folder was never used
    data = app_settings.data_dir
    left = [p for p in _files(data) if p.is_file() and p.name != "treesim.db"]
    assert [p for p in left if "treesim-plot-" in str(p) or p.suffix == ".part"] == []


def test_a_plot_archive_is_unpacked_beside_it_not_in_the_system_temp_folder(tmp_path, monkeypatch):
    data = tmp_path / "data" / "tmp"
    data.mkdir(parents=True)
    archive = data / "x.part"
    archive.write_bytes(_bomb(10))
    where: list[Path] = []
    real = plots.tempfile.TemporaryDirectory

    def spy(*args, **kwargs):
        where.append(Path(kwargs["dir"]))
        return real(*args, **kwargs)

    monkeypatch.setattr(plots.tempfile, "TemporaryDirectory", spy)
    info = plots.inspect_plot_archive(archive, "x.zip", max_bytes=LIMIT)
    assert (info["kind"], info["n_trees"]) == ("plot", 1)
    assert where == [data.resolve()]
    assert sorted(p.name for p in data.iterdir()) == ["x.part"]  # removed after


def test_a_lying_archive_never_puts_more_than_the_limit_on_disk(tmp_path, monkeypatch):
    """An archive whose directory declares tiny sizes (so the declared total passes) but
    whose member inflates far beyond the limit: the streamed counter stops it, and the bytes
    on disk never exceed the limit (counted at every write, not timed)."""
    archive = tmp_path / "bomb.zip"
    archive.write_bytes(_bomb(20 * LIMIT))
    real_infolist = zipfile.ZipFile.infolist
    real_init = zipfile.ZipExtFile.__init__

    def lying_infolist(self):
        infos = real_infolist(self)
        for i in infos:
            i.file_size = 1  # what a lying (or zip64-confused) directory declares
        return infos

    def unbounded_init(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        self._left = 1 << 40  # a reader that trusts the stream, not the directory

    monkeypatch.setattr(zipfile.ZipFile, "infolist", lying_infolist)
    monkeypatch.setattr(zipfile.ZipExtFile, "__init__", unbounded_init)
    on_disk = [0]
    peak = [0]

    class Counting(io.FileIO):
        def write(self, b):
            n = super().write(b)
            on_disk[0] += n
            peak[0] = max(peak[0], on_disk[0])
            return n

    monkeypatch.setattr(plots, "open", lambda p, mode="r": Counting(p, mode[0]), raising=False)
    work = tmp_path / "work"
    work.mkdir()
    with pytest.raises(ResourceLimitError, match="unpacks to more than"):
        plots.inspect_plot_archive(archive, "bomb.zip", max_bytes=LIMIT, work_dir=work)
    assert 0 < peak[0] <= LIMIT
    assert list(work.iterdir()) == []


# -- 2. a full disk: 507 on upload and on submission, a clear failure in a job, /readyz ------
def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device", "/srv/secret/data/x.part")


def test_a_full_disk_on_upload_is_507_not_500(app_settings, monkeypatch):
    import treesim.service.api.uploads as uploads

    with TestClient(create_app(app_settings), raise_server_exceptions=False) as client:
        monkeypatch.setattr(uploads.os, "replace", _enospc)  # placing the upload fails
        r = client.post("/v1/uploads?filename=tree.txt", content=BUNDLED_CLOUD.read_bytes())
        body = _problem(r, 507)
        assert body["type"] == "/problems#insufficient-storage"
        assert "/srv/secret" not in r.text and "a bug" not in r.text
        assert _parts(app_settings.data_dir) == []  # nothing kept


def test_a_full_disk_while_unpacking_a_plot_is_507(tmp_path):
    """The inspector's child wraps a full disk in treesim's error; it still comes back as
    a full disk (its cause does not cross the process boundary by itself)."""
    from treesim.service.inspect import _inspect

    archive = tmp_path / "p.zip"
    archive.write_bytes(_bomb(10))
    real = plots.unpack_plot

    def full(*args, **kwargs):
        try:
            raise OSError(errno.ENOSPC, "No space left on device")
        except OSError:
            raise plots._bad("p.zip", "entry is corrupt") from None

    plots.unpack_plot = full
    try:
        with pytest.raises(OSError) as info:
            _inspect(str(archive), "p.zip", LIMIT)
    finally:
        plots.unpack_plot = real
    assert info.value.errno == errno.ENOSPC


def test_a_full_disk_on_job_submission_is_507(app_settings, monkeypatch):
    from treesim.service.jobs.store import Store

    with TestClient(create_app(app_settings), raise_server_exceptions=False) as client:
        r = client.post("/v1/uploads?filename=tree.txt", content=BUNDLED_CLOUD.read_bytes())
        assert r.status_code == 201, r.text
        monkeypatch.setattr(Store, "create_job", _enospc)
        r = client.post(
            "/v1/processes/reconstruct/execution", json={"inputs": {"cloud": r.json()["id"]}}
        )
        body = _problem(r, 507)
        assert "/srv/secret" not in body["detail"]


def test_a_full_job_store_is_507_not_500(app_settings):
    """SQLite's own "database or disk is full" (SQLITE_FULL, raised by the real driver: the
    store's connections may not grow the file past its size now) is a full disk: 507,
    not a 500 "bug in treesim"."""
    from sqlalchemy import event

    with TestClient(create_app(app_settings), raise_server_exceptions=False) as client:
        up = client.post("/v1/uploads?filename=tree.txt", content=BUNDLED_CLOUD.read_bytes())
        assert up.status_code == 201, up.text
        engine = client.app.state.store.engine

        @event.listens_for(engine, "connect")
        def _no_growth(dbapi_conn, _record):
            cur = dbapi_conn.cursor()
            pages = cur.execute("PRAGMA page_count").fetchone()[0]
            cur.execute(f"PRAGMA max_page_count={pages}")
            cur.close()

        engine.dispose()  # the pool's next connections are capped
        body = {"inputs": {"cloud": up.json()["id"]}, "parameters": {"preset": "draft"}}
        statuses = []
        for _ in range(200):  # each job's row takes room, until a page must be added
            r = client.post("/v1/processes/reconstruct/execution", json=body)
            statuses.append(r.status_code)
            if r.status_code != 201:
                break
    assert statuses[-1] == 507 and set(statuses[:-1]) <= {201}, statuses
    problem = _problem(r, 507)
    assert problem["type"] == "/problems#insufficient-storage"
    assert "a bug" not in r.text and "treesim.db" not in r.text


def test_a_wrapped_database_disk_full_is_recognised():
    """The forms a full job store reaches the API in: sqlite3's error (by its code or,
    built by hand, its message), SQLAlchemy's wrapper around it, Postgres's disk_full."""
    import sqlite3

    from sqlalchemy.exc import OperationalError

    from treesim.service.problems import is_disk_full

    full = sqlite3.OperationalError("database or disk is full")
    assert is_disk_full(full)
    assert is_disk_full(OperationalError("INSERT INTO jobs ...", {}, full))
    locked = sqlite3.OperationalError("database is locked")
    assert not is_disk_full(OperationalError("INSERT INTO jobs ...", {}, locked))

    class DiskFull(Exception):  # psycopg.errors.DiskFull's SQLSTATE
        sqlstate = "53100"

    assert is_disk_full(OperationalError("INSERT", {}, DiskFull("could not extend file")))


def test_a_full_disk_inside_a_job_fails_it_with_a_clear_message(tmp_path, monkeypatch):
    """A reader that wraps ENOSPC in treesim's InputFormatError (with the server's path)
    used to end the job as 'bad-input-file'; it is out of disk space, without paths."""
    from treesim.errors import InputFormatError
    from treesim.service.jobs import runner

    def execute(spec):
        try:
            _enospc()
        except OSError as exc:
            raise InputFormatError(f"/srv/secret/data/jobs/j/out.ply: {exc}") from exc

    monkeypatch.setattr(runner, "execute", execute)
    spec = runner.JobSpec("j", 1, "reconstruct", {}, {}, str(tmp_path), str(tmp_path), 1)
    out = runner._outcome(spec)
    assert out["ok"] is False
    p = out["problem"]
    assert (p["status"], p["type"]) == (507, "/problems#insufficient-storage")
    assert "out of disk space" in p["detail"] and "/srv" not in p["detail"]


def test_readyz_is_503_below_the_free_space_floor(app_settings):
    import shutil

    free_mb = shutil.disk_usage(app_settings.data_dir.parent).free / 2**20
    low = app_settings.model_copy(update={"min_free_mb": free_mb * 4 + 1})
    with TestClient(create_app(low)) as client:
        r = client.get("/readyz")
        assert r.status_code == 503
        assert r.json()["checks"]["disk"]["ok"] is False
        assert "TREESIM_MIN_FREE_MB" in r.json()["checks"]["disk"]["detail"]
    with TestClient(create_app(app_settings)) as client:  # the default floor, 500 MiB
        disk = client.get("/readyz").json()["checks"]["disk"]
        assert disk["ok"] is (free_mb >= 500), disk


# -- 3. a failed job keeps its log's end, shown in its status -----------------------------------
def test_a_failed_job_keeps_its_log_and_its_status_shows_it(app_settings, monkeypatch):
    from treesim.service.jobs import worker as worker_mod
    from treesim.service.problems import problem

    settings = app_settings.model_copy(update={"workers": 1, "job_threads": 1})
    boom = "Traceback (most recent call last):\nZeroDivisionError: division by zero\n"

    class FailingHandle:  # a job's process that printed a traceback and wrote its result
        def __init__(self, spec):
            spec.log_path.write_text("x" * 100 + "\n" + "filler line\n" * 20_000 + boom)

        def wait(self, timeout):
            return True

        def stop(self):
            pass

        def outcome(self):
            bug = problem("internal-error", "ZeroDivisionError: division by zero (a bug)")
            return worker_mod.Outcome(False, problem=bug)

    with TestClient(create_app(app_settings)) as client:
        up = client.post("/v1/uploads?filename=tree.txt", content=BUNDLED_CLOUD.read_bytes())
        r = client.post(
            "/v1/processes/reconstruct/execution", json={"inputs": {"cloud": up.json()["id"]}}
        )
        job_id = r.json()["jobID"] if "jobID" in r.json() else r.json()["id"]
        store = client.app.state.store
        w = worker_mod.Worker(settings, store)
        monkeypatch.setattr(w, "_start", FailingHandle)
        claim = store.claim(w.id, settings.lease_s)
        assert claim is not None and claim.id == job_id
        w._run(claim)
        status = client.get(f"/v1/jobs/{job_id}").json()
    assert status["status"] == "failed"
    log = status["error"]["log"]
    assert log.endswith(boom)  # the traceback, the log's end
    assert len(log.encode()) <= worker_mod.LOG_TAIL_BYTES + 64  # bounded (the cut's note)
    assert log.startswith("[... the log's start is cut ...]\nfiller line\n")
    jobdir = settings.data_dir / "jobs" / job_id
    assert not any(p.name.startswith("attempt-") for p in jobdir.iterdir())  # attempts gone


# -- 4. every numeric parameter bounded ---------------------------------------------------------
#: Numbers a process's own schema (not the parameter model) declares without a range.
_OPEN_BY_DESIGN: set[str] = set()  # (plot-scan.stations was, until its coordinates had one)


def _unbounded(schema, path: str, out: set[str]) -> None:
    if isinstance(schema, list):
        for s in schema:
            _unbounded(s, path, out)
        return
    if not isinstance(schema, dict):
        return
    t = schema.get("type")
    if t in ("number", "integer") or (isinstance(t, list) and {"number", "integer"} & set(t)):
        lo = "minimum" in schema or "exclusiveMinimum" in schema
        hi = "maximum" in schema or "exclusiveMaximum" in schema
        if not (lo and hi):
            out.add(path)
    for key, value in schema.items():
        if key == "properties":
            for name, sub in value.items():
                _unbounded(sub, f"{path}.{name}", out)
        elif isinstance(value, (dict, list)):
            _unbounded(value, path, out)


def test_every_number_of_every_process_has_a_minimum_and_a_maximum():
    from treesim.service.processes import PROCESSES

    open_: set[str] = set()
    for pid, proc in PROCESSES.items():
        _unbounded(proc.parameters_schema(), pid, open_)
    assert open_ <= _OPEN_BY_DESIGN, sorted(open_ - _OPEN_BY_DESIGN)


@pytest.mark.parametrize(
    ("parameters", "field"),
    [
        ({"scan": {"min_distance_m": 1e308}}, "min_distance_m"),
        ({"scan": {"distance_m": 1e12}}, "distance_m"),
        ({"compare": {"seed": 10**30}}, "seed"),
        ({"scan": {"scanner": {"reflectance": {"wood": 1e308}}}}, "reflectance"),
    ],
)
def test_a_huge_parameter_is_a_422_naming_it(app_settings, parameters, field):
    with TestClient(create_app(app_settings)) as client:
        up = client.post("/v1/uploads?filename=tree.txt", content=BUNDLED_CLOUD.read_bytes())
        r = client.post(
            "/v1/processes/run/execution",
            json={"inputs": {"cloud": up.json()["id"], **parameters}},
        )
    body = _problem(r, 422)
    assert field in body["detail"], body


@pytest.mark.parametrize(
    ("stations", "says"),
    [
        ([[0.0, 0.0]] * 1001, "1000"),  # more stations than a plot scan takes
        ([[1e12, 0.0]], "1e+12"),  # farther than any place on Earth
        ([[0.0, 0.0, -1e300]], "-1e+300"),
    ],
)
def test_absurd_stations_are_a_422_naming_them(app_settings, stations, says):
    with TestClient(create_app(app_settings)) as client:
        r = client.post(
            "/v1/processes/plot-scan/execution",
            json={"inputs": {"stand": {}, "stations": {"value": stations}}},
        )
        body = _problem(r, 422)
        assert body["field"].startswith("parameters.stations"), body
        assert says in body["detail"], body
        # a plot in UTM (northing 5e6 m) is not absurd: accepted
        utm = [[500_000.0, 5_000_000.0], [500_010.0, 5_000_000.0, 301.5]]
        r = client.post(
            "/v1/processes/plot-scan/execution",
            json={"inputs": {"stand": {}, "stations": {"value": utm}}},
        )
        assert r.status_code == 201, r.text


def test_stations_out_of_the_plot_s_reach_are_refused_before_scanning():
    """A station farther from the plot's centre than its radius plus the scanner's range
    records no tree (e.g. local coordinates for a plot in UTM): refused, naming it."""
    from treesim.errors import InvalidParameterError
    from treesim.plot.scan import Station
    from treesim.service.processes.plot_scan import check_stations_reach

    centre, radius_m, range_m = (500_000.0, 5_000_000.0), 15.0, 100.0
    # 3-4-5 triangles: 69 + 46 = 115 m from the centre, exactly the reach
    edge = Station(position_m=(500_069.0, 5_000_092.0, 300.0))
    check_stations_reach([edge], centre, radius_m, range_m)  # at the reach: kept
    past = Station(position_m=(500_069.0, 5_000_092.1, 300.0))
    local = Station(position_m=(3.0, 4.0, 1.5))
    for i, bad in ((2, past), (2, local)):
        with pytest.raises(InvalidParameterError, match=f"station {i} at") as info:
            check_stations_reach([edge, bad], centre, radius_m, range_m)
        assert info.value.field == "stations"


# -- 5. a client that drops mid-upload; a stalled upload ----------------------------------------
def _raw_upload(app, receive) -> tuple[int | None, bytes]:
    """POST /v1/uploads straight into the ASGI app with the given ``receive``: (status,
    body) of what the app answered (None: it answered nothing)."""
    import asyncio

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": "/v1/uploads",
        "raw_path": b"/v1/uploads",
        "query_string": b"filename=tree.txt",
        "root_path": "",
        "headers": [(b"host", b"testserver"), (b"content-length", b"100000")],
        "client": ("127.0.0.1", 5000),
        "server": ("testserver", 80),
        "state": {},
    }
    sent: list[dict] = []

    async def send(message):
        sent.append(message)

    async def main():
        await app(scope, receive, send)

    asyncio.run(main())
    start = next((m for m in sent if m["type"] == "http.response.start"), None)
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return (start["status"] if start else None), body


def test_a_client_dropping_mid_upload_is_a_warning_not_a_500(app_settings, caplog):
    import logging

    steps = iter(
        [
            {"type": "http.request", "body": b"1 2 3\n" * 100, "more_body": True},
            {"type": "http.disconnect"},
        ]
    )

    async def receive():
        return next(steps)

    with TestClient(create_app(app_settings)) as client:
        with caplog.at_level(logging.WARNING):
            status, _ = _raw_upload(client.app, receive)
    assert status is not None and status < 500
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert errors == [], [r.getMessage() for r in errors]
    warned = [r for r in caplog.records if "closed the connection" in r.getMessage()]
    assert len(warned) == 1 and warned[0].exc_info is None  # one line, no traceback
    assert _parts(app_settings.data_dir) == []


def test_a_stalled_upload_times_out_and_its_part_file_is_removed(app_settings):
    import asyncio
    import time

    settings = app_settings.model_copy(update={"upload_stall_s": 0.5})
    parts_seen: list[int] = []
    sent_first = [False]

    async def receive():
        if not sent_first[0]:
            sent_first[0] = True
            return {"type": "http.request", "body": b"1 2 3\n" * 100, "more_body": True}
        parts_seen.append(len(_parts(settings.data_dir)))
        await asyncio.sleep(3600)  # the client stalls

    with TestClient(create_app(settings)) as client:
        t0 = time.monotonic()
        status, body = _raw_upload(client.app, receive)
        waited_s = time.monotonic() - t0
    assert status == 408, body
    assert b"TREESIM_UPLOAD_STALL_S" in body
    assert parts_seen == [1]  # the .part file existed while the body stalled ...
    assert _parts(settings.data_dir) == []  # ... and is gone
    assert waited_s < 30


# -- 6. problem+json for every error status; HEAD on every GET route ----------------------------
def _successful_job(client, settings) -> str:
    """A successful job with one 1000-byte result, made through the store."""
    from treesim.service.jobs.worker import list_results

    store = client.app.state.store
    job_id = store.create_job(
        process="run", inputs={}, parameters={}, max_attempts=1, time_limit_s=60
    )["id"]
    claim = store.claim("test-worker", 30.0)
    results = settings.data_dir / "jobs" / job_id / "results"
    results.mkdir(parents=True)
    (results / "data.bin").write_bytes(bytes(range(250)) * 4)
    assert store.succeed(claim, results=list_results(results), summary={}, message="done")
    return job_id


@pytest.mark.parametrize("byte_range", ["bytes=5000-6000", "bytes=600-100"])
def test_an_unsatisfiable_or_inverted_range_is_a_problem(app_settings, byte_range):
    with TestClient(create_app(app_settings)) as client:
        job_id = _successful_job(client, app_settings)
        url = f"/v1/jobs/{job_id}/results/data.bin"
        assert client.get(url, headers={"Range": "bytes=10-19"}).content == bytes(range(10, 20))
        r = client.get(url, headers={"Range": byte_range})
    assert r.status_code in (400, 416), r.text
    body = _problem(r, r.status_code)
    assert body["detail"]


def test_head_answers_on_every_get_route_as_get_does(app_settings):
    """Every GET route of the API's definition (and the pages left out of it): HEAD gets
    GET's status and content type, and no body."""
    with TestClient(create_app(app_settings)) as client:
        job_id = _successful_job(client, app_settings)
        fill = {"job_id": job_id, "name": "data.bin", "process_id": "run"}
        paths = [p for p, ops in client.app.openapi()["paths"].items() if "get" in ops]
        paths += ["/docs", "/redoc", "/openapi.json"]
        checked = 0
        for template in paths:
            path = template
            for key, value in fill.items():
                path = path.replace(f"{{{key}}}", value)
            path = re.sub(r"\{[^}]+\}", "nope", path)
            get = client.get(path, follow_redirects=False)
            head = client.head(path, follow_redirects=False)
            assert head.status_code == get.status_code, (template, head.status_code)
            assert head.content == b"", template
            ctype = get.headers.get("content-type", "").split(";")[0]
            assert head.headers.get("content-type", "").split(";")[0] == ctype, template
            checked += 1
    assert checked >= 15, checked


def test_head_on_a_large_result_answers_get_s_headers_without_reading_it(app_settings, monkeypatch):
    """HEAD on a download gives GET's headers (size, type, ETag, Last-Modified, a range's
    206 and Content-Range) from the file's stat: the file is never opened (it used to be
    read whole and the bytes thrown away)."""
    import anyio

    from treesim.service.jobs.worker import list_results

    opened: list[str] = []
    real_open = anyio.open_file

    async def spy(file, *args, **kwargs):
        opened.append(Path(file).name)
        return await real_open(file, *args, **kwargs)

    size = 64 * 2**20  # sparse: 64 MiB that a HEAD must not read
    with TestClient(create_app(app_settings)) as client:
        store = client.app.state.store
        job_id = store.create_job(
            process="run", inputs={}, parameters={}, max_attempts=1, time_limit_s=60
        )["id"]
        claim = store.claim("test-worker", 30.0)
        results = app_settings.data_dir / "jobs" / job_id / "results"
        results.mkdir(parents=True)
        with open(results / "big.laz", "wb") as fh:
            fh.truncate(size)
        assert store.succeed(claim, results=list_results(results), summary={}, message="ok")
        url = f"/v1/jobs/{job_id}/results/big.laz"
        monkeypatch.setattr(anyio, "open_file", spy)
        for extra in ({}, {"Range": "bytes=100-199"}):
            head = client.head(url, headers=extra)
            assert opened == [], (extra, opened)  # HEAD never opened the file
            get = client.get(url, headers=extra)
            assert opened == ["big.laz"], opened  # (GET does: the spy sees it)
            opened.clear()
            assert head.status_code == get.status_code == (206 if extra else 200)
            assert head.content == b""
            assert len(get.content) == (100 if extra else size)
            for key in (
                "content-length",
                "content-type",
                "etag",
                "last-modified",
                "content-range",
                "content-disposition",
                "accept-ranges",
            ):
                assert head.headers.get(key) == get.headers.get(key), key
            assert head.headers["content-length"] == str(100 if extra else size)
            assert head.headers["etag"] and head.headers["last-modified"]


# -- 7. leases expired by the API, with no worker alive -----------------------------------------
def test_the_api_hands_back_a_job_whose_worker_died_with_no_worker_alive(app_settings):
    import time

    settings = app_settings.model_copy(update={"lease_s": 2.0})  # workers=0: the API alone
    with TestClient(create_app(settings)) as client:
        store = client.app.state.store
        job_id = store.create_job(
            process="run", inputs={}, parameters={}, max_attempts=2, time_limit_s=60
        )["id"]
        t0 = time.monotonic()  # (before the claim: its lease runs from the claim)
        claim = store.claim("a-worker-that-dies", 2.0)  # ... and never renews its lease
        assert claim is not None and store.job(job_id)["status"] == "running"
        while time.monotonic() - t0 < 30 and store.job(job_id)["status"] == "running":
            time.sleep(0.2)
        job = client.get(f"/v1/jobs/{job_id}").json()
        waited_s = time.monotonic() - t0
    assert job["status"] == "accepted", job  # an attempt is left: handed back
    assert "stopped renewing its lease" in job["message"]
    # not before its lease ended (how soon after depends on the host's load: not asserted)
    assert waited_s >= 2.0 - 0.1


# -- 8. no orphan processes after kill -9 or SIGTERM of serve -----------------------------------
def _session_members(sid: int) -> list[int]:
    """Pids of the live processes in session ``sid`` (Linux /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[3]) == sid and fields[0] != "Z":  # fields: state, ppid, pgrp, session
            out.append(int(d.name))
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="counts processes in /proc")
@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_no_process_outlives_serve(serve, tmp_path, sig):
    import os
    import signal
    import time

    import httpx

    base, srv = serve(tmp_path / "data", workers=0)
    r = httpx.post(
        f"{base}/v1/uploads?filename=tree.txt", content=BUNDLED_CLOUD.read_bytes(), timeout=60
    )
    assert r.status_code == 201, r.text  # the inspector ran
    pid = srv.proc.pid
    assert len(_session_members(pid)) >= 3  # the API, its inspector, the resource tracker
    os.kill(pid, getattr(signal, sig))  # the server alone, not its process group
    srv.proc.wait(30)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30 and _session_members(pid):  # (a loaded host is slow)
        time.sleep(0.1)
    left = _session_members(pid)
    for p in left:  # clean up what this test started before failing
        os.kill(p, signal.SIGKILL)
    assert left == [], f"{len(left)} processes outlived the server after {sig}"
