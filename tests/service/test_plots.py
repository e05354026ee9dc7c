"""Plots in the service: the ``plot`` upload (a zip archive, checked and unpacked safely),
the ``plan`` and ``plot-scan`` processes (their parameters from the parameter models, the
choice of plot source), and small real jobs on an embedded worker: a plan of a 3-sapling
plot whose stations.csv then feeds a plot scan, a plot scan of a generated stand, and a plan
whose budget cannot buy one station, which fails the job with treesim's message."""

from __future__ import annotations

import csv
import io
import json
import stat
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from treesim.plot import Plot, PlotTree
from treesim.plot.io import write_plot
from treesim.service.app import create_app
from treesim.service.settings import Settings

from .conftest import wait_job

PROBLEM = "application/problem+json"
LIMIT = 2_000_000


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("plots") / "data"


@pytest.fixture(scope="module")
def client(data_dir):
    """The app with one embedded worker slot (jobs run in spawned processes)."""
    settings = Settings(
        data_dir=data_dir,
        workers=1,
        job_threads=1,
        api_token=None,
        database_url=None,
        poll_interval_s=0.2,
        max_upload_bytes=LIMIT,
    )
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture(scope="module")
def plot_dir(tmp_path_factory) -> Path:
    """Three saplings in a 5 m plot, as treesim plot generate would leave them."""
    d = tmp_path_factory.mktemp("plot") / "myplot"
    d.mkdir()
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i)
        for i, (x, y) in enumerate([(2.0, 0.0), (-2.0, 1.0), (0.0, -2.5)])
    ]
    write_plot(d / "plot.toml", Plot(trees, radius_m=5.0, facets=8))
    return d


def _zip(entries: dict[str, bytes | str], **links: str) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in entries.items():  # a fixed date: the same entries, the same bytes
            z.writestr(zipfile.ZipInfo(name, (2026, 1, 1, 0, 0, 0)), data, zipfile.ZIP_DEFLATED)
        for name, target in links.items():
            info = zipfile.ZipInfo(name)
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
            z.writestr(info, target)
    return buf.getvalue()


def _plot_zip(plot_dir: Path, folder: str = "myplot/") -> bytes:
    return _zip({f"{folder}{p.name}": p.read_bytes() for p in sorted(plot_dir.iterdir())})


@pytest.fixture(scope="module")
def plot_id(client, plot_dir) -> str:
    r = client.post("/v1/uploads?filename=plot.zip", content=_plot_zip(plot_dir))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _problem(r, status: int, field: str | None = None, contains: str | None = None) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    if field is not None:
        assert body.get("field") == field, body
    if contains is not None:
        assert contains.lower() in body["detail"].lower(), body["detail"]
    assert "Traceback" not in body["detail"]
    return body


def _job(client, process: str, inputs: dict, parameters: dict) -> str:
    r = client.post(
        "/v1/jobs", json={"process": process, "inputs": inputs, "parameters": parameters}
    )
    assert r.status_code == 201, r.text
    return r.json()["jobID"]


# -- the plot upload --------------------------------------------------------------------------
def test_a_plot_archive_uploads_as_a_plot(client, plot_dir, plot_id):
    up = client.get(f"/v1/uploads/{plot_id}").json()
    assert (up["kind"], up["format"], up["n_trees"]) == ("plot", "zip", 3)
    assert up["bounds"] == {"min": [-5.0, -5.0, 0.0], "max": [5.0, 5.0, 0.0]}
    # the same bytes again: stored once; plot.toml at the root is as good as in a folder
    again = client.post("/v1/uploads?filename=again.zip", content=_plot_zip(plot_dir))
    assert again.status_code == 200 and again.json()["id"] == plot_id
    root = client.post("/v1/uploads?filename=root.zip", content=_plot_zip(plot_dir, ""))
    assert root.status_code == 201 and root.json()["n_trees"] == 3
    kinds = client.get("/openapi.json").json()["components"]["schemas"]["UploadOut"]
    assert "plot" in kinds["properties"]["kind"]["enum"]


_TOML = 'radius_m = 5.0\ntrees = "trees.csv"\n'
_CSV = "tree_id,x_m,y_m,species\n1,1.0,0.0,sapling\n"


