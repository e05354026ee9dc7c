"""The HTTP API in-process (FastAPI's TestClient, no worker): uploads, bad input, jobs,
processes, tokens, problems. Every bad input is a 4xx ``application/problem+json`` with
nothing stored."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from treesim.cloud import Cloud
from treesim.io import write_cloud
from treesim.service.app import create_app
from treesim.service.settings import Settings

from .conftest import BUNDLED_CLOUD

PROBLEM = "application/problem+json"


def _settings(data_dir: Path, **kw) -> Settings:
    base = dict(
        data_dir=data_dir, workers=0, api_token=None, database_url=None, poll_interval_s=0.2
    )
    return Settings(**{**base, **kw})


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("api") / "data"


@pytest.fixture(scope="module")
def client(data_dir) -> TestClient:
    app = create_app(_settings(data_dir, max_upload_bytes=2_000_000))
    with TestClient(app) as c:
        yield c


@pytest.fixture(scope="module")
def samples(tmp_path_factory) -> dict[str, Path]:
    """Small files of every kind, written by treesim's own writers."""
    d = tmp_path_factory.mktemp("samples")
    rng = np.random.default_rng(7)
    xyz = rng.uniform(-1.0, 1.0, (4000, 3)) + [500_000.0, 5_200_000.0, 300.0]
    cloud = Cloud(xyz)
    out = {}
    for suffix in (".laz", ".las", ".ply", ".xyz"):
        out[suffix] = write_cloud(d / f"c{suffix}", cloud)
    out["bounds"] = (xyz.min(0), xyz.max(0))
    return out


def _stored_files(data_dir: Path) -> list[Path]:
    root = data_dir / "uploads"
    return sorted(p for p in root.rglob("*") if p.is_file()) if root.exists() else []


def _assert_problem(r, status: int, field: str | None = None, contains: str | None = None):
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers["content-type"]
    body = r.json()
    assert body["status"] == status
    # treesim's problem types, or OGC API - Processes' exception URIs (no-such-job, ...)
    assert body["type"].startswith(("/problems#", "http://www.opengis.net/def/exceptions/"))
    assert body["detail"]
    if field is not None:
        assert body.get("field") == field, body
    if contains is not None:
        assert contains.lower() in body["detail"].lower(), body["detail"]
    return body


def _upload(client, path: Path, filename: str | None = None):
    name = filename or path.name
    return client.post(f"/v1/uploads?filename={name}", content=path.read_bytes())


