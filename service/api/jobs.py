"""``/v1/jobs`` and ``/v1/processes``: submit, follow, dismiss, and fetch results."""

from __future__ import annotations

import shutil
from pathlib import Path, PurePosixPath
from typing import Annotated, Any

from fastapi import APIRouter, Query, Response
from fastapi.responses import FileResponse, RedirectResponse

from treesim.errors import InvalidParameterError
from treesim.io import MESH_SUFFIXES

from ..jobs.store import STATUSES, Store, decode_cursor
from ..problems import ServiceProblem
from ..processes import PROCESSES, Process, check_parameters
from ..schemas import (
    ExecuteRequest,
    JobList,
    JobRequest,
    Link,
    ProcessDescription,
    ProcessList,
    ProcessSummary,
    ResultItem,
    ResultList,
    StatusInfo,
    iso,
)
from ..settings import Settings
from .deps import SettingsDep, StoreDep
from .responses import PROBLEM_RESPONSES

router = APIRouter()

RESULTS_REL = "http://www.opengis.net/def/rel/ogc/1.0/results"


# -- processes --------------------------------------------------------------------------------
def _summary(p: Process) -> ProcessSummary:
    d = p.describe()
    return ProcessSummary(
        id=p.id,
        title=p.title,
        description=p.description,
        version=d["version"],
        jobControlOptions=d["jobControlOptions"],
        links=[
            Link(href=f"/v1/processes/{p.id}", rel="self", type="application/json"),
            Link(
                href=f"/v1/processes/{p.id}/execution",
                rel="http://www.opengis.net/def/rel/ogc/1.0/execute",
                title="execute",
            ),
        ],
    )


@router.get("/processes", response_model=ProcessList, tags=["processes"], summary="The processes")
def list_processes() -> ProcessList:
    return ProcessList(processes=[_summary(p) for p in PROCESSES.values()])


def _process(process_id: str, field: str = "process_id") -> Process:
    try:
        return PROCESSES[process_id]
    except KeyError:
        raise ServiceProblem(
            "not-found",
            f"no process {process_id!r}; the processes are {', '.join(PROCESSES)}",
            field=field,
        ) from None


@router.get(
    "/processes/{process_id}",
    response_model=ProcessDescription,
    responses=PROBLEM_RESPONSES(404),
    tags=["processes"],
    summary="A process: its inputs, outputs and the JSON Schema of its parameters",
)
def get_process(process_id: str) -> ProcessDescription:
    p = _process(process_id)
    d = p.describe()
    return ProcessDescription(
        **_summary(p).model_dump(),
        inputs=d["inputs"],
        parameters=d["parameters"],
        outputs=d["outputs"],
    )


# -- submitting -------------------------------------------------------------------------------
def _kind_of_result(path: Path) -> str:
    from treesim.io.ply import ply_has_faces

    suffix = path.suffix.lower()
    if suffix == ".csv":  # a table (stations.csv of a plan), never a cloud
        return "table"
    if suffix in MESH_SUFFIXES and (suffix != ".ply" or ply_has_faces(path)):
        return "mesh"
    return "cloud"


def _resolve_inputs(
    process: Process, given: dict[str, Any], store: Store, settings: Settings
) -> tuple[dict[str, Any], list[tuple[str, str | None, str | None]]]:
    known = {i.name: i for i in process.inputs}
    for name in given:
        if name not in known:
            raise ServiceProblem(
                "invalid-parameter",
                f"process {process.id!r} has no input {name!r}; its inputs are {', '.join(known)}",
                field=f"inputs.{name}",
            )
    resolved: dict[str, Any] = {}
    links: list[tuple[str, str | None, str | None]] = []
    for name, spec in known.items():
        ref = given.get(name)
        field = f"inputs.{name}"
        if ref is None:
            if not spec.required:
                continue
            raise ServiceProblem(
                "invalid-parameter",
                f"input {name!r} is required: {spec.description} (an upload id)",
                field=field,
            )
        if isinstance(ref, str):
            up = store.upload(ref)
            if up is None:
                raise ServiceProblem("not-found", f"{field}: no upload {ref!r}", field=field)
            kind = up["kind"]
            resolved[name] = {
                "upload": up["id"],
                "path": up["path"],
                "filename": up["filename"],
                "kind": kind,
            }
            links.append((name, up["id"], None))
        else:
            job_id, result = ref.job, ref.result
            src = store.job(job_id)
            if src is None:
                raise ServiceProblem("not-found", f"{field}: no job {job_id!r}", field=field)
            if src["status"] != "successful":
                raise ServiceProblem(
                    "conflict",
                    f"{field}: job {job_id} is {src['status']}; chain a job after its input "
                    "job has succeeded",
                    field=field,
                )
            names = {r["name"] for r in src["results"] or []}
            if result not in names:
                raise ServiceProblem(
                    "not-found",
                    f"{field}: job {job_id} has no result {result!r}; it has "
                    f"{', '.join(sorted(names))}",
                    field=field,
                )
            rel = f"jobs/{job_id}/results/{result}"
            kind = _kind_of_result(settings.data_dir / rel)
            resolved[name] = {"job": job_id, "result": result, "path": rel, "kind": kind}
            links.append((name, None, job_id))
        if kind not in spec.kinds:
            raise ServiceProblem(
                "invalid-parameter",
                f"{field} must be a {' or '.join(spec.kinds)}, got a {kind}",
                field=field,
            )
    return resolved, links


