"""Named users (issue 24, "Users"): a tokens file maps users to token hashes and roles;
each user lists, reads, downloads, chains and dismisses only their own uploads and jobs
(another's is 404, as if it did not exist, never 403); an admin sees all. The route walk
takes every ``/v1`` route with an upload or job id from the app itself, so that a route
added later is checked without being named here."""

from __future__ import annotations

import base64
import hashlib
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from treesim.errors import InputFormatError
from treesim.service.api.deps import hash_token, load_tokens
from treesim.service.app import create_app
from treesim.service.jobs.store import Store
from treesim.service.settings import Settings

from .conftest import store_url

TOKENS = {"ana": "ana-secret-1", "ben": "ben-secret-2", "root": "root-secret-3"}
ROLES = {"ana": "user", "ben": "user", "root": "admin"}
# two different small clouds (the service stores each content once)
CLOUD_A = b"".join(f"{i * 0.1:.3f} {i * 0.05:.3f} {i * 0.02:.3f}\n".encode() for i in range(200))
CLOUD_B = b"".join(f"{i * 0.2:.3f} {i * 0.07:.3f} {i * 0.03:.3f}\n".encode() for i in range(200))


def _auth(user: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {TOKENS[user]}"}


def _tokens_file(path: Path) -> Path:
    lines = []
    for user, token in TOKENS.items():
        # the hash as the documented shell one-liner makes it, not by the code under test
        digest = hashlib.sha256(token.encode()).hexdigest()
        lines += [f"[{user}]", f'token_sha256 = "{digest}"', f'role = "{ROLES[user]}"', ""]
    path.write_text("\n".join(lines))
    return path


@pytest.fixture(params=["sqlite", "postgres"])
def app_and_client(request, tmp_path):
    settings = Settings(
        data_dir=tmp_path / "data",
        workers=0,
        api_token="legacy-token",
        database_url=store_url(request.param, tmp_path),
        tokens_file=_tokens_file(tmp_path / "tokens.toml"),
    )
    app = create_app(settings)
    with TestClient(app) as c:
        yield app, c


def _upload(client, user: str, body: bytes, name: str = "c.xyz") -> str:
    r = client.post(f"/v1/uploads?filename={name}", content=body, headers=_auth(user))
    assert r.status_code in (200, 201), r.text
    return r.json()["id"]


def _job(client, user: str, upload_id: str) -> str:
    body = {"process": "run", "inputs": {"cloud": upload_id}, "parameters": {"preset": "draft"}}
    r = client.post("/v1/jobs", json=body, headers=_auth(user))
    assert r.status_code == 201, r.text
    return r.json()["jobID"]


def _succeed(app, job_id: str) -> None:
    """Finish ``job_id`` as a worker would, with one report file."""
    store: Store = app.state.store
    claim = store.claim("test-worker", 60.0)
    assert claim is not None and claim.id == job_id
    results = app.state.settings.data_dir / "jobs" / job_id / "results"
    results.mkdir(parents=True, exist_ok=True)
    (results / "report.html").write_text("<!doctype html><title>r</title>")
    item = {"name": "report.html", "size_bytes": 31, "media_type": "text/html"}
    assert store.succeed(claim, results=[item], summary={})


def _id_routes(app) -> list[tuple[str, str]]:
    """(method, path template) of every /v1 operation that takes an upload or a job id,
    from the API's own definition (every route FastAPI serves is in it)."""
    out = []
    for path, item in app.openapi()["paths"].items():
        if path.startswith("/v1") and ("{upload_id}" in path or "{job_id}" in path):
            out += [(m.upper(), path) for m in sorted(item) if m in ("get", "delete", "post")]
    return out


def _fill(path: str, upload_id: str, job_id: str) -> str:
    return (
        path.replace("{upload_id}", upload_id)
        .replace("{job_id}", job_id)
        .replace("{name}", "report.html")
    )


def test_hash_and_tokens_file(tmp_path):
    assert hash_token("abc") == hashlib.sha256(b"abc").hexdigest()
    users = load_tokens(_tokens_file(tmp_path / "t.toml"))
    assert {u.name: u.role for u in users.values()} == ROLES
    bad = tmp_path / "bad.toml"
    bad.write_text('[eve]\ntoken_sha256 = "abc"\nrole = "user"\n')
    with pytest.raises(InputFormatError, match="eve"):
        load_tokens(bad)
    bad.write_text(f'[eve]\ntoken_sha256 = "{"0" * 64}"\nrole = "root"\n')
    with pytest.raises(InputFormatError, match="role"):
        load_tokens(bad)


def test_tokens_authenticate_and_wrong_ones_do_not(app_and_client):
    _, client = app_and_client
    for user in TOKENS:
        assert client.get("/v1/jobs", headers=_auth(user)).status_code == 200
    # the single token of before is one more admin
    assert client.get("/v1/jobs", headers={"Authorization": "Bearer legacy-token"}).is_success
    for bad in ({}, {"Authorization": "Bearer ana-secret"}, {"Authorization": "Bearer x"}):
        assert client.get("/v1/jobs", headers=bad).status_code == 401
    # a hash is not a token
    digest = hashlib.sha256(TOKENS["ana"].encode()).hexdigest()
    assert client.get("/v1/jobs", headers={"Authorization": f"Bearer {digest}"}).status_code == 401


def test_each_user_sees_only_their_own_and_the_admin_all(app_and_client):
    app, client = app_and_client
    up_a = _upload(client, "ana", CLOUD_A)
    job_a = _job(client, "ana", up_a)
    _succeed(app, job_a)
    up_b = _upload(client, "ben", CLOUD_B)
    job_b = _job(client, "ben", up_b)

    def listed(user: str) -> tuple[set[str], set[str]]:
        ups = client.get("/v1/uploads", headers=_auth(user)).json()["uploads"]
        js = client.get("/v1/jobs?limit=100", headers=_auth(user)).json()["jobs"]
        return {u["id"] for u in ups}, {j["jobID"] for j in js}

    assert listed("ana") == ({up_a}, {job_a})
    assert listed("ben") == ({up_b}, {job_b})
    assert listed("root") == ({up_a, up_b}, {job_a, job_b})

    routes = _id_routes(app)
    # every route of the API that takes an id is walked (and there are some of each)
    assert {p for _, p in routes} >= {
        "/v1/uploads/{upload_id}",
        "/v1/jobs/{job_id}",
        "/v1/jobs/{job_id}/results",
        "/v1/jobs/{job_id}/results/{name}",
    }
    reads = [(m, p) for m, p in routes if m == "GET"]
    deletes = [(m, p) for m, p in routes if m != "GET"]
    for method, path in reads + deletes:  # ben on ana's: 404, and nothing happens
        r = client.request(method, _fill(path, up_a, job_a), headers=_auth("ben"))
        assert r.status_code == 404, (method, path, r.status_code, r.text)
        assert r.headers["content-type"].startswith("application/problem+json")
    for method, path in reads:  # ana and the admin read ana's
        for user in ("ana", "root"):
            r = client.request(
                method, _fill(path, up_a, job_a), headers=_auth(user), follow_redirects=False
            )
            assert r.status_code in (200, 307), (user, method, path, r.status_code, r.text)
    assert listed("ana") == ({up_a}, {job_a})  # ben's deletes did nothing

    # chaining: ben may not name ana's upload or job result, by id or by href
    base = "http://testserver/v1"
    for cloud in (
        up_a,
        {"href": f"{base}/uploads/{up_a}"},
        {"job": job_a, "result": "report.html"},
        {"href": f"{base}/jobs/{job_a}/results/report.html"},
    ):
        body = {"process": "run", "inputs": {"cloud": cloud}}
        r = client.post("/v1/jobs", json=body, headers=_auth("ben"))
        assert r.status_code == 404, (cloud, r.text)

    # the admin dismisses ben's job; ana dismisses her own
    assert client.delete(f"/v1/jobs/{job_b}", headers=_auth("root")).json()["status"] == "dismissed"
    assert client.delete(f"/v1/jobs/{job_a}", headers=_auth("ana")).json()["status"] == "dismissed"
    assert client.delete(f"/v1/uploads/{up_b}", headers=_auth("root")).status_code == 204
    assert client.get(f"/v1/uploads/{up_b}", headers=_auth("ben")).status_code == 404


def test_same_content_is_owned_by_each_sender(app_and_client):
    app, client = app_and_client
    up_a = _upload(client, "ana", CLOUD_A)
    assert client.get(f"/v1/uploads/{up_a}", headers=_auth("ben")).status_code == 404
    # ben sends the same bytes: the same stored upload, now his too
    assert _upload(client, "ben", CLOUD_A) == up_a
    assert client.get(f"/v1/uploads/{up_a}", headers=_auth("ben")).status_code == 200
    # ben deleting it takes it from his list only: ana keeps it, and the file stays
    assert client.delete(f"/v1/uploads/{up_a}", headers=_auth("ben")).status_code == 204
    assert client.get(f"/v1/uploads/{up_a}", headers=_auth("ben")).status_code == 404
    rec = client.get(f"/v1/uploads/{up_a}", headers=_auth("ana"))
    assert rec.status_code == 200
    stored = list((app.state.settings.data_dir / "uploads").rglob("*.xyz"))
    assert len(stored) == 1
    # ana, the last owner, deletes it: the file goes
    assert client.delete(f"/v1/uploads/{up_a}", headers=_auth("ana")).status_code == 204
    assert not list((app.state.settings.data_dir / "uploads").rglob("*.xyz"))
    assert client.get(f"/v1/uploads/{up_a}", headers=_auth("root")).status_code == 404


def test_migration_keeps_old_rows_without_owner(tmp_path):
    """A job store of the first schema (0001) with a job and an upload is upgraded: the rows
    stay, with no owner, seen by an admin and by no user."""
    import sqlalchemy as sa
    from alembic import command
    from alembic.config import Config

    from treesim.service.jobs import store as store_mod

    url = f"sqlite:///{tmp_path / 'old.db'}"
    engine = sa.create_engine(url)
    cfg = Config()
    cfg.set_main_option("script_location", str(Path(store_mod.__file__).parent / "migrations"))
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "0001")
        conn.execute(
            sa.text(
                "INSERT INTO jobs (id, process, status, inputs, parameters, progress, attempt,"
                " max_attempts, time_limit_s, created, updated) VALUES ('j-old', 'run',"
                " 'accepted', '{}', '{}', 0, 0, 3, 60, 1.0, 1.0)"
            )
        )
        conn.execute(
            sa.text(
                "INSERT INTO uploads (id, sha256, filename, format, kind, size_bytes, info, path,"
                " created) VALUES ('u-old', 'ab', 'c.xyz', 'xyz', 'cloud', 3, '{}', 'x', 1.0)"
            )
        )
    engine.dispose()
    s = Store(url)  # migrates to the newest schema
    try:
        assert s.job("j-old")["owner"] is None
        assert s.job("j-old", owner="ana") is None
        assert [j["id"] for j in s.list_jobs(owner="ana")[0]] == []
        assert [j["id"] for j in s.list_jobs()[0]] == ["j-old"]
        assert s.upload("u-old") is not None and s.upload("u-old", owner="ana") is None
    finally:
        s.dispose()
    # and back: 0002's downgrade leaves the first schema, with the rows
    engine = sa.create_engine(url)
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.downgrade(cfg, "0001")
        cols = {c["name"] for c in sa.inspect(conn).get_columns("jobs")}
        assert "owner" not in cols and "upload_owners" not in sa.inspect(conn).get_table_names()
        assert conn.execute(sa.text("SELECT id FROM jobs")).scalar() == "j-old"
    engine.dispose()


