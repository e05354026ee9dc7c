"""OGC API - Processes - Part 1: Core, in-process (TestClient, no worker): the landing page
at ``/v1/`` and ``/`` (JSON unless a browser asks for HTML), conformance, the process list
and descriptions (every input with its schema, every setting an input, outputs by id),
the execute request (inputs by href or value, ``Prefer: respond-async``, remote hrefs
refused), and the OGC exception types. Oracles: the standard's requirement texts (link
relations, class URIs, exception URIs) and the parameter model's own schema."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from treesim.service.app import create_app
from treesim.service.processes import PROCESSES
from treesim.service.settings import Settings

from .conftest import BUNDLED_CLOUD

OGC_REL = "http://www.opengis.net/def/rel/ogc/1.0/"
EXC = "http://www.opengis.net/def/exceptions/ogcapi-processes-1/1.0/"
CONF = "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/"


def _settings(data_dir: Path, **kw) -> Settings:
    base = dict(data_dir=data_dir, workers=0, api_token=None, database_url=None)
    return Settings(**{**base, **kw})


@pytest.fixture(scope="module")
def client(tmp_path_factory) -> TestClient:
    app = create_app(_settings(tmp_path_factory.mktemp("ogc") / "data"))
    with TestClient(app) as c:
        yield c


@pytest.fixture(scope="module")
def upload(client) -> dict:
    r = client.post("/v1/uploads?filename=cloud.txt", content=BUNDLED_CLOUD.read_bytes())
    assert r.status_code in (200, 201), r.text
    return r.json()


def _rels(doc: dict) -> dict[str, dict]:
    return {link["rel"]: link for link in doc["links"]}


def _ogc_problem(r, status: int, kind: str) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    assert body["type"] == EXC + kind, body
    assert body["status"] == status and body["detail"]
    return body


# -- landing page and conformance -------------------------------------------------------------
def test_landing_page_links_what_part_1_requires(client):
    page = client.get("/v1/").json()
    rels = _rels(page)
    for rel in ("service-desc", "service-doc", OGC_REL + "conformance", OGC_REL + "processes"):
        assert rel in rels, rel
    assert rels[OGC_REL + "processes"]["href"] == "http://testserver/v1/processes"
    assert rels[OGC_REL + "job-list"]["href"] == "http://testserver/v1/jobs"
    assert rels["self"]["href"] == "http://testserver/v1/"
    assert all(link["type"] for link in page["links"])  # never null
    # the links lead somewhere: the OpenAPI document, the docs, the conformance classes
    assert client.get(rels["service-desc"]["href"]).json()["openapi"].startswith("3.")
    assert client.get(rels["service-doc"]["href"]).status_code == 200
    assert client.get(rels[OGC_REL + "conformance"]["href"]).status_code == 200


def test_the_oas30_service_desc_is_a_valid_openapi_30_document(client):
    """The oas30 class: a service-desc in OpenAPI 3.0 that a 3.0 validator accepts (and
    that FastAPI's own 3.1 document, said to be 3.0, is not: the check can fail)."""
    from openapi_spec_validator import validate
    from openapi_spec_validator.validation.exceptions import OpenAPIValidationError

    descs = [link for link in client.get("/v1/").json()["links"] if link["rel"] == "service-desc"]
    oas30 = [link for link in descs if link["type"].endswith("version=3.0")]
    assert len(oas30) == 1, descs
    doc = client.get(oas30[0]["href"]).json()
    assert doc["openapi"] == "3.0.3"
    validate(doc)
    assert set(doc["paths"]) == set(client.get("/openapi.json").json()["paths"])
    native = client.get("/openapi.json").json()
    with pytest.raises(OpenAPIValidationError):
        validate({**native, "openapi": "3.0.3"})


@pytest.mark.parametrize(
    "accept, query, html",
    [
        ("text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8", "", True),  # Firefox
        ("application/json", "", False),
        ("*/*", "", False),  # requests, curl, OWSLib
        ("text/html", "?f=json", False),
        ("application/json", "?f=html", True),
        ("application/json, text/html;q=0.5", "", False),
    ],
)
def test_root_is_the_page_for_a_browser_and_the_landing_page_for_a_client(
    client, accept, query, html
):
    r = client.get("/" + query, headers={"Accept": accept})
    assert r.status_code == 200
    if html:
        assert r.headers["content-type"].startswith("text/html") and "<form" in r.text
    else:
        assert r.headers["content-type"].startswith("application/json")
        assert OGC_REL + "processes" in _rels(r.json())
    assert "accept" in r.headers["vary"].lower()


def test_conformance_lists_the_classes(client):
    want = {CONF + c for c in ("core", "ogc-process-description", "json", "oas30")}
    want |= {CONF + "job-list", CONF + "dismiss"}
    assert set(client.get("/v1/conformance").json()["conformsTo"]) == want


def test_the_roots_ogc_paths_lead_to_v1(client, upload):
    """A client given the server's root (OWSLib joins paths to it) finds every resource:
    a 308 keeps the method and body."""
    assert client.get("/conformance").json() == client.get("/v1/conformance").json()
    r = client.get("/processes?limit=2", follow_redirects=False)
    assert r.status_code == 308 and r.headers["location"] == "/v1/processes?limit=2"
    assert len(client.get("/processes?limit=2").json()["processes"]) == 2
    body = {"inputs": {"cloud": upload["links"][0]["href"], "preset": "draft"}}
    job = client.post("/processes/reconstruct/execution", json=body)
    assert job.status_code == 201, job.text
    assert client.get(f"/jobs/{job.json()['jobID']}").json()["processID"] == "reconstruct"
    assert client.delete(f"/jobs/{job.json()['jobID']}").json()["status"] == "dismissed"


def test_the_landing_page_and_conformance_need_no_token(tmp_path):
    app = create_app(_settings(tmp_path / "data", api_token="s3cret"))
    with TestClient(app) as c:
        assert c.get("/v1/").status_code == 200
        assert c.get("/v1/conformance").status_code == 200
        assert c.get("/", headers={"Accept": "application/json"}).status_code == 200
        assert c.get("/v1/processes").status_code == 401


# -- processes --------------------------------------------------------------------------------
def test_process_list_has_links_and_summaries(client):
    doc = client.get("/v1/processes").json()
    assert _rels(doc)["self"]["type"] == "application/json"
    assert [p["id"] for p in doc["processes"]] == list(PROCESSES)
    for p in doc["processes"]:
        assert p["version"] and p["jobControlOptions"] == ["async-execute", "dismiss"]
        rels = _rels(p)
        assert rels["self"]["href"].endswith(f"/v1/processes/{p['id']}")
        assert rels[OGC_REL + "execute"]["href"].endswith(f"/v1/processes/{p['id']}/execution")
        assert all(link["type"] for link in p["links"])
    two = client.get("/v1/processes?limit=2").json()
    assert [p["id"] for p in two["processes"]] == list(PROCESSES)[:2]
    nxt = client.get(_rels(two)["next"]["href"]).json()
    assert [p["id"] for p in nxt["processes"]] == list(PROCESSES)[2:4]


@pytest.mark.parametrize("pid", list(PROCESSES))
def test_every_input_has_a_schema_and_every_setting_is_an_input(client, pid):
    d = client.get(f"/v1/processes/{pid}").json()
    process = PROCESSES[pid]
    files = {i.name for i in process.inputs}
    settings = set(d["parameters"]["properties"])  # the parameters object, as before
    assert set(d["inputs"]) == files | settings
    for name, spec in d["inputs"].items():
        assert {"title", "description", "schema", "minOccurs", "maxOccurs"} <= set(spec), name
        assert spec["maxOccurs"] == 1
    for name in files:
        alts = d["inputs"][name]["schema"]["anyOf"]
        assert any("contentMediaType" in s for s in alts), name
    for name in settings:
        assert d["inputs"][name]["minOccurs"] == 0
    # outputs by id, each with the media type of its file
    ids = process.output_ids()
    assert set(d["outputs"]) == set(ids)
    for oid, out in d["outputs"].items():
        assert "." not in oid and "/" not in oid, oid
        assert out["title"] == ids[oid]
        assert out["schema"]["contentMediaType"]


def test_run_describes_preset_as_an_input(client):
    d = client.get("/v1/processes/run").json()
    preset = d["inputs"]["preset"]["schema"]
    assert preset["type"] == "string" and set(preset["enum"]) == {"draft", "standard", "fine"}
    assert preset["default"] == "standard"
    assert d["outputs"]["report"]["schema"]["contentMediaType"] == "text/html"
    assert d["outputs"]["scan"]["schema"]["contentMediaType"] == "application/vnd.laszip"
    assert d["outputs"]["vs_mesh_comparison"]["title"] == "vs_mesh/comparison.json"
    # the range of a setting in OpenAPI 3.0's words: a boolean exclusiveMinimum by its bound
    scanner = d["inputs"]["scan"]["schema"]["properties"]["scanner"]["properties"]
    max_range = scanner["max_range_m"]
    assert max_range["exclusiveMinimum"] is True and max_range["minimum"] == 0
    assert "[m]" in max_range["description"]


def test_file_inputs_name_the_kinds_they_take(client):
    """Two text/csv inputs take different files (a QSM table, a stations table): the
    description names the kind in treesim's extension, which a client (the jobs page)
    reads to offer only fitting uploads."""
    run = client.get("/v1/processes/run").json()["inputs"]
    scan = client.get("/v1/processes/plot-scan").json()["inputs"]
    assert run["reference_qsm"]["x-treesim-kinds"] == ["cylinders"]
    assert run["cloud"]["x-treesim-kinds"] == ["cloud"]
    assert scan["stations"]["x-treesim-kinds"] == ["table"]
    assert scan["plot"]["x-treesim-kinds"] == ["plot"]


def test_unknown_process_is_ogcs_no_such_process(client):
    _ogc_problem(client.get("/v1/processes/nope"), 404, "no-such-process")
    _ogc_problem(client.post("/v1/processes/nope/execution", json={}), 404, "no-such-process")


# -- execution --------------------------------------------------------------------------------
def _execute(client, pid: str, body: dict, **headers):
    return client.post(f"/v1/processes/{pid}/execution", json=body, headers=headers)


def test_standard_execute_with_href_and_a_setting_as_input(client, upload):
    body = {
        "inputs": {"cloud": {"href": upload["links"][0]["href"]}, "preset": {"value": "draft"}},
        "outputs": {"tree": {"transmissionMode": "reference"}},
        "response": "document",
    }
    r = _execute(client, "run", body, Prefer="respond-async")
    assert r.status_code == 201, r.text
    job = r.json()
    assert r.headers["preference-applied"] == "respond-async"
    assert r.headers["location"] == f"http://testserver/v1/jobs/{job['jobID']}"
    assert job["type"] == "process" and job["status"] == "accepted"
    assert job["processID"] == "run"
    assert job["parameters"] == {"preset": "draft"}
    assert job["inputs"]["cloud"]["upload"] == upload["id"]
    assert None not in job.values() and "started" not in job  # no nulls: left out
    assert client.get(r.headers["location"]).json()["jobID"] == job["jobID"]
    client.delete(r.headers["location"])


def test_plain_values_relative_hrefs_and_the_treesim_forms(client, upload):
    for cloud in (upload["id"], {"href": f"/v1/uploads/{upload['id']}"}):
        r = _execute(client, "reconstruct", {"inputs": {"cloud": cloud, "preset": "draft"}})
        assert r.status_code == 201, r.text
        assert "preference-applied" not in r.headers  # nothing asked, nothing applied
        assert r.json()["parameters"] == {"preset": "draft"}
        client.delete(r.headers["location"])
    # treesim's way still works, with its parameters object
    r = client.post(
        "/v1/jobs",
        json={
            "process": "run",
            "inputs": {"cloud": upload["id"]},
            "parameters": {"preset": "draft"},
        },
    )
    assert r.status_code == 201, r.text
    client.delete(r.headers["location"])


@pytest.mark.parametrize(
    "inputs, status, field",
    [
        ({"cloud": {"href": "http://example.org/tree.laz"}}, 400, "inputs.cloud"),
        ({"cloud": {"href": "https://testserver/v1/uploads/x"}}, 400, "inputs.cloud"),  # scheme
        ({"cloud": {"href": "ftp://testserver/tree.laz"}}, 400, "inputs.cloud"),
        ({"cloud": {"href": "/v1/processes/run"}}, 400, "inputs.cloud"),
        ({"cloud": {"value": "0 0 0\n"}}, 422, "inputs.cloud"),
        ({"cloud": [{"href": "/v1/uploads/x"}]}, 422, "inputs.cloud"),
        ({"cloud": {"href": "/v1/uploads/no-such-upload"}}, 404, "inputs.cloud"),
        ({"cloud": {"href": "/v1/jobs/no-such-job/results/tree.ply"}}, 404, "inputs.cloud"),
        ({"preset": {"href": "/v1/uploads/x"}}, 422, "inputs.preset"),
        ({"preset": "ultra"}, 422, "parameters.preset"),
        ({"no_such_input": 1}, 422, "inputs.no_such_input"),
    ],
)
def test_bad_inputs_are_problems_naming_the_input(client, upload, inputs, status, field):
    before = len(client.get("/v1/jobs?limit=1000").json()["jobs"])
    body = {"inputs": {"cloud": upload["id"], **inputs}}
    r = _execute(client, "run", body)
    assert r.status_code == status, r.text
    assert r.json()["field"] == field, r.json()
    assert len(client.get("/v1/jobs?limit=1000").json()["jobs"]) == before


def test_remote_hrefs_are_refused_with_the_setting_named(client):
    r = _execute(client, "run", {"inputs": {"cloud": {"href": "http://example.org/tree.laz"}}})
    body = r.json()
    assert body["type"] == "/problems#remote-input-refused"
    assert "TREESIM_ALLOW_REMOTE_HREFS" in body["detail"]


def test_a_setting_given_twice_and_bad_outputs(client, upload):
    r = _execute(
        client,
        "run",
        {"inputs": {"cloud": upload["id"], "preset": "draft"}, "parameters": {"preset": "fine"}},
    )
    assert r.status_code == 422 and r.json()["field"] == "inputs.preset", r.text
    for outputs, field in (
        ({"tree.ply": {}}, "outputs.tree.ply"),  # by id, not by file name
        ({"tree": {"transmissionMode": "value"}}, "outputs.tree"),
        ({"tree": {"format": {"mediaType": "text/csv"}}}, "outputs.tree"),
    ):
        r = _execute(client, "run", {"inputs": {"cloud": upload["id"]}, "outputs": outputs})
        assert r.status_code == 422 and r.json()["field"] == field, r.text
    r = _execute(client, "run", {"inputs": {"cloud": upload["id"]}, "response": "raw"})
    assert r.status_code == 201, r.text
    client.delete(r.headers["location"])


def test_an_input_that_is_a_file_or_a_value(client):
    """plot-scan's stations: a stations CSV by reference, or positions by value."""
    body = {"inputs": {"stand": {}, "stations": {"value": [[0, 0], [3.5, 0]]}}}
    r = _execute(client, "plot-scan", body)
    assert r.status_code == 201, r.text
    assert r.json()["parameters"]["stations"] == [[0, 0], [3.5, 0]]
    assert r.json()["inputs"] == {}
    client.delete(r.headers["location"])
    r = _execute(
        client, "plot-scan", {"inputs": {"stand": {}, "stations": {"href": "/v1/uploads/x"}}}
    )
    assert r.status_code == 404 and r.json()["field"] == "inputs.stations", r.text


def test_remote_hrefs_are_fetched_where_the_setting_allows(tmp_path):
    """With TREESIM_ALLOW_REMOTE_HREFS an href on another origin (here a file server on
    this machine's loopback, never the network, so TREESIM_REMOTE_HREF_HOSTS lists it:
    test_hrefs.py has the refusals) is downloaded and kept as an upload."""
    import functools
    import http.server
    import threading

    served = tmp_path / "served"
    served.mkdir()
    (served / "tree.xyz").write_bytes(BUNDLED_CLOUD.read_bytes())
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(served))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{httpd.server_address[1]}"
    try:
        settings = _settings(
            tmp_path / "data", allow_remote_hrefs=True, remote_href_hosts=["127.0.0.1"]
        )
        app = create_app(settings)
        with TestClient(app) as c:
            r = _execute(c, "reconstruct", {"inputs": {"cloud": {"href": f"{url}/tree.xyz"}}})
            assert r.status_code == 201, r.text
            ups = c.get("/v1/uploads").json()["uploads"]
            assert [u["filename"] for u in ups] == ["tree.xyz"]
            n_lines = sum(1 for line in BUNDLED_CLOUD.read_text().splitlines() if line.strip())
            assert ups[0]["n_points"] == n_lines
            assert r.json()["inputs"]["cloud"]["upload"] == ups[0]["id"]
            r = _execute(c, "reconstruct", {"inputs": {"cloud": {"href": f"{url}/missing.xyz"}}})
            assert r.status_code == 400 and "404" in r.json()["detail"], r.text
    finally:
        httpd.shutdown()


