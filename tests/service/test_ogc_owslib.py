"""A real OGC client against the live service: OWSLib's ``Processes`` (``treesim serve`` on
a free port, its embedded worker) reads the landing page, conformance, the process list
and a description, from the server's root and from ``/v1/``; executes ``run`` on an
uploaded cloud with the ``preset`` set as a standard input; the status is polled by its
link until done, and the results fetched by their hrefs.

Oracles: the standard's link relations and class URIs; the draft preset's own parameter
hash (``treesim.params``), which ``run.json`` must carry, and not the default preset's; the
LAZ the results link to read back with laspy."""

from __future__ import annotations

import io
import time

import httpx
import pytest

from treesim.params import DEFAULT_RUN_PRESET, params_hash, run_preset

from .conftest import BUNDLED_CLOUD

pytestmark = pytest.mark.slow

owslib_processes = pytest.importorskip("owslib.ogcapi.processes", reason="needs OWSLib (dev)")

OGC_REL = "http://www.opengis.net/def/rel/ogc/1.0/"
CORE = "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/core"


def _link(doc: dict, rel: str) -> str:
    return next(link["href"] for link in doc["links"] if link["rel"] == rel)


def _poll(status: dict, timeout_s: float = 240) -> dict:
    """Follow the status document's self link until the job ends."""
    url = _link(status, "self")
    t0 = time.monotonic()
    while status["status"] in ("accepted", "running"):
        assert time.monotonic() - t0 < timeout_s, status
        time.sleep(0.3)
        status = httpx.get(url, timeout=30).json()
    return status


def test_owslib_lists_describes_executes_and_fetches(serve, tmp_path):
    import laspy

    Processes = owslib_processes.Processes  # noqa: N806 - OWSLib's class
    base, _ = serve(tmp_path / "data", workers=1)

    for root in (f"{base}/", f"{base}/v1/"):
        api = Processes(root)
        assert _link(api.response, OGC_REL + "processes") == f"{base}/v1/processes"
        assert CORE in api.conformance()["conformsTo"]
        assert api.api()["openapi"] == "3.0.3"  # OWSLib takes the 3.0 service-desc
        assert "run" in [p["id"] for p in api.processes()]
        run = api.process("run")
        assert run["inputs"]["preset"]["schema"]["enum"]
        assert run["inputs"]["cloud"]["minOccurs"] == 1
        assert "report" in run["outputs"]

    # a cloud is uploaded the treesim way (OGC Part 1 has no upload); its href is the input
    up = httpx.post(
        f"{base}/v1/uploads?filename=cloud.txt", content=BUNDLED_CLOUD.read_bytes(), timeout=60
    )
    assert up.status_code == 201, up.text
    href = _link(up.json(), "self")

    api = Processes(f"{base}/v1/")
    status = api.execute(
        "run",
        inputs={"cloud": {"href": href}, "preset": "draft"},
        outputs={o: {"transmissionMode": "reference"} for o in ("report", "run", "tree", "scan")},
        async_=True,
    )
    assert api.response_headers["Preference-Applied"] == "respond-async"
    assert api.response_headers["Location"] == _link(status, "self")
    assert status["type"] == "process" and status["status"] == "accepted"
    done = _poll(status)
    assert done["status"] == "successful", done
    assert done["progress"] == 100

    results = httpx.get(_link(done, OGC_REL + "results"), timeout=30).json()
    assert set(results) == {"report", "run", "tree", "scan"}  # the outputs asked for
    run_json = httpx.get(results["run"]["href"], timeout=30).json()
    assert results["run"]["type"] == "application/json"
    # the preset given as a standard input decided the run
    assert run_json["params_hash"] == params_hash(run_preset("draft"))
    assert run_json["params_hash"] != params_hash(run_preset(DEFAULT_RUN_PRESET))
    scan = httpx.get(results["scan"]["href"], timeout=60)
    assert scan.status_code == 200 and results["scan"]["type"] == "application/vnd.laszip"
    las = laspy.read(io.BytesIO(scan.content))
    assert len(las.points) == run_json["scan"]["points"] > 0
    report = httpx.get(results["report"]["href"], timeout=30)
    assert report.headers["content-type"].startswith("text/html")

    # from the server's root too (308 to /v1, the body kept); without Prefer the job runs
    # asynchronously all the same (every process is async-execute only), nothing applied
    root_api = Processes(f"{base}/")
    other = root_api.execute("reconstruct", inputs={"cloud": {"href": href}}, async_=False)
    assert other["status"] in ("accepted", "running") and other["processID"] == "reconstruct"
    assert "Preference-Applied" not in root_api.response_headers
    gone = httpx.delete(_link(other, "self"), timeout=30).json()
    assert gone["status"] == "dismissed"
