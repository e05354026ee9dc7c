"""The service under load, on this machine: status-poll latency, upload throughput, jobs
per hour.

Starts the real ``treesim serve`` (uvicorn, 127.0.0.1, a free port) in a fresh temporary
data folder, and measures:

* **status polls**: 50 concurrent clients (asyncio + httpx, one open connection each, in
  this same process, so they share the machine's 2 cores with the server) each polling
  ``GET /v1/jobs/{id}`` in a loop; latency p50/p90/p99/max and requests per second (the API
  alone, no job running, then again while a job runs on the embedded worker), and one
  client alone for the floor;
* **uploads**: ``POST /v1/uploads`` of a generated LAS file (streamed, hashed, sniffed,
  opened and checked, stored) in MB/s, side by side with a plain file copy of the same
  file on the same disk (``shutil.copyfile``);
* **jobs per hour**: N ``run`` jobs of the bundled tree with a preset, queued at once on
  the embedded worker, from the first submission to the last success; side by side with
  the same run in-process (``treesim.run.run_tree``), so the service's own overhead shows.

Measured figures only; nothing is reused between runs.

Usage: ``python benchmarks/bench_service.py [--clients 50] [--polls 40] [--upload-mb 100]
[--jobs 4] [--preset standard]``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import platform
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BUNDLED = ROOT / "pipeline" / "data" / "coffee_tree" / "cloud.txt"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Service:
    def __init__(self, data: Path, workers: int) -> None:
        self.port = _free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        env = {k: v for k, v in os.environ.items() if not k.startswith("TREESIM_")}
        env.update(TREESIM_DATA_DIR=str(data), TREESIM_POLL_INTERVAL_S="0.2")
        self.log = open(data.parent / f"serve-{self.port}.log", "ab")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "treesim.cli", "serve", "--port", str(self.port),
             "--workers", str(workers), "--log-level", "warning"],
            env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
        self._wait(workers)

    def _wait(self, workers: int) -> None:
        import httpx

        path = "/readyz" if workers else "/healthz"
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:
            if self.proc.poll() is not None:
                raise SystemExit(f"treesim serve exited ({self.proc.returncode})")
            try:
                if httpx.get(self.base + path, timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise SystemExit("treesim serve did not start within 120 s")

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.log.close()


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q / 100 * (len(s) - 1))))]


async def _polls(base: str, job_id: str, clients: int, polls: int) -> tuple[list[float], float]:
    """``clients`` clients, each on its own open connection (made and used once before the
    clock starts: building 50 httpx clients costs the client process about a second of CPU
    on this machine, which is not the server's latency), poll at once; (latencies, wall)."""
    import httpx

    latencies: list[float] = []
    errors = 0
    pool = [httpx.AsyncClient(base_url=base, timeout=30) for _ in range(clients)]
    try:
        await asyncio.gather(*(c.get("/healthz") for c in pool))

        async def client(c: httpx.AsyncClient) -> None:
            nonlocal errors
            for _ in range(polls):
                t = time.perf_counter()
                r = await c.get(f"/v1/jobs/{job_id}")
                latencies.append(time.perf_counter() - t)
                errors += r.status_code != 200

        t0 = time.perf_counter()
        await asyncio.gather(*(client(c) for c in pool))
        wall = time.perf_counter() - t0
    finally:
        await asyncio.gather(*(c.aclose() for c in pool))
    if errors:
        raise SystemExit(f"{errors} status polls failed")
    return latencies, wall


def _print_polls(what: str, polled: tuple[list[float], float]) -> None:
    lat, wall = polled
    ms = [x * 1000 for x in lat]
    print(
        f"  {what:28} p50 {_pct(ms, 50):6.1f} ms  p90 {_pct(ms, 90):6.1f} ms  "
        f"p99 {_pct(ms, 99):6.1f} ms  max {max(ms):6.1f} ms  {len(ms) / wall:5.0f} req/s"
    )


def _las_file(path: Path, target_mb: float) -> Path:
    import numpy as np

    from treesim.cloud import Cloud
    from treesim.io import write_cloud

    n = int(target_mb * 1e6 / 30)  # treesim's LAS records are 30 bytes a point
    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 30, (n, 3)) + [500_000.0, 5_200_000.0, 300.0]
    return write_cloud(path, Cloud(xyz))