# -- status, results, exceptions --------------------------------------------------------------
def test_unknown_job_and_results_not_ready(client, upload):
    for path in ("/v1/jobs/nope", "/v1/jobs/nope/results", "/v1/jobs/nope/results/tree.ply"):
        _ogc_problem(client.get(path), 404, "no-such-job")
    _ogc_problem(client.delete("/v1/jobs/nope"), 404, "no-such-job")
    r = _execute(client, "reconstruct", {"inputs": {"cloud": upload["id"]}})
    url = r.headers["location"]
    body = _ogc_problem(client.get(url + "/results"), 404, "result-not-ready")
    assert "accepted" in body["detail"]
    status = client.get(url).json()
    assert status["status"] == "accepted" and status["progress"] == 0
    assert OGC_REL + "results" not in _rels(status)
    client.delete(url)


@pytest.fixture
def finished(tmp_path):
    """An app whose one job has been claimed and succeeded as a worker would record it,
    with its files written: (client, job id, data folder)."""
    data_dir = tmp_path / "data"
    app = create_app(_settings(data_dir))
    with TestClient(app) as c:
        up = c.post("/v1/uploads?filename=cloud.txt", content=BUNDLED_CLOUD.read_bytes()).json()
        job = c.post("/v1/processes/reconstruct/execution", json={"inputs": {"cloud": up["id"]}})
        store = app.state.store
        claim = store.claim("test-worker", 30)
        assert claim.id == job.json()["jobID"]
        ply = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        ply += b"property float z\nend_header\n0 0 0\n"  # a point, no faces: a cloud
        files = {"tree.ply": ply, "tree.json": b'{"dbh_m": 0.1}', "extra/log.txt": b"x"}
        results = []
        for name, data in files.items():
            p = data_dir / "jobs" / claim.id / "results" / name
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
            media = "application/json" if name.endswith(".json") else "application/octet-stream"
            results.append({"name": name, "size_bytes": len(data), "media_type": media})
        assert store.succeed(claim, results=results, summary={"dbh_m": 0.1, "note": None})
        yield c, claim.id, files


