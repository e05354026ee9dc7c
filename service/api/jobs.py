"""``/v1/jobs``: follow, list and dismiss jobs (OGC API - Processes' status documents),
their results document and files. Jobs are started in :mod:`.processes`."""

from __future__ import annotations

import shutil
from pathlib import Path, PurePosixPath
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import FileResponse, RedirectResponse

from treesim.io import MESH_SUFFIXES

from ..jobs.store import STATUSES, Store, decode_cursor
from ..problems import ServiceProblem
from ..schemas import (
    JobList,
    Link,
    ResultItem,
    ResultLink,
    ResultList,
    Results,
    StatusInfo,
    iso,
)
from .deps import BaseDep, SettingsDep, StoreDep, UserDep
from .responses import PROBLEM_RESPONSES, Download

router = APIRouter()

RESULTS_REL = "http://www.opengis.net/def/rel/ogc/1.0/results"
JSON = "application/json"


def kind_of_result(path: Path) -> str:
    """A job result's kind as an input of another job: table, plot, mesh or cloud."""
    from treesim.io.ply import ply_has_faces

    suffix = path.suffix.lower()
    if suffix == ".csv":  # a table (stations.csv of a plan), never a cloud
        return "table"
    if suffix == ".zip":  # a plot archive (a plot-from-cloud job's twin.zip)
        return "plot"
    if suffix in MESH_SUFFIXES and (suffix != ".ply" or ply_has_faces(path)):
        return "mesh"
    return "cloud"


# -- following --------------------------------------------------------------------------------
def status_info(job: dict[str, Any], base: str = "") -> StatusInfo:
    """A job's status document (OGC API - Processes' ``statusInfo``, with treesim's
    attempt, stage, inputs, parameters, error and summary beside it)."""
    jid = job["id"]
    url = f"{base}/v1/jobs/{jid}"
    links = [
        Link(href=url, rel="self", type=JSON, title="status"),
        Link(href=f"{base}/v1/jobs", rel="up", type=JSON, title="the job list"),
    ]
    if job["status"] == "successful":
        links.append(Link(href=f"{url}/results", rel=RESULTS_REL, type=JSON, title="results"))
        links.append(Link(href=f"{url}/files", rel="alternate", type=JSON, title="files"))
        names = {r["name"] for r in job["results"] or []}
        if "report.html" in names:
            links.append(
                Link(href=f"{url}/report", rel="alternate", type="text/html", title="report")
            )
    inputs = {
        k: {kk: v[kk] for kk in ("upload", "job", "result", "filename", "kind") if kk in v}
        for k, v in (job["inputs"] or {}).items()
    }
    return StatusInfo(
        jobID=jid,
        processID=job["process"],
        status=job["status"],
        message=job["message"],
        progress=int(round(job["progress"] or 0)),
        stage=job["stage"],
        created=iso(job["created"]),
        started=iso(job["started"]),
        finished=iso(job["finished"]),
        updated=iso(job["updated"]),
        attempt=job["attempt"],
        max_attempts=job["max_attempts"],
        inputs=inputs,
        parameters=job["parameters"] or {},
        error=job["error"] if job["status"] in ("failed", "accepted") else None,
        summary=job["summary"] if job["status"] == "successful" else None,
        links=links,
    )


def _job(store: Store, job_id: str, owner: str | None = None) -> dict[str, Any]:
    """The job; no-such-job (404) when there is none or ``owner`` (if given) did not
    submit it: another user's job is as absent as one that never was."""
    job = store.job(job_id, owner=owner)
    if job is None:
        raise ServiceProblem("no-such-job", f"no job {job_id!r}", field="job_id")
    return job


def _listed(values: list[str] | None) -> list[str]:
    """A query parameter's values, repeated or comma-separated (``?a=x,y&a=z``)."""
    return [x.strip() for v in values or [] for x in v.split(",") if x.strip()]