def _chunks(path: Path, size: int = 1 << 20):
    with open(path, "rb") as fh:
        while chunk := fh.read(size):
            yield chunk


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--polls", type=int, default=40, help="polls per client")
    ap.add_argument("--upload-mb", type=float, default=100.0)
    ap.add_argument("--jobs", type=int, default=4)
    ap.add_argument("--preset", default="standard")
    args = ap.parse_args()

    import httpx

    cores = os.cpu_count() or 1
    print(
        f"# {time.strftime('%Y-%m-%d')}, {platform.machine()} {cores} cores, "
        f"Python {platform.python_version()}, {platform.system()} {platform.release()}"
    )
    with tempfile.TemporaryDirectory(prefix="bench-service-") as tmp:
        tmp_path = Path(tmp)

        # -- the API alone: polls and uploads ---------------------------------------------
        svc = Service(tmp_path / "api", workers=0)
        try:
            with httpx.Client(base_url=svc.base, timeout=600) as c:
                up = c.post("/v1/uploads?filename=cloud.txt", content=BUNDLED.read_bytes())
                up.raise_for_status()
                job = c.post(
                    "/v1/jobs", json={"process": "run", "inputs": {"cloud": up.json()["id"]}}
                ).json()
                print(f"\nstatus polls: {args.clients} clients × {args.polls} polls")
                polled = asyncio.run(_polls(svc.base, job["jobID"], args.clients, args.polls))
                _print_polls(f"{args.clients} clients, API alone", polled)
                alone = asyncio.run(_polls(svc.base, job["jobID"], 1, args.polls))
                _print_polls("1 client, API alone", alone)

                las = _las_file(tmp_path / "big.las", args.upload_mb)
                size_mb = las.stat().st_size / 1e6
                t = time.perf_counter()
                shutil.copyfile(las, tmp_path / "copy.las")
                t_copy = time.perf_counter() - t
                (tmp_path / "copy.las").unlink()
                t = time.perf_counter()
                r = c.post(
                    "/v1/uploads?filename=big.las",
                    content=_chunks(las),
                    headers={"Content-Length": str(las.stat().st_size)},
                )
                t_up = time.perf_counter() - t
                r.raise_for_status()
                n = r.json()["n_points"]
                print(f"\nupload of a {size_mb:.0f} MB LAS ({n:,} points):")
                print(f"  POST /v1/uploads (stream, SHA-256, sniff, open, check, store): "
                      f"{t_up:6.2f} s  {size_mb / t_up:7.0f} MB/s")  # fmt: skip
                print(f"  plain file copy on the same disk:                            "
                      f"{t_copy:6.2f} s  {size_mb / t_copy:7.0f} MB/s")  # fmt: skip
                print(f"  upload / copy throughput: {t_copy / t_up:.2f}")
                from treesim.io import inspect_file

                t = time.perf_counter()
                inspect_file(las)
                t_inspect = time.perf_counter() - t
                print(f"  of which opening and checking the file (inspect_file, in-process): "
                      f"{t_inspect:.2f} s ({100 * t_inspect / t_up:.0f} %)")  # fmt: skip
        finally:
            svc.stop()

        # -- jobs per hour, the embedded worker --------------------------------------------
        from treesim.params import run_preset
        from treesim.run import run_tree

        t = time.perf_counter()
        run_tree(BUNDLED, run_preset(args.preset), tmp_path / "inproc")
        t_inproc = time.perf_counter() - t

        svc = Service(tmp_path / "jobs", workers=1)
        try:
            with httpx.Client(base_url=svc.base, timeout=60) as c:
                up = c.post("/v1/uploads?filename=cloud.txt", content=BUNDLED.read_bytes())
                up.raise_for_status()
                t0 = time.perf_counter()
                ids = [
                    c.post(
                        "/v1/jobs",
                        json={"process": "run", "inputs": {"cloud": up.json()["id"]},
                              "parameters": {"preset": args.preset}},
                    ).json()["jobID"]
                    for _ in range(args.jobs)
                ]  # fmt: skip
                polled = False
                while True:
                    states = [c.get(f"/v1/jobs/{j}").json() for j in ids]
                    if not polled and any(s["status"] == "running" for s in states):
                        polled = True
                        busy = asyncio.run(_polls(svc.base, ids[-1], args.clients, args.polls // 2))
                    if all(s["status"] in ("successful", "failed") for s in states):
                        break
                    time.sleep(0.2)
                wall_jobs = time.perf_counter() - t0
                failed = [s for s in states if s["status"] != "successful"]
                if failed:
                    raise SystemExit(f"{len(failed)} jobs failed: {failed[0]['error']}")
        finally:
            svc.stop()
        print(f"\nstatus polls while a job runs ({args.clients} clients × {args.polls // 2}):")
        _print_polls(f"{args.clients} clients, job running", busy)
        per_job = wall_jobs / args.jobs
        print(f"\njobs: {args.jobs} × run --preset {args.preset} of the bundled tree, 1 slot:")
        print(f"  service: {wall_jobs:6.1f} s in all, {per_job:5.1f} s a job, "
              f"{3600 / per_job:6.0f} jobs/hour")  # fmt: skip
        print(f"  run_tree in-process: {t_inproc:5.1f} s a job, {3600 / t_inproc:6.0f} jobs/hour")
        print(f"  service overhead per job: {per_job - t_inproc:+.1f} s "
              f"({per_job / t_inproc:.2f}× in-process)")  # fmt: skip
    return 0


if __name__ == "__main__":
    from benchmarks import docs_part

    # --docs: the printout also becomes its part of docs/validation.md
    with docs_part.recording(docs_part.from_argv("bench-service"), "bench_service.py"):
        rc = main()
    raise SystemExit(rc)