def test_results_document_maps_output_ids_to_links(finished):
    client, job_id, files = finished
    status = client.get(f"/v1/jobs/{job_id}").json()
    assert status["status"] == "successful" and status["progress"] == 100
    assert status["finished"] and status["started"] and status["created"]
    results_link = _rels(status)[OGC_REL + "results"]
    assert results_link["type"] == "application/json"
    doc = client.get(results_link["href"]).json()
    # reconstruct's outputs: tree.ply, cylinders.csv (not written here), tree.json
    assert set(doc) == {"tree_ply", "tree_json"}
    assert doc["tree_json"]["type"] == "application/json"
    for oid, link in doc.items():
        assert client.get(link["href"]).content == files[link["title"]], oid
    only = client.get(f"/v1/jobs/{job_id}/results?outputs=tree_json").json()
    assert set(only) == {"tree_json"}
    assert client.get(f"/v1/jobs/{job_id}/results?outputs=nope").status_code == 422
    # every file, with treesim's listing
    names = {r["name"] for r in client.get(f"/v1/jobs/{job_id}/files").json()["results"]}
    assert names == set(files)


def test_the_requested_outputs_are_kept_and_the_results_document_lists_them(tmp_path):
    """An execute request's ``outputs`` select what its results document lists (OGC API -
    Processes: the requested outputs; all when none is named), after the job ran, with
    ``?outputs=`` still choosing among every output written."""
    data_dir = tmp_path / "data"
    app = create_app(_settings(data_dir))
    with TestClient(app) as c:
        up = c.post("/v1/uploads?filename=cloud.txt", content=BUNDLED_CLOUD.read_bytes()).json()
        asked = {"tree_json": {"transmissionMode": "reference"}}
        picked = _execute(c, "reconstruct", {"inputs": {"cloud": up["id"]}, "outputs": asked})
        every = c.post(  # treesim's way, no outputs named: every output
            "/v1/jobs", json={"process": "reconstruct", "inputs": {"cloud": up["id"]}}
        )
        assert picked.status_code == every.status_code == 201, (picked.text, every.text)
        store = app.state.store
        assert store.job(picked.json()["jobID"])["outputs"] == ["tree_json"]
        assert store.job(every.json()["jobID"])["outputs"] is None
        files = {"tree.ply": b"ply\n", "tree.json": b"{}", "cylinders.csv": b"x\n"}
        for _ in range(2):  # both jobs run, writing the same files
            claim = store.claim("test-worker", 30)
            out = data_dir / "jobs" / claim.id / "results"
            out.mkdir(parents=True)
            results = []
            for name, data in files.items():
                (out / name).write_bytes(data)
                results.append({"name": name, "size_bytes": len(data), "media_type": "x/y"})
            assert store.succeed(claim, results=results, summary={})
        doc = c.get(picked.headers["location"] + "/results").json()
        assert set(doc) == {"tree_json"}
        assert doc["tree_json"]["href"].endswith("/results/tree.json")
        every_doc = c.get(every.headers["location"] + "/results").json()
        assert set(every_doc) == {"tree_ply", "tree_json", "cylinders"}
        chosen = c.get(picked.headers["location"] + "/results?outputs=cylinders").json()
        assert set(chosen) == {"cylinders"}