@pytest.mark.parametrize(
    "body, contains",
    [
        (_zip({"../plot.toml": _TOML, "trees.csv": _CSV}), "'..' is refused"),
        (_zip({"/abs/plot.toml": _TOML}), "absolute paths are refused"),
        (_zip({"plot.toml": _TOML, "trees.csv": _CSV}, **{"x.ply": "/etc/hostname"}), "links"),
        (_zip({"trees.csv": _CSV}), "no plot.toml"),
        (_zip({"a/plot.toml": _TOML, "b/plot.toml": _TOML}), "more than one plot file"),
        (_zip({"plot.toml": 'trees = "../../../etc/passwd"\n'}), "outside the archive"),
        (_zip({"plot.toml": _TOML}), "not in the archive"),
        (
            _zip(
                {
                    "plot.toml": _TOML,
                    "trees.csv": "tree_id,x_m,y_m,source,path\n1,0,0,mesh,/etc/hostname\n",
                }
            ),
            "absolute path",
        ),
        (
            _zip(
                {"plot.toml": _TOML, "trees.csv": "tree_id,x_m,y_m,source,path\n1,0,0,mesh,t.ply\n"}
            ),
            "not in the archive",
        ),
        (_zip({"plot.toml": "radius_m = [", "trees.csv": _CSV}), "not a valid toml"),
        (_zip({"plot.toml": _TOML, "trees.csv": "tree_id,x_m\n1,2\n"}), "lacks the column(s) y_m"),
        (b"PK\x03\x04" + b"\x00" * 200, "not a readable zip"),
    ],
)
def test_a_bad_plot_archive_is_refused_and_nothing_kept(client, data_dir, body, contains):
    before = sorted(p for p in (data_dir / "uploads").rglob("*") if p.is_file())
    body_ = _problem(client.post("/v1/uploads?filename=p.zip", content=body), 422)
    assert contains.lower() in body_["detail"].lower(), body_["detail"]
    assert body_["detail"].startswith("p.zip")
    assert "/tmp" not in body_["detail"]  # never the folder it was unpacked into
    assert sorted(p for p in (data_dir / "uploads").rglob("*") if p.is_file()) == before


def test_a_plot_archive_that_unpacks_too_big_is_refused(client):
    big = _zip({"plot.toml": _TOML, "trees.csv": _CSV, "zeros.bin": b"\0" * (4 * LIMIT + 1)})
    assert len(big) < LIMIT
    _problem(client.post("/v1/uploads?filename=z.zip", content=big), 422, contains="unpacks to")


