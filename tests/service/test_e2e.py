"""The real service over HTTP: ``treesim serve`` (uvicorn on 127.0.0.1, a free port) in a
temporary data folder, driven as a user's script would drive it.

- the bundled tree through ``run`` with the draft preset: the figures equal ``treesim run``'s;
- kill -9 of the whole service mid-job, then a restart: the job is retried and succeeds, every
  upload and job is still listed, no result folder is half-written;
- twenty concurrent uploads and ten concurrent jobs on two worker processes, on SQLite and
  on Postgres: all complete, none lost, none run twice;
- reconstruct → scan → compare chained over HTTP.
"""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
import pytest

from .conftest import BUNDLED_CLOUD, BUNDLED_QSM, Server, service_env, store_url, wait_job

pytestmark = pytest.mark.slow


def _upload(client: httpx.Client, path: Path) -> dict:
    r = client.post(f"/v1/uploads?filename={path.name}", content=path.read_bytes())
    assert r.status_code in (200, 201), r.text
    return r.json()


def _start_run(client: httpx.Client, upload_id: str, **params) -> str:
    r = client.post(
        "/v1/jobs",
        json={"process": "run", "inputs": {"cloud": upload_id}, "parameters": params},
    )
    assert r.status_code == 201, r.text
    return r.json()["jobID"]


def _read_xyz(path: Path) -> np.ndarray:
    import laspy

    las = laspy.read(path)
    return np.column_stack([las.x, las.y, las.z])


def test_run_over_http_equals_treesim_run(serve, tmp_path):
    base, _ = serve(tmp_path / "data", workers=1)
    with httpx.Client(base_url=base, timeout=30) as c:
        up = _upload(c, BUNDLED_CLOUD)
        # the bundled tree's TreeQSM table, set beside the reconstruction
        qsm = _upload(c, BUNDLED_QSM)
        assert qsm["kind"] == "cylinders" and qsm["n_points"] > 1000
        r = c.post(
            "/v1/jobs",
            json={
                "process": "run",
                "inputs": {"cloud": up["id"], "reference_qsm": qsm["id"]},
                "parameters": {"preset": "draft"},
            },
        )
        assert r.status_code == 201, r.text
        job_id = r.json()["jobID"]
        seen_running = wait_job(c, job_id, until=lambda j: j["status"] != "accepted")
        job = wait_job(c, job_id)
        assert job["status"] == "successful", job
        assert job["progress"] == 100 and job["attempt"] == 1
        assert seen_running["status"] in ("running", "successful")

        results = {r["name"]: r for r in c.get(f"/v1/jobs/{job_id}/files").json()["results"]}
        assert {"report.html", "run.json", "scan.laz", "tree.ply"} <= set(results)
        report = c.get(f"/v1/jobs/{job_id}/report", follow_redirects=True)
        assert report.status_code == 200
        assert report.headers["content-type"].startswith("text/html")
        assert "<html" in report.text.lower()
        laz = c.get(results["scan.laz"]["href"])
        assert laz.status_code == 200 and len(laz.content) == results["scan.laz"]["size_bytes"]
        (tmp_path / "http.laz").write_bytes(laz.content)
        run_json = c.get(results["run.json"]["href"]).json()
        # a range request, as a client resuming a big cloud's download sends
        part = c.get(results["scan.laz"]["href"], headers={"Range": "bytes=100-199"})
        assert part.status_code == 206 and part.content == laz.content[100:200]
        metrics = c.get("/metrics").text
        for stage in ("reconstruct", "scan", "compare_mesh", "report"):
            assert (
                f'treesim_stage_duration_seconds_count{{process="run",stage="{stage}"}} 1.0'
                in metrics
            ), stage

    # the same run by the command line, with the same threads as the service's job
    cli = tmp_path / "cli"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "treesim.cli",
            "run",
            str(BUNDLED_CLOUD),
            "--preset",
            "draft",
            "--reference-qsm",
            str(BUNDLED_QSM),
            "--threads",
            "1",
            "-o",
            str(cli),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    expected = json.loads((cli / "run.json").read_text())
    for key in ("params_hash", "reconstruction", "vs_mesh", "vs_field"):
        assert run_json[key] == expected[key], key
        assert job["summary"][key] == expected[key], key
    assert run_json["scan"]["points"] == expected["scan"]["points"]
    for key in ("figures", "difference", "sha256"):
        assert run_json["reference_qsm"][key] == expected["reference_qsm"][key], key
    np.testing.assert_array_equal(_read_xyz(tmp_path / "http.laz"), _read_xyz(cli / "scan.laz"))


def test_kill_9_mid_job_then_restart_loses_nothing(serve, tmp_path):
    data = tmp_path / "data"
    base, srv = serve(data, workers=1)
    with httpx.Client(base_url=base, timeout=30) as c:
        up = _upload(c, BUNDLED_CLOUD)
        done = _start_run(c, up["id"], preset="draft")
        assert wait_job(c, done)["status"] == "successful"
        victim = _start_run(c, up["id"], preset="draft")
        wait_job(c, victim, until=lambda j: j["status"] == "running" and j["progress"] > 0)
    srv.kill9()
    # what a crash leaves: the victim's attempt folder, never a results folder
    assert not (data / "jobs" / victim / "results").exists()

    base, _ = serve(data, workers=1)
    with httpx.Client(base_url=base, timeout=30) as c:
        job = wait_job(c, victim, timeout_s=300)
        assert job["status"] == "successful", job
        assert job["attempt"] == 2
        uploads = c.get("/v1/uploads").json()["uploads"]
        assert [u["id"] for u in uploads] == [up["id"]]
        listed = {j["jobID"]: j["status"] for j in c.get("/v1/jobs").json()["jobs"]}
        assert listed == {done: "successful", victim: "successful"}
        for job_id in (done, victim):
            jobdir = data / "jobs" / job_id
            assert sorted(p.name for p in jobdir.iterdir()) == ["results"]
            listing = c.get(f"/v1/jobs/{job_id}/files").json()["results"]
            listed_names = {r["name"] for r in listing}
            on_disk = {
                p.relative_to(jobdir / "results").as_posix()
                for p in (jobdir / "results").rglob("*")
                if p.is_file()
            }
            assert on_disk == listed_names
        assert c.get(f"/v1/jobs/{victim}/report", follow_redirects=True).status_code == 200
        assert "treesim_lease_expiries_total 1.0" in c.get("/metrics").text


