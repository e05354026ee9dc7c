"""A bounded schemathesis run over the whole OpenAPI schema, in-process (ASGI): generated
requests, valid and invalid, against every operation. No response is a 5xx, and every
response conforms to the schema (status code, content type, headers, body)."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import (
    content_type_conformance,
    not_a_server_error,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from service.app import create_app
from service.settings import Settings

from .conftest import BUNDLED_CLOUD

pytestmark = pytest.mark.slow

CHECKS = (
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
)


@pytest.fixture(scope="module")
def api_schema(tmp_path_factory):
    """The app, with one real upload and one accepted job so that generated ids can meet
    real records, and no worker (the jobs stay accepted)."""
    from fastapi.testclient import TestClient

    data_dir = tmp_path_factory.mktemp("schemathesis") / "data"
    app = create_app(
        Settings(
            data_dir=data_dir,
            workers=0,
            api_token=None,
            database_url=None,
            max_upload_bytes=5_000_000,
        )
    )
    with TestClient(app) as client:
        up = client.post("/v1/uploads?filename=cloud.txt", content=BUNDLED_CLOUD.read_bytes())
        assert up.status_code == 201, up.text
        job = client.post("/v1/jobs", json={"process": "run", "inputs": {"cloud": up.json()["id"]}})
        assert job.status_code == 201, job.text
        yield schemathesis.openapi.from_asgi("/openapi.json", app)


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
@settings(
    max_examples=25,
    deadline=None,
    derandomize=True,
    suppress_health_check=list(HealthCheck),
)
def test_no_server_error_and_every_response_fits_the_schema(case):
    case.call_and_validate(checks=CHECKS)