def submit(
    process: Process,
    inputs: dict[str, Any],
    parameters: dict[str, Any],
    store: Store,
    settings: Settings,
    response: Response,
) -> StatusInfo:
    try:
        parsed = check_parameters(process, parameters)
    except InvalidParameterError as exc:
        raise ServiceProblem(
            "invalid-parameter", str(exc), field=getattr(exc, "field", "parameters")
        ) from None
    resolved, links = _resolve_inputs(process, inputs, store, settings)
    if process.check_inputs is not None:
        try:
            process.check_inputs(frozenset(resolved), parsed)
        except InvalidParameterError as exc:
            raise ServiceProblem(
                "invalid-parameter", str(exc), field=getattr(exc, "field", "inputs")
            ) from None

    def still_there(conn: Any) -> None:
        from sqlalchemy import select

        from ..jobs.store import jobs, uploads

        for name, upload_id, source in links:
            if (
                upload_id
                and conn.execute(select(uploads.c.id).where(uploads.c.id == upload_id)).first()
                is None
            ):
                raise ServiceProblem(
                    "not-found",
                    f"inputs.{name}: upload {upload_id} was just deleted",
                    field=f"inputs.{name}",
                )
            if (
                source
                and conn.execute(select(jobs.c.status).where(jobs.c.id == source)).scalar()
                != "successful"
            ):
                raise ServiceProblem(
                    "conflict",
                    f"inputs.{name}: job {source} was just dismissed",
                    field=f"inputs.{name}",
                )

    job = store.create_job(
        process=process.id,
        inputs=resolved,
        parameters=parameters,
        max_attempts=settings.max_attempts,
        time_limit_s=settings.job_time_limit_s,
        links=links,
        check=still_there,
    )
    response.status_code = 201
    response.headers["Location"] = f"/v1/jobs/{job['id']}"
    return status_info(job)


_SUBMIT_RESPONSES = {
    201: {
        "description": "the job, accepted",
        "headers": {"Location": {"schema": {"type": "string"}}},
    },
    **PROBLEM_RESPONSES(404, 409, 422),
}


@router.post(
    "/jobs",
    status_code=201,
    response_model=StatusInfo,
    responses=_SUBMIT_RESPONSES,
    tags=["jobs"],
    summary="Start a job of a process",
)
def create_job(
    body: JobRequest, store: StoreDep, settings: SettingsDep, response: Response
) -> StatusInfo:
    """``{"process": "run", "inputs": {"cloud": UPLOAD_ID}, "parameters": {...}}``. An input
    may be an earlier successful job's result: ``{"job": ID, "result": "tree.ply"}``."""
    if body.process not in PROCESSES:
        raise ServiceProblem(
            "invalid-parameter",
            f"unknown process {body.process!r}; the processes are {', '.join(PROCESSES)}",
            field="process",
        )
    return submit(PROCESSES[body.process], body.inputs, body.parameters, store, settings, response)


@router.post(
    "/processes/{process_id}/execution",
    status_code=201,
    response_model=StatusInfo,
    responses=_SUBMIT_RESPONSES,
    tags=["processes"],
    summary="Execute a process as a job (OGC API – Processes)",
)
def execute(
    process_id: str,
    body: ExecuteRequest,
    store: StoreDep,
    settings: SettingsDep,
    response: Response,
) -> StatusInfo:
    return submit(_process(process_id), body.inputs, body.parameters, store, settings, response)


