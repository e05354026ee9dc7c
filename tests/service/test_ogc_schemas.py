"""The service's OGC API - Processes documents against the standard's own schemas (Part 1:
Core 1.0, vendored in ``ogc_schemas/`` with their provenance): the landing page,
conformance, process list, every process description, a status document, the job list,
a results document and an exception."""

from __future__ import annotations

from pathlib import Path

import jsonschema
import pytest
import yaml
from fastapi.testclient import TestClient
from referencing import Registry, Resource
from referencing.jsonschema import DRAFT4

from treesim.service.app import create_app
from treesim.service.processes import PROCESSES
from treesim.service.settings import Settings

from .conftest import BUNDLED_CLOUD

SCHEMAS = Path(__file__).parent / "ogc_schemas"
BASE = "https://ogc-schemas.invalid/processes-core-1.0/"


def _registry() -> Registry:
    """Every vendored file as a resource under one base URI, so that the files' relative
    ``$ref``s (``link.yaml``) resolve among them (OpenAPI 3.0 schemas: draft 4)."""
    resources = []
    for path in sorted(SCHEMAS.glob("*.yaml")):
        contents = yaml.safe_load(path.read_text(encoding="utf-8"))
        resources.append((BASE + path.name, Resource(contents, DRAFT4)))
    return Registry().with_resources(resources)


REGISTRY = _registry()


def check(doc: object, schema: str) -> None:
    """Validate ``doc`` against the standard's ``schema`` (file stem); every error listed."""
    validator = jsonschema.Draft4Validator({"$ref": BASE + schema + ".yaml"}, registry=REGISTRY)
    errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.absolute_path))
    msgs = [f"{'/'.join(map(str, e.absolute_path))}: {e.message[:300]}" for e in errors]
    assert not msgs, f"{schema}:\n" + "\n".join(msgs[:20])


def test_the_vendored_schemas_catch_what_they_should():
    """The oracle can fail: documents that break the standard are refused."""
    with pytest.raises(AssertionError, match="jobID"):
        check({"status": "accepted", "type": "process"}, "statusInfo")
    with pytest.raises(AssertionError, match="sleeping"):
        check({"jobID": "x", "status": "sleeping", "type": "process"}, "statusInfo")
    with pytest.raises(AssertionError):
        check({"links": [{"href": "x", "type": None}]}, "landingPage")  # a null type
    with pytest.raises(AssertionError):  # an input without its schema
        check({"id": "p", "version": "1", "inputs": {"a": {"title": "a"}}}, "process")
    with pytest.raises(AssertionError):  # a JSON Schema 2020-12 null type is not OpenAPI 3.0
        bad = {"schema": {"type": ["number", "null"]}}
        check({"id": "p", "version": "1", "inputs": {"a": bad}}, "process")


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    data_dir = tmp_path_factory.mktemp("ogc_schemas") / "data"
    app = create_app(Settings(data_dir=data_dir, workers=0, api_token=None, database_url=None))
    with TestClient(app) as c:
        c.app_state = app.state
        yield c


def test_landing_page_conformance_and_process_list(client):
    check(client.get("/v1/").json(), "landingPage")
    check(client.get("/", headers={"Accept": "application/json"}).json(), "landingPage")
    check(client.get("/v1/conformance").json(), "confClasses")
    check(client.get("/v1/processes").json(), "processList")


@pytest.mark.parametrize("pid", list(PROCESSES))
def test_every_process_description(client, pid):
    check(client.get(f"/v1/processes/{pid}").json(), "process")


def test_status_job_list_results_and_exceptions(client):
    up = client.post("/v1/uploads?filename=cloud.txt", content=BUNDLED_CLOUD.read_bytes())
    body = {"inputs": {"cloud": {"href": up.json()["links"][0]["href"]}, "preset": "draft"}}
    r = client.post("/v1/processes/run/execution", json=body, headers={"Prefer": "respond-async"})
    assert r.status_code == 201, r.text
    check(r.json(), "statusInfo")
    job_id = r.json()["jobID"]
    check(client.get(f"/v1/jobs/{job_id}").json(), "statusInfo")
    check(client.get("/v1/jobs").json(), "jobList")
    for path in (f"/v1/jobs/{job_id}/results", "/v1/jobs/nope", "/v1/processes/nope"):
        check(client.get(path).json(), "exception")
    # the job, done as a worker records it: its status and results document
    store = client.app_state.store
    claim = store.claim("w", 30)
    assert claim.id == job_id
    results = [
        {"name": "report.html", "size_bytes": 10, "media_type": "text/html"},
        {"name": "scan.laz", "size_bytes": 10, "media_type": "application/vnd.laszip"},
        {"name": "vs_mesh/comparison.json", "size_bytes": 2, "media_type": "application/json"},
    ]
    store.succeed(claim, results=results, summary={"points": 3, "vs_field": None})
    status = client.get(f"/v1/jobs/{job_id}").json()
    check(status, "statusInfo")
    doc = client.get(f"/v1/jobs/{job_id}/results").json()
    assert set(doc) == {"report", "scan", "vs_mesh_comparison"}
    check(doc, "results")
    check(client.delete(f"/v1/jobs/{job_id}").json(), "statusInfo")