@router.get(
    "/jobs",
    response_model=JobList,
    response_model_exclude_none=True,
    responses=PROBLEM_RESPONSES(422),
    tags=["jobs"],
    summary="List jobs, newest first",
)
def list_jobs(
    store: StoreDep,
    base: BaseDep,
    user: UserDep,
    status: Annotated[
        list[str] | None,
        Query(description="only these statuses (repeat, or comma-separated)"),
    ] = None,
    limit: Annotated[int, Query(ge=1, le=10000)] = 10,
    cursor: Annotated[str | None, Query(max_length=500, description="from a 'next' link")] = None,
) -> JobList:
    wanted = _listed(status)
    for s in wanted:
        if s not in STATUSES:
            raise ServiceProblem(
                "invalid-parameter",
                f"status {s!r} is not one of {', '.join(STATUSES)}",
                field="status",
            )
    cursor = cursor or None  # an empty cursor= is the first page
    if cursor is not None and decode_cursor(cursor) is None:
        raise ServiceProblem(
            "invalid-parameter",
            "cursor is not one this service made: take it from a 'next' link",
            field="cursor",
        )
    rows, nxt = store.list_jobs(status=wanted, limit=limit, cursor=cursor, owner=user.owner)
    q = "".join(f"&status={s}" for s in wanted)
    url = f"{base}/v1/jobs?limit={limit}{q}"
    links = [
        Link(
            href=url + (f"&cursor={cursor}" if cursor else ""),
            rel="self",
            type=JSON,
            title="this page",
        )
    ]
    if nxt:
        links.append(Link(href=f"{url}&cursor={nxt}", rel="next", type=JSON, title="next page"))
    return JobList(jobs=[status_info(r, base) for r in rows], links=links)


@router.get(
    "/jobs/{job_id}",
    response_model=StatusInfo,
    response_model_exclude_none=True,
    responses=PROBLEM_RESPONSES(404),
    tags=["jobs"],
    summary="A job's status, progress and links to its results",
)
def get_job(job_id: str, store: StoreDep, base: BaseDep, user: UserDep) -> StatusInfo:
    return status_info(_job(store, job_id, user.owner), base)


@router.delete(
    "/jobs/{job_id}",
    response_model=StatusInfo,
    response_model_exclude_none=True,
    responses=PROBLEM_RESPONSES(404, 409),
    tags=["jobs"],
    summary="Dismiss a job: stop it if running, remove its files",
)
def dismiss_job(
    job_id: str, store: StoreDep, settings: SettingsDep, base: BaseDep, user: UserDep
) -> StatusInfo:
    job, before, readers = store.dismiss(job_id, owner=user.owner)
    if job is None:
        raise ServiceProblem("no-such-job", f"no job {job_id!r}", field="job_id")
    if readers:
        raise ServiceProblem(
            "conflict",
            f"job {job_id}'s results are inputs of {len(readers)} unfinished job(s) "
            f"({', '.join(readers[:5])}); dismiss them first",
            jobs=readers,
        )
    # a running job's worker stops it and removes its attempt at its next lease renewal
    shutil.rmtree(settings.data_dir / "jobs" / job_id / "results", ignore_errors=True)
    return status_info(job, base)


# -- results ----------------------------------------------------------------------------------
_REPORT_CSP = (
    "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'none'; frame-ancestors 'self'"
)


def _successful(store: Store, job_id: str, owner: str | None = None) -> dict[str, Any]:
    """The job, successful; else OGC's exception: no-such-job, result-not-ready (accepted
    or running), the job's own error (failed), not-found (dismissed)."""
    job = _job(store, job_id, owner)
    status = job["status"]
    if status in ("accepted", "running"):
        raise ServiceProblem(
            "result-not-ready",
            f"job {job_id} is {status}: results appear when it is successful",
            field="job_id",
        )
    if status == "failed":
        err = dict(job["error"] or {})
        raise _JobFailed(job_id, err)
    if status != "successful":
        raise ServiceProblem(
            "not-found", f"job {job_id} is {status}: it has no results", field="job_id"
        )
    return job


class _JobFailed(ServiceProblem):
    """A failed job's results: its own problem (type and status), as OGC asks."""

    def __init__(self, job_id: str, err: dict[str, Any]) -> None:
        detail = f"job {job_id} failed: {err.get('detail', 'no reason recorded')}"
        super().__init__("internal-error", detail)
        self.err = err

    @property
    def status(self) -> int:
        return int(self.err.get("status", 500))

    def body(self) -> dict[str, Any]:
        return {**self.err, "status": self.status, "detail": self.detail, "field": "job_id"}