# -- following --------------------------------------------------------------------------------
def status_info(job: dict[str, Any]) -> StatusInfo:
    jid = job["id"]
    links = [Link(href=f"/v1/jobs/{jid}", rel="self", type="application/json", title="status")]
    if job["status"] == "successful":
        links.append(
            Link(
                href=f"/v1/jobs/{jid}/results",
                rel=RESULTS_REL,
                type="application/json",
                title="results",
            )
        )
        names = {r["name"] for r in job["results"] or []}
        if "report.html" in names:
            links.append(
                Link(
                    href=f"/v1/jobs/{jid}/report", rel="alternate", type="text/html", title="report"
                )
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


def _job(store: Store, job_id: str) -> dict[str, Any]:
    job = store.job(job_id)
    if job is None:
        raise ServiceProblem("not-found", f"no job {job_id!r}", field="job_id")
    return job


@router.get("/jobs", response_model=JobList, tags=["jobs"], summary="List jobs, newest first")
def list_jobs(
    store: StoreDep,
    status: Annotated[
        list[str] | None,
        Query(description="only these statuses (repeat, or comma-separated)"),
    ] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 50,
    cursor: Annotated[str | None, Query(max_length=500, description="from a 'next' link")] = None,
) -> JobList:
    wanted: list[str] = []
    for s in status or []:
        wanted.extend(x.strip() for x in s.split(",") if x.strip())
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
    rows, nxt = store.list_jobs(status=wanted, limit=limit, cursor=cursor)
    links = []
    if nxt:
        q = "".join(f"&status={s}" for s in wanted)
        links.append(Link(href=f"/v1/jobs?limit={limit}&cursor={nxt}{q}", rel="next"))
    return JobList(jobs=[status_info(r) for r in rows], links=links)


@router.get(
    "/jobs/{job_id}",
    response_model=StatusInfo,
    responses=PROBLEM_RESPONSES(404),
    tags=["jobs"],
    summary="A job's status, progress and links to its results",
)
def get_job(job_id: str, store: StoreDep) -> StatusInfo:
    return status_info(_job(store, job_id))


@router.delete(
    "/jobs/{job_id}",
    response_model=StatusInfo,
    responses=PROBLEM_RESPONSES(404, 409),
    tags=["jobs"],
    summary="Dismiss a job: stop it if running, remove its files",
)
def dismiss_job(job_id: str, store: StoreDep, settings: SettingsDep) -> StatusInfo:
    job, before, readers = store.dismiss(job_id)
    if job is None:
        raise ServiceProblem("not-found", f"no job {job_id!r}", field="job_id")
    if readers:
        raise ServiceProblem(
            "conflict",
            f"job {job_id}'s results are inputs of {len(readers)} unfinished job(s) "
            f"({', '.join(readers[:5])}); dismiss them first",
            jobs=readers,
        )
    # a running job's worker stops it and removes its attempt at its next lease renewal
    shutil.rmtree(settings.data_dir / "jobs" / job_id / "results", ignore_errors=True)
    return status_info(job)


# -- results ----------------------------------------------------------------------------------
_REPORT_CSP = (
    "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'none'; frame-ancestors 'self'"
)


def _successful(store: Store, job_id: str) -> dict[str, Any]:
    job = _job(store, job_id)
    if job["status"] != "successful":
        raise ServiceProblem(
            "not-found",
            f"job {job_id} is {job['status']}: results appear when it is successful",
            field="job_id",
        )
    return job


@router.get(
    "/jobs/{job_id}/results",
    response_model=ResultList,
    responses=PROBLEM_RESPONSES(404),
    tags=["results"],
    summary="A successful job's files",
)
def list_results(job_id: str, store: StoreDep) -> ResultList:
    job = _successful(store, job_id)
    return ResultList(
        jobID=job_id,
        results=[
            ResultItem(**r, href=f"/v1/jobs/{job_id}/results/{r['name']}")
            for r in job["results"] or []
        ],
    )


@router.get(
    "/jobs/{job_id}/results/{name:path}",
    response_class=FileResponse,
    responses={
        200: {"content": {"application/octet-stream": {}}, "description": "the file"},
        206: {"description": "part of the file (Range request)"},
        **PROBLEM_RESPONSES(404),
    },
    tags=["results"],
    summary="Download one result (Range requests supported)",
)
def get_result(job_id: str, name: str, store: StoreDep, settings: SettingsDep) -> FileResponse:
    job = _successful(store, job_id)
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
    return FileResponse(path, media_type=items[clean]["media_type"], headers=headers)


@router.get(
    "/jobs/{job_id}/report",
    status_code=307,
    response_class=RedirectResponse,
    responses={307: {"description": "to results/report.html"}, **PROBLEM_RESPONSES(404)},
    tags=["results"],
    summary="The job's HTML report",
)
def get_report(job_id: str, store: StoreDep) -> RedirectResponse:
    job = _successful(store, job_id)
    if "report.html" not in {r["name"] for r in job["results"] or []}:
        raise ServiceProblem(
            "not-found", f"job {job_id} ({job['process']}) has no report", field="job_id"
        )
    # a redirect, so that the report's relative links (vs_mesh/report.html) resolve
    return RedirectResponse(f"/v1/jobs/{job_id}/results/report.html", status_code=307)