def test_metrics_need_an_admin_unless_opened(app_and_client, tmp_path):
    _, client = app_and_client
    assert client.get("/metrics").status_code == 401
    assert client.get("/metrics", headers=_auth("ana")).status_code == 401
    r = client.get("/metrics", headers=_auth("root"))
    assert r.status_code == 200 and "treesim" in r.text
    opened = Settings(
        data_dir=tmp_path / "open",
        workers=0,
        api_token="legacy-token",
        database_url=None,
        metrics_open=True,
    )
    with TestClient(create_app(opened)) as c:
        assert c.get("/metrics").status_code == 200


def test_the_pages_session_is_an_httponly_cookie_for_reading(app_and_client):
    app, client = app_and_client
    up_a = _upload(client, "ana", CLOUD_A)
    assert client.post("/session", json={"token": "wrong"}).status_code == 401
    assert "set-cookie" not in client.post("/session", json={"token": "wrong"}).headers
    r = client.post("/session", json={"token": TOKENS["ana"]})
    assert r.status_code == 200 and r.json()["user"] == "ana"
    cookie = r.headers["set-cookie"]
    attrs = {a.strip().split("=")[0].lower() for a in cookie.split(";")}
    assert {"httponly", "samesite"} <= attrs and "samesite=strict" in cookie.lower()
    assert "secure" not in attrs  # plain http here; https sets Secure
    value = cookie.split(";")[0].split("=", 1)[1]
    assert (
        TOKENS["ana"] not in cookie
        and hashlib.sha256(TOKENS["ana"].encode()).hexdigest()[:16] not in value
    )
    # the session reads as ana (her upload, not another's), and never writes
    assert client.get("/session").json()["user"] == "ana"
    assert client.get(f"/v1/uploads/{up_a}").status_code == 200
    assert client.post("/v1/uploads?filename=c.xyz", content=CLOUD_B).status_code == 401
    # a forged session (another name with ana's signature) is refused
    name, expires, sig = value.strip('"').split(".")
    forged = f"{base64.urlsafe_b64encode(b'root').decode()}.{expires}.{sig}"
    client.cookies.set("treesim_session", forged)
    assert client.get("/v1/jobs").status_code == 401
    client.cookies.clear()
    # over https the cookie is Secure too
    https = TestClient(app, base_url="https://testserver")
    r = https.post("/session", json={"token": TOKENS["ben"]})
    assert "secure" in {a.strip().lower() for a in r.headers["set-cookie"].split(";")}
    # signing out clears it
    assert client.delete("/session").status_code == 204