@router.get(
    "/jobs/{job_id}/results",
    response_model=Results,
    responses=PROBLEM_RESPONSES(404, 415, 422, 500, 507),
    tags=["results"],
    summary="A successful job's results document: each output by id, a link to its file",
)
def get_results(
    job_id: str,
    store: StoreDep,
    base: BaseDep,
    user: UserDep,
    outputs: Annotated[
        list[str] | None,
        Query(description="only these output ids (repeat, or comma-separated)"),
    ] = None,
) -> Results:
    """OGC API - Processes' results document: output id → ``{href, type, title}`` of its
    file (every output by reference): the outputs the execute request asked for (its
    ``outputs``; every output when it named none), or those ``?outputs=`` names. Outputs
    a run did not write (``cylinders`` of a mesh reconstruction) are left out."""
    from ..processes import PROCESSES

    job = _successful(store, job_id, user.owner)
    names = {r["name"]: r for r in job["results"] or []}
    process = PROCESSES.get(job["process"])
    ids = process.output_ids() if process else {}
    wanted = _listed(outputs) or list(job.get("outputs") or [])
    for oid in wanted:
        if oid not in ids:
            raise ServiceProblem(
                "invalid-parameter",
                f"process {job['process']!r} has no output {oid!r}; its outputs are "
                f"{', '.join(ids)}",
                field="outputs",
            )
    url = f"{base}/v1/jobs/{job_id}/results"
    return {
        oid: ResultLink(href=f"{url}/{name}", type=names[name]["media_type"], title=name)
        for oid, name in ids.items()
        if name in names and (not wanted or oid in wanted)
    }


@router.get(
    "/jobs/{job_id}/files",
    response_model=ResultList,
    responses=PROBLEM_RESPONSES(404, 415, 422, 500, 507),
    tags=["results"],
    summary="A successful job's files: name, size, media type (treesim's listing)",
)
def list_files(job_id: str, store: StoreDep, base: BaseDep, user: UserDep) -> ResultList:
    job = _successful(store, job_id, user.owner)
    url = f"{base}/v1/jobs/{job_id}/results"
    return ResultList(
        jobID=job_id,
        results=[ResultItem(**r, href=f"{url}/{r['name']}") for r in job["results"] or []],
    )


@router.get(
    "/jobs/{job_id}/results/{name:path}",
    response_class=FileResponse,
    responses={
        200: {"content": {"application/octet-stream": {}}, "description": "the file"},
        206: {"description": "part of the file (Range request)"},
        **PROBLEM_RESPONSES(404, 415, 422, 500, 507),
    },
    tags=["results"],
    summary="Download one result (Range requests supported)",
)
def get_result(
    job_id: str, name: str, store: StoreDep, settings: SettingsDep, user: UserDep
) -> Download:
    job = _successful(store, job_id, user.owner)
    items = {r["name"]: r for r in job["results"] or []}
    clean = PurePosixPath(name).as_posix()
    if clean not in items:
        raise ServiceProblem("not-found", f"job {job_id} has no result {name!r}", field="name")
    path = settings.data_dir / "jobs" / job_id / "results" / clean
    if not path.is_file():
        raise ServiceProblem("not-found", f"result {name!r} of job {job_id} is gone", field="name")
    headers = {"X-Content-Type-Options": "nosniff"}
    if items[clean]["media_type"] == "text/html":
        # reports are self-contained: they may run their own inline code and show data:
        # images, but never call out (nor back to the API with the reader's cookie)
        headers["Content-Security-Policy"] = _REPORT_CSP
    else:
        headers["Content-Disposition"] = f'attachment; filename="{PurePosixPath(clean).name}"'
    return Download(path, media_type=items[clean]["media_type"], headers=headers)


@router.get(
    "/jobs/{job_id}/report",
    status_code=307,
    response_class=RedirectResponse,
    responses={
        307: {"description": "to results/report.html"},
        **PROBLEM_RESPONSES(404, 415, 422, 500, 507),
    },
    tags=["results"],
    summary="The job's HTML report",
)
def get_report(job_id: str, store: StoreDep, user: UserDep) -> RedirectResponse:
    job = _successful(store, job_id, user.owner)
    if "report.html" not in {r["name"] for r in job["results"] or []}:
        raise ServiceProblem(
            "not-found", f"job {job_id} ({job['process']}) has no report", field="job_id"
        )
    # a redirect, so that the report's relative links (vs_mesh/report.html) resolve
    return RedirectResponse(f"/v1/jobs/{job_id}/results/report.html", status_code=307)