def test_the_service_starts_without_the_plot_and_plan_modules():
    """Plots are read in the upload's inspector and in jobs, never in the API's start-up."""
    root = Path(__file__).resolve().parents[2]
    heavy = ("treesim.plot", "treesim.plan", "open3d")
    code = (
        "import sys\nimport treesim.service.app\n"
        f"print(','.join(m for m in {heavy!r} if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "", f"imported at start-up: {out.stdout.strip()}"


# -- the processes and their parameters -------------------------------------------------------
def _files(description: dict) -> dict[str, dict]:
    """A process description's file inputs (those with a media type; the others are its
    settings, each an input too)."""
    return {
        k: v
        for k, v in description["inputs"].items()
        if any("contentMediaType" in s for s in v["schema"].get("anyOf", []))
    }


def _output_files(description: dict) -> set[str]:
    """The file names of a description's outputs (each output's title; its id is the
    name less the suffix)."""
    return {o["title"] for o in description["outputs"].values()}


def test_plan_and_plot_scan_are_described_with_ranges(client):
    ids = [p["id"] for p in client.get("/v1/processes").json()["processes"]]
    assert ids[4:6] == ["plan", "plot-scan"]
    plan = client.get("/v1/processes/plan").json()
    props = plan["parameters"]["properties"]
    assert props["goal_coverage"]["maximum"] == 1 and props["tolerance_m"]["exclusiveMinimum"] == 0
    assert props["max_stations"]["default"] == 20 and "threads" not in props
    assert props["instrument"]["default"] == "riegl-vz400"
    assert props["stand"]["properties"]["stems_per_ha"]["exclusiveMinimum"] == 0
    assert "sapling" in props["tree"]["properties"]["species"]["enum"]
    assert {k: v["minOccurs"] for k, v in _files(plan).items()} == {"plot": 0, "mesh": 0}
    assert {"plan.json", "stations.csv", "map.png", "curve.png"} <= _output_files(plan)
    scan = client.get("/v1/processes/plot-scan").json()
    sp = scan["parameters"]["properties"]
    assert {"stations", "tolerance_m", "figures", "instrument", "scanner", "sectors"} <= set(sp)
    assert sp["sectors"]["minimum"] == 1 and sp["sectors"]["default"] == 1
    assert "min_distance_m" not in sp and "max_rays" not in sp
    assert set(_files(scan)) == {"plot", "mesh", "stations"}
    assert {"plot_scan.laz", "plot_scan.json", "tree_figures.csv"} <= _output_files(scan)


@pytest.mark.parametrize(
    "process, inputs, parameters, field, contains",
    [
        ("plan", "plot", {"goal_coverage": 1.5}, "parameters", "goal_coverage"),
        ("plan", "plot", {"goal_coverage": 0}, "parameters", "needs a goal"),
        ("plan", "plot", {"resolution_deg": -1}, None, "resolution"),
        ("plan", "plot", {"instrument": "lidar-9000"}, "parameters.instrument", None),
        ("plan", "plot", {"samples_per_tree": 10}, "parameters", "samples_per_tree"),
        ("plan", "plot", {"nope": 1}, "parameters.nope", "unknown"),
        ("plan", "plot", {"radius_m": 3}, "parameters.radius_m", "one tree"),
        ("plan", "plot", {"tree": {"species": "sapling"}}, "parameters.tree", "give one of"),
        ("plan", None, {}, "inputs.plot", "give one of"),
        ("plan", None, {"tree": {"species": "oak"}}, "parameters.tree.species", None),
        ("plan", None, {"tree": {"species": "sapling"}, "radius_m": -2}, None, "radius_m"),
        ("plan", None, {"stand": {"stems_per_ha": 0}}, "parameters.stand", "stems_per_ha"),
        ("plan", None, {"stand": {"species": "oak:1"}}, "parameters.stand", "unknown species"),
        ("plan", None, {"stand": {"radius_m": 500}}, "parameters.stand", "radius_m"),
        ("plan", None, {"stand": {"stems_per_ha": 20000, "radius_m": 30}}, None, "5,000"),
        ("plot-scan", "plot", {"n_stations": 0}, "parameters", "n_stations"),
        ("plot-scan", "plot", {"stations": [[1.0]]}, "parameters.stations.0", None),
        ("plot-scan", "plot", {"tolerance_m": -1}, "parameters", "tolerance_m"),
        ("plot-scan", "plot", {"scanner": {"max_range_m": -5}}, "parameters.scanner", None),
        ("plot-scan", None, {"figures": True}, "inputs.plot", "give one of"),
        ("plot-scan", "plot", {"sectors": 0}, "parameters.sectors", ">= 1"),
        (
            "plot-scan",
            "plot",
            {"sectors": 2, "scanner": {"beam_divergence_mrad": 0.3, "subrays": 7}},
            "parameters.sectors",
            "neighbouring pulses",
        ),
    ],
)
def test_bad_plan_and_plot_scan_requests_are_422(
    client, plot_id, process, inputs, parameters, field, contains
):
    n = len(client.get("/v1/jobs?limit=1000").json()["jobs"])
    given = {"plot": plot_id} if inputs == "plot" else {}
    r = client.post(
        "/v1/jobs", json={"process": process, "inputs": given, "parameters": parameters}
    )
    _problem(r, 422, field=field, contains=contains)
    assert len(client.get("/v1/jobs?limit=1000").json()["jobs"]) == n


def test_a_plot_input_must_be_a_plot(client, plot_id):
    r = client.post(
        "/v1/jobs", json={"process": "scan", "inputs": {"mesh": plot_id}, "parameters": {}}
    )
    _problem(r, 422, field="inputs.mesh", contains="got a plot")
    r = client.post(
        "/v1/jobs",
        json={"process": "plot-scan", "inputs": {"plot": plot_id, "stations": plot_id}},
    )
    _problem(r, 422, field="inputs.stations", contains="table")


# -- real jobs --------------------------------------------------------------------------------
_PLAN = {
    "resolution_deg": 0.5,
    "tolerance_m": 0.05,
    "samples_per_tree": 300,
    "candidate_spacing_m": 1.5,
    "verify": False,
}


def _results(client, job_id: str) -> dict[str, dict]:
    listing = client.get(f"/v1/jobs/{job_id}/files").json()["results"]
    return {r["name"]: r for r in listing}


def _csv(client, result: dict) -> list[dict[str, str]]:
    r = client.get(result["href"])
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    return list(csv.DictReader(io.StringIO(r.text)))


def test_plan_then_plot_scan_of_its_stations(client, plot_id):
    job = wait_job(client, _job(client, "plan", {"plot": plot_id}, _PLAN), timeout_s=120)
    assert job["status"] == "successful", job
    assert job["progress"] == 100
    results = _results(client, job["jobID"])
    assert set(results) == {"plan.json", "stations.csv", "map.png", "curve.png"}
    plan = client.get(results["plan.json"]["href"]).json()
    stations = plan["plan"]["stations"]
    assert plan["plan"]["n_stations"] == len(stations) >= 1
    assert plan["instrument"]["name"] == "riegl-vz400"
    assert job["summary"]["n_stations"] == len(stations)
    assert job["summary"]["stations"] == stations
    rows = _csv(client, results["stations.csv"])
    assert len(rows) == len(stations) and {"x_m", "y_m", "z_m"} <= set(rows[0])
    png = client.get(results["map.png"]["href"])
    assert png.headers["content-type"] == "image/png" and png.content[:4] == b"\x89PNG"

    # the plan's stations.csv scans the same plot
    scan = wait_job(
        client,
        _job(
            client,
            "plot-scan",
            {"plot": plot_id, "stations": {"job": job["jobID"], "result": "stations.csv"}},
            {"resolution_deg": 0.5, "sectors": 2},
        ),
        timeout_s=120,
    )
    assert scan["status"] == "successful", scan
    results = _results(client, scan["jobID"])
    assert set(results) == {"plot_scan.laz", "plot_scan.json", "tree_figures.csv"}
    figures = list(
        csv.DictReader(io.StringIO(client.get(results["tree_figures.csv"]["href"]).text))
    )
    assert sorted(int(r["tree_id"]) for r in figures) == [1, 2, 3]
    assert all(int(r["points"]) > 0 for r in figures)
    summary = json.loads(client.get(results["plot_scan.json"]["href"]).content)
    assert len(summary["stations"]) == len(stations)
    # each station in two sectors (the parameter reached the scan)
    assert all(len(s["sector_triangles_loaded"]) == 2 for s in summary["stations"])
    assert scan["summary"]["trees_measured"] == 3 and scan["summary"]["points"] > 0
    laz = client.get(results["plot_scan.laz"]["href"]).content
    assert laz[:4] == b"LASF" and len(laz) == results["plot_scan.laz"]["size_bytes"]


def test_plot_scan_of_a_generated_stand(client):
    stand = {"species": "sapling", "stems_per_ha": 600, "radius_m": 4, "seed": 1, "facets": 8}
    params = {"stand": stand, "resolution_deg": 0.5, "n_stations": 2}
    job = wait_job(client, _job(client, "plot-scan", {}, params), timeout_s=120)
    assert job["status"] == "successful", job
    results = _results(client, job["jobID"])
    assert {"plot_scan.laz", "tree_figures.csv", "stand/plot.toml", "stand/trees.csv"} <= set(
        results
    )
    trees = _csv(client, results["stand/trees.csv"])
    figures = list(
        csv.DictReader(io.StringIO(client.get(results["tree_figures.csv"]["href"]).text))
    )
    assert len(trees) == 3  # 600 stems/ha on 0.005 ha
    assert [r["tree_id"] for r in figures] == [r["tree_id"] for r in trees]
    assert job["summary"]["inputs"]["stand"]["trees"] == 3


def test_a_plan_over_its_budget_fails_the_job_with_the_reason(client):
    params = {"tree": {"species": "sapling", "facets": 8}, "max_field_time_min": 1, **_PLAN}
    job = wait_job(client, _job(client, "plan", {}, params), timeout_s=120)
    assert job["status"] == "failed", job
    assert job["attempt"] == 1  # treesim's refusal is not retried
    err = job["error"]
    assert err["type"] == "/problems#invalid-parameter" and err["status"] == 422
    assert "less than one station" in err["detail"] and "Traceback" not in err["detail"]
    # OGC: a failed job's results answer its own problem
    _problem(client.get(f"/v1/jobs/{job['jobID']}/results"), 422, contains="failed")


def test_plot_from_cloud_and_validate_are_described_with_ranges(client):
    twin = client.get("/v1/processes/plot-from-cloud").json()
    props = twin["parameters"]["properties"]
    assert props["units"]["enum"] == ["auto", "m", "ft", "us-ft"]
    assert props["dtm_cell_m"]["exclusiveMinimum"] == 0 and props["dtm_cell_m"]["maximum"] == 10
    assert "twin.zip" in _output_files(twin)
    val = client.get("/v1/processes/validate").json()
    assert set(_files(val)) == {"real", "simulated", "plot"}
    assert val["inputs"]["plot"]["minOccurs"] == 0
    assert val["parameters"]["properties"]["tau_m"]["exclusiveMinimum"] == 0


@pytest.mark.parametrize(
    ("process", "params", "field"),
    [
        ("plot-from-cloud", {"units": "yards"}, "parameters"),
        ("plot-from-cloud", {"dtm_cell_m": 0}, "parameters"),
        ("plot-from-cloud", {"min_tree_points": 5}, "parameters"),
        ("validate", {"tau_m": -1}, "parameters"),
        ("validate", {"tau_m": 1e308}, "parameters"),
        ("validate", {"bins": 3}, "parameters.bins"),
    ],
)
def test_plot_from_cloud_and_validate_refuse_bad_parameters(client, process, params, field):
    """Bad parameters are a 422 naming the field, before any job runs."""
    r = client.post("/v1/jobs", json={"process": process, "inputs": {}, "parameters": params})
    assert r.status_code == 422, r.text
    assert r.json()["field"].startswith(field), r.json()