# -- uploads ----------------------------------------------------------------------------------
def test_upload_reports_format_counts_bounds_and_hash(client, samples, data_dir):
    import hashlib

    lo, hi = samples["bounds"]
    for suffix in (".laz", ".ply", ".xyz"):
        path = samples[suffix]
        # the name says nothing about the content: the bytes decide
        r = client.post("/v1/uploads?filename=tree-without-suffix", content=path.read_bytes())
        assert r.status_code in (200, 201), r.text
        up = r.json()
        assert up["format"] == suffix[1:]
        assert up["kind"] == "cloud"
        assert up["n_points"] == 4000
        assert up["size_bytes"] == path.stat().st_size
        assert up["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
        # LAS/LAZ store scaled integers: bounds within the writer's scale (1e-4 m or finer)
        np.testing.assert_allclose(up["bounds"]["min"], lo, atol=1e-3)
        np.testing.assert_allclose(up["bounds"]["max"], hi, atol=1e-3)
        assert r.headers["location"] == f"/v1/uploads/{up['id']}"
        assert client.get(f"/v1/uploads/{up['id']}").json() == up
        stored = data_dir / "uploads" / up["sha256"][:2]
        assert any(p.name.startswith(up["sha256"]) for p in stored.iterdir())


def test_same_content_is_stored_once(client, samples, data_dir):
    first = _upload(client, samples[".las"], "a.las")
    again = _upload(client, samples[".las"], "b.las")
    assert first.status_code == 201 and again.status_code == 200, (first.text, again.text)
    assert again.json()["id"] == first.json()["id"]
    sha = first.json()["sha256"]
    copies = [p for p in _stored_files(data_dir) if p.name.startswith(sha)]
    assert len(copies) == 1


def test_the_bundled_tree_uploads(client):
    r = _upload(client, BUNDLED_CLOUD)
    assert r.status_code in (200, 201), r.text
    n_lines = sum(1 for line in BUNDLED_CLOUD.read_text().splitlines() if line.strip())
    assert r.json()["n_points"] == n_lines
    assert r.json()["filename"] == "cloud.txt"


@pytest.fixture
def nothing_stored(client, data_dir):
    """Asserts at the end that the test left no upload record and no file behind."""
    before_files = _stored_files(data_dir)
    before = client.get("/v1/uploads?limit=1000").json()["uploads"]
    yield
    assert client.get("/v1/uploads?limit=1000").json()["uploads"] == before
    assert _stored_files(data_dir) == before_files


def test_empty_body(client, nothing_stored):
    r = client.post("/v1/uploads?filename=tree.las", content=b"")
    _assert_problem(r, 422, contains="empty")


def test_truncated_laz(client, samples, nothing_stored):
    data = samples[".laz"].read_bytes()
    r = client.post("/v1/uploads?filename=tree.laz", content=data[: len(data) // 2])
    _assert_problem(r, 422)


def test_truncated_las_header(client, samples, nothing_stored):
    r = client.post("/v1/uploads?filename=tree.las", content=samples[".las"].read_bytes()[:150])
    assert r.status_code in (415, 422), r.text
    _assert_problem(r, r.status_code)


def test_text_named_las(client, nothing_stored):
    body = b"This is not a point cloud.\nIt is a letter to the editor.\n" * 20
    r = client.post("/v1/uploads?filename=tree.las", content=body)
    _assert_problem(r, 415)


def test_binary_garbage(client, nothing_stored):
    body = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 8
    _assert_problem(client.post("/v1/uploads?filename=tree.png", content=body), 415)


def test_nan_coordinates(client, nothing_stored):
    body = b"0 0 0\n1 1 1\nnan 2 2\n3 3 3\n"
    _assert_problem(client.post("/v1/uploads?filename=tree.xyz", content=body), 422)


def test_upload_past_the_limit_by_content_length(client, nothing_stored):
    body = b"0 0 0\n" * 400_000  # 2.4 MB > the 2 MB limit of this app
    r = client.post("/v1/uploads?filename=big.xyz", content=body)
    _assert_problem(r, 413, contains="limit")


def test_upload_past_the_limit_while_streaming(client, data_dir, nothing_stored):
    def chunks():  # no Content-Length: chunked transfer, counted as it arrives
        for _ in range(40):
            yield b"0 0 0\n" * 10_000

    r = client.post("/v1/uploads?filename=big.xyz", content=chunks())
    _assert_problem(r, 413)
    assert not list((data_dir / "uploads" / "tmp").iterdir())


@pytest.mark.parametrize(
    "name", ["../../etc/passwd", "a/b.las", "..", "x\\y.las", "bad\x00name.las", "é" * 200]
)
def test_filename_that_is_a_path(client, samples, name, nothing_stored):
    r = client.post("/v1/uploads", params={"filename": name}, content=samples[".xyz"].read_bytes())
    _assert_problem(r, 422, field="filename")


def test_missing_upload_is_404(client):
    _assert_problem(client.get("/v1/uploads/nope"), 404, field="upload_id")
    _assert_problem(client.delete("/v1/uploads/nope"), 404, field="upload_id")


# -- processes and jobs -----------------------------------------------------------------------
def test_processes_describe_inputs_and_parameter_schemas(client):
    ids = [p["id"] for p in client.get("/v1/processes").json()["processes"]]
    assert ids == [
        "run", "reconstruct", "scan", "compare", "plan", "plot-scan", "plot-from-cloud", "validate"
    ]  # fmt: skip
    run = client.get("/v1/processes/run").json()
    props = run["parameters"]["properties"]
    assert set(props["preset"]["enum"]) == {"draft", "standard", "fine"}
    assert props["preset"]["default"] == "standard"
    assert "scan" in props and "reconstruct" in props
    assert "threads" not in props and "nthreads" not in props["compare"]["properties"]
    assert "cloud" in run["inputs"]
    scan = client.get("/v1/processes/scan").json()
    assert "instrument" in scan["parameters"]["properties"]
    compare = client.get("/v1/processes/compare").json()["inputs"]
    assert {"cloud", "reference"} <= set(compare)  # the files, and each setting too
    assert compare["cloud"]["minOccurs"] == compare["reference"]["minOccurs"] == 1
    _assert_problem(client.get("/v1/processes/nope"), 404, field="process_id")


def test_parameter_schemas_accept_the_models_defaults(client):
    """Each process's parameter schema validates the defaults the model would use, so a
    client that fills in every default is accepted."""
    import jsonschema

    from treesim.params import RunParams, execution_only_paths

    defaults = RunParams().to_dict()
    for path in execution_only_paths():  # threads, timeouts: the worker decides those
        node = defaults
        for key in path[:-1]:
            node = node[key]
        node.pop(path[-1])
    for pid in ("reconstruct", "scan", "compare"):
        params = defaults[pid]
        schema = client.get(f"/v1/processes/{pid}").json()["parameters"]
        jsonschema.validate(params, schema)


@pytest.fixture(scope="module")
def cloud_id(client) -> str:
    return _upload(client, BUNDLED_CLOUD).json()["id"]


def test_job_is_accepted_with_location_and_links(client, cloud_id):
    r = client.post(
        "/v1/jobs",
        json={"process": "run", "inputs": {"cloud": cloud_id}, "parameters": {"preset": "draft"}},
    )
    assert r.status_code == 201, r.text
    job = r.json()
    assert r.headers["location"].endswith(f"/v1/jobs/{job['jobID']}")
    assert job["status"] == "accepted" and job["progress"] == 0 and job["attempt"] == 0
    assert job["inputs"]["cloud"]["upload"] == cloud_id
    assert client.get(r.headers["location"]).json()["jobID"] == job["jobID"]
    listed = client.get("/v1/jobs?status=accepted&limit=1000").json()["jobs"]
    assert job["jobID"] in [j["jobID"] for j in listed]
    # not ready: OGC API - Processes answers 404 for the results of an unfinished job
    _assert_problem(client.get(f"/v1/jobs/{job['jobID']}/results"), 404, contains="accepted")
    # an upload a job reads cannot be deleted until the job is over
    body = _assert_problem(client.delete(f"/v1/uploads/{cloud_id}"), 409)
    assert job["jobID"] in body["jobs"]
    gone = client.delete(f"/v1/jobs/{job['jobID']}").json()
    assert gone["status"] == "dismissed"


def test_ogc_execution_is_the_same(client, cloud_id):
    r = client.post("/v1/processes/reconstruct/execution", json={"inputs": {"cloud": cloud_id}})
    assert r.status_code == 201, r.text
    assert r.json()["processID"] == "reconstruct"
    client.delete(r.headers["location"])


@pytest.mark.parametrize(
    "parameters, field",
    [
        ({"no_such_thing": 1}, "parameters.no_such_thing"),
        ({"preset": "ultra"}, "parameters.preset"),
        ({"scan": {"scanner": {"max_range_m": -5}}}, "parameters.scan.scanner"),
        ({"scan": {"scanner": {"subrays": 2.5}}}, "parameters.scan.scanner.subrays"),
        ({"scan": {"n_stations": "three"}}, "parameters.scan.n_stations"),
        ({"reconstruct": {"method": "magic"}}, "parameters.reconstruct.method"),
        ({"scan": {"scanner": {"horizontal_resolution_deg": math.inf}}}, None),
    ],
)
def test_bad_parameters_name_the_field(client, cloud_id, parameters, field):
    before = len(client.get("/v1/jobs?limit=1000").json()["jobs"])
    r = client.post(
        "/v1/jobs",
        content=_json_allowing_inf(
            {"process": "run", "inputs": {"cloud": cloud_id}, "parameters": parameters}
        ),
        headers={"content-type": "application/json"},
    )
    assert r.status_code == 422, r.text
    body = r.json()
    if field is not None:
        assert body["field"] == field, body
    assert len(client.get("/v1/jobs?limit=1000").json()["jobs"]) == before


def _json_allowing_inf(obj) -> str:
    import json

    return json.dumps(obj)  # Infinity is not JSON: the server must refuse it, not crash


def test_job_naming_a_missing_upload(client):
    r = client.post("/v1/jobs", json={"process": "run", "inputs": {"cloud": "no-such-upload"}})
    _assert_problem(r, 404, field="inputs.cloud")


def test_job_input_errors(client, cloud_id):
    _assert_problem(
        client.post("/v1/jobs", json={"process": "run", "inputs": {}}), 422, field="inputs.cloud"
    )
    _assert_problem(
        client.post("/v1/jobs", json={"process": "run", "inputs": {"cloud": cloud_id, "x": "y"}}),
        422,
        field="inputs.x",
    )
    _assert_problem(
        client.post("/v1/jobs", json={"process": "scan", "inputs": {"mesh": cloud_id}}),
        422,
        field="inputs.mesh",
        contains="mesh",
    )
    _assert_problem(
        client.post(
            "/v1/jobs",
            json={"process": "scan", "inputs": {"mesh": {"job": "nope", "result": "tree.ply"}}},
        ),
        404,
        field="inputs.mesh",
    )
    _assert_problem(
        client.post("/v1/jobs", json={"process": "nope", "inputs": {}}), 422, field="process"
    )
    r = client.post("/v1/jobs", content=b"{not json", headers={"content-type": "application/json"})
    _assert_problem(r, 422)


def test_job_listing_pages_with_a_cursor(client, cloud_id):
    made = []
    for _ in range(5):
        r = client.post("/v1/jobs", json={"process": "reconstruct", "inputs": {"cloud": cloud_id}})
        made.append(r.json()["jobID"])
    seen: list[str] = []
    url = "/v1/jobs?limit=2&status=accepted"
    while url:
        page = client.get(url).json()
        assert len(page["jobs"]) <= 2
        seen.extend(j["jobID"] for j in page["jobs"])
        url = next((link["href"] for link in page["links"] if link["rel"] == "next"), None)
    assert len(seen) == len(set(seen))
    assert [j for j in seen if j in made] == made[::-1]  # newest first, none twice
    _assert_problem(client.get("/v1/jobs?status=sleeping"), 422, field="status")
    _assert_problem(client.get("/v1/jobs?cursor=garbage"), 422)
    for j in made:
        client.delete(f"/v1/jobs/{j}")


def test_unknown_job_is_404(client):
    for path in ("/v1/jobs/nope", "/v1/jobs/nope/results", "/v1/jobs/nope/report"):
        _assert_problem(client.get(path), 404)
    _assert_problem(client.delete("/v1/jobs/nope"), 404)


def test_health_ready_metrics_and_pages(client):
    assert client.get("/healthz").status_code == 200
    ready = client.get("/readyz")
    # no worker in this app: not ready, and it says why
    assert ready.status_code == 503
    assert "worker" in ready.text
    client.get("/v1/jobs/no-such-job")
    m = client.get("/metrics").text
    # requests by route template (prefix included, ids not) and status
    assert 'treesim_http_requests_total{method="GET",route="/v1/jobs/{job_id}",status="404"}' in m
    assert "no-such-job" not in m
    accepted = len(client.get("/v1/jobs?status=accepted&limit=1000").json()["jobs"])
    assert f'treesim_jobs{{status="accepted"}} {float(accepted)}' in m
    assert f"treesim_queue_depth {float(accepted)}" in m
    for name in ("treesim_lease_expiries", "treesim_workers_alive", "treesim_stage_duration"):
        assert name in m, name
    page = client.get("/", headers={"Accept": "text/html"})  # a browser's: JSON otherwise
    assert page.status_code == 200 and "<form" in page.text
    assert "http://" not in page.text and "https://" not in page.text  # no external resources
    assert client.get("/problems").status_code == 200
    assert client.get("/openapi.json").json()["info"]["title"]


# -- the token --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def locked(tmp_path_factory):
    app = create_app(_settings(tmp_path_factory.mktemp("locked") / "data", api_token="s3cret"))
    with TestClient(app) as c:
        yield c


def test_token_required_on_every_v1_route(locked, samples):
    routes = [
        ("GET", "/v1/uploads"),
        ("GET", "/v1/jobs"),
        ("GET", "/v1/processes"),
        ("POST", "/v1/jobs"),
        ("POST", "/v1/uploads?filename=x.xyz"),
    ]
    for method, path in routes:
        for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": "s3cret"}):
            r = locked.request(method, path, headers=headers, content=b"0 0 0\n")
            _assert_problem(r, 401)
            assert r.headers["www-authenticate"].startswith("Bearer")
    ok = {"Authorization": "Bearer s3cret"}
    assert locked.get("/v1/uploads", headers=ok).json() == {"uploads": []}
    r = locked.post("/v1/uploads?filename=c.xyz", headers=ok, content=samples[".xyz"].read_bytes())
    assert r.status_code == 201
    # health and the page stay open (they reveal nothing); the API does not
    assert locked.get("/healthz").status_code == 200
    assert locked.get("/").status_code == 200


def test_the_pages_cookie_opens_reads_only(locked):
    # the page's session (set by the server from the token, HttpOnly), never the raw token
    locked.cookies.set("treesim_token", "s3cret")
    _assert_problem(locked.get("/v1/jobs"), 401)
    locked.cookies.clear()
    assert locked.post("/session", json={"token": "s3cret"}).status_code == 200
    try:
        assert locked.get("/v1/jobs").status_code == 200
        r = locked.post("/v1/jobs", json={"process": "run", "inputs": {"cloud": "x"}})
        _assert_problem(r, 401)
        locked.cookies.set("treesim_session", "wrong")
        _assert_problem(locked.get("/v1/jobs"), 401)
    finally:
        locked.cookies.clear()