def _small_tree_mesh(path: Path) -> Path:
    """A trunk and a branch as one triangle mesh: quick to scan."""
    import trimesh

    trunk = trimesh.creation.cylinder(radius=0.15, height=3.0, sections=24)
    trunk.apply_translation([0, 0, 1.5])
    branch = trimesh.creation.cylinder(radius=0.05, height=1.0, sections=12)
    branch.apply_translation([0.4, 0, 2.5])
    trimesh.util.concatenate([trunk, branch]).export(path)
    return path


@pytest.mark.parametrize("backend", ["sqlite", "postgres"])
def test_twenty_uploads_and_ten_jobs_at_once(serve, tmp_path, backend):
    data = tmp_path / "data"
    url = store_url(backend, tmp_path) if backend == "postgres" else ""
    db = {"TREESIM_DATABASE_URL": url} if url else {}
    # the API with one embedded worker slot, and a second worker process on the same store
    base, _ = serve(data, workers=1, **db)
    log = tmp_path / "worker.log"
    other = Server(["worker", "--workers", "1"], service_env(data, **db), log).start()
    try:
        rng = np.random.default_rng(3)
        files = []
        for i in range(20):
            p = tmp_path / f"cloud{i}.xyz"
            np.savetxt(p, rng.normal(size=(2000, 3)) + [0, 0, 2 + i], fmt="%.6f")
            files.append(p)
        mesh = _small_tree_mesh(tmp_path / "tree.ply")
        with httpx.Client(base_url=base, timeout=60) as c:
            with ThreadPoolExecutor(20) as pool:
                ups = list(pool.map(lambda p: _upload(c, p), files))
            assert len({u["id"] for u in ups}) == 20
            assert all(u["n_points"] == 2000 for u in ups)
            assert len(c.get("/v1/uploads?limit=100").json()["uploads"]) == 20
            mesh_id = _upload(c, mesh)["id"]

            def scan_job(i: int) -> str:
                r = c.post(
                    "/v1/jobs",
                    json={
                        "process": "scan",
                        "inputs": {"mesh": mesh_id},
                        "parameters": {"resolution_deg": 0.5, "n_stations": 1 + i % 3},
                    },
                )
                assert r.status_code == 201, r.text
                return r.json()["jobID"]

            with ThreadPoolExecutor(10) as pool:
                ids = list(pool.map(scan_job, range(10)))
            jobs = [wait_job(c, j, timeout_s=300) for j in ids]
            assert [j["status"] for j in jobs] == ["successful"] * 10, jobs
            assert [j["attempt"] for j in jobs] == [1] * 10  # none ran twice
            listed = c.get("/v1/jobs?limit=100").json()["jobs"]
            assert sorted(j["jobID"] for j in listed) == sorted(ids)
            for j in jobs:
                assert j["summary"]["points"] > 0
                assert len(j["summary"]["stations"]) == j["parameters"]["n_stations"]
    finally:
        other.stop()
    # both worker processes took jobs: the claims really raced
    from treesim.service.jobs.store import Store

    store = Store(url or f"sqlite:///{data / 'treesim.db'}")
    try:
        claimants = {store.job(j)["worker_id"] for j in ids}
    finally:
        store.dispose()
    assert len(claimants) == 2, claimants


def test_reconstruct_scan_compare_chain(serve, tmp_path):
    base, _ = serve(tmp_path / "data", workers=1)
    with httpx.Client(base_url=base, timeout=30) as c:
        up = _upload(c, BUNDLED_CLOUD)

        def run(process: str, inputs: dict, parameters: dict | None = None) -> dict:
            r = c.post(
                "/v1/jobs",
                json={"process": process, "inputs": inputs, "parameters": parameters or {}},
            )
            assert r.status_code == 201, r.text
            job = wait_job(c, r.json()["jobID"])
            assert job["status"] == "successful", job
            return job

        rec = run("reconstruct", {"cloud": up["id"]}, {"preset": "draft"})
        scan = run(
            "scan",
            {"mesh": {"job": rec["jobID"], "result": "tree.ply"}},
            {"preset": "draft"},
        )
        cmp_ = run(
            "compare",
            {
                "cloud": {"job": scan["jobID"], "result": "scan.laz"},
                "reference": {"job": rec["jobID"], "result": "tree.ply"},
            },
        )
        # a simulated scan of a mesh lies on that mesh
        figures = cmp_["summary"]
        assert figures["accuracy"]["max_m"] < 1e-3, figures["accuracy"]
        assert c.get(f"/v1/jobs/{cmp_['jobID']}/report", follow_redirects=True).status_code == 200
        # the scan's mesh is an input of the compare job's chain: its source job stays
        r = c.delete(f"/v1/uploads/{up['id']}")
        assert r.status_code == 204, r.text