def test_a_result_by_href_or_output_id_is_an_input(finished):
    client, job_id, _ = finished
    href = client.get(f"/v1/jobs/{job_id}/results").json()["tree_ply"]["href"]
    for mesh in ({"href": href}, {"job": job_id, "result": "tree_ply"}):
        r = client.post("/v1/processes/scan/execution", json={"inputs": {"mesh": mesh}})
        # this tree.ply is a cloud, not a mesh: its kind decides, and the error names the input
        assert r.status_code == 422 and r.json()["field"] == "inputs.mesh", r.text
        assert "mesh" in r.json()["detail"]


def test_a_failed_jobs_results_are_its_own_problem(tmp_path):
    app = create_app(_settings(tmp_path / "data"))
    with TestClient(app) as c:
        up = c.post("/v1/uploads?filename=cloud.txt", content=BUNDLED_CLOUD.read_bytes()).json()
        c.post("/v1/processes/reconstruct/execution", json={"inputs": {"cloud": up["id"]}})
        claim = app.state.store.claim("w", 30)
        problem = {
            "type": "/problems#reconstruction-failed",
            "title": "Reconstruction failed",
            "status": 422,
            "detail": "no stem found",
        }
        app.state.store.fail(claim, problem, retry=False)
        r = c.get(f"/v1/jobs/{claim.id}/results")
        assert r.status_code == 422
        assert r.json()["type"] == "/problems#reconstruction-failed"
        assert "no stem found" in r.json()["detail"]
