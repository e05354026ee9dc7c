"""``/v1/processes``: the processes (OGC API - Processes' list and descriptions), and
starting a job: ``POST /v1/processes/{id}/execution`` (the standard execute request) and
``POST /v1/jobs`` (treesim's way, kept)."""

from __future__ import annotations

from typing import Annotated, Any, NamedTuple
from urllib.parse import SplitResult, unquote, urlsplit

from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from treesim.errors import InvalidParameterError

from ..jobs.store import Store
from ..problems import ServiceProblem
from ..processes import PROCESSES, Process, check_parameters
from ..schemas import (
    ExecuteRequest,
    JobRequest,
    Link,
    ProcessDescription,
    ProcessList,
    ProcessSummary,
    StatusInfo,
)
from ..settings import Settings
from .deps import BaseDep, User, require_token
from .jobs import kind_of_result, status_info
from .responses import PROBLEM_RESPONSES

router = APIRouter()

EXECUTE_REL = "http://www.opengis.net/def/rel/ogc/1.0/execute"
JSON = "application/json"


# -- the processes ----------------------------------------------------------------------------
def _summary(p: Process, base: str) -> ProcessSummary:
    d = p.describe()
    return ProcessSummary(
        id=p.id,
        title=p.title,
        description=p.description,
        version=d["version"],
        jobControlOptions=d["jobControlOptions"],
        outputTransmission=d["outputTransmission"],
        links=[
            Link(href=f"{base}/v1/processes/{p.id}", rel="self", type=JSON, title="description"),
            Link(
                href=f"{base}/v1/processes/{p.id}/execution",
                rel=EXECUTE_REL,
                type=JSON,
                title="execute",
            ),
        ],
    )


@router.get(
    "/processes",
    response_model=ProcessList,
    responses=PROBLEM_RESPONSES(422),
    tags=["processes"],
    summary="The processes",
)
def list_processes(
    base: BaseDep,
    limit: Annotated[int, Query(ge=1, le=10000)] = 10,
    offset: Annotated[int, Query(ge=0, le=10000, description="from a 'next' link")] = 0,
) -> ProcessList:
    procs = list(PROCESSES.values())
    page = procs[offset : offset + limit]
    url = f"{base}/v1/processes"
    links = [Link(href=f"{url}?limit={limit}&offset={offset}", rel="self", type=JSON, title="this")]
    if offset + limit < len(procs):
        nxt = f"{url}?limit={limit}&offset={offset + limit}"
        links.append(Link(href=nxt, rel="next", type=JSON, title="next page"))
    return ProcessList(processes=[_summary(p, base) for p in page], links=links)


def _process(process_id: str, field: str = "process_id") -> Process:
    try:
        return PROCESSES[process_id]
    except KeyError:
        raise ServiceProblem(
            "no-such-process",
            f"no process {process_id!r}; the processes are {', '.join(PROCESSES)}",
            field=field,
        ) from None


@router.get(
    "/processes/{process_id}",
    response_model=ProcessDescription,
    responses=PROBLEM_RESPONSES(404),
    tags=["processes"],
    summary="A process: its inputs (files and settings, each with its JSON Schema), outputs, "
    "and the JSON Schema of its parameters object",
)
def get_process(process_id: str, base: BaseDep) -> ProcessDescription:
    p = _process(process_id)
    d = p.describe()
    return ProcessDescription(
        **_summary(p, base).model_dump(),
        inputs=d["inputs"],
        outputs=d["outputs"],
        parameters=d["parameters"],
    )


# -- the inputs of a request ------------------------------------------------------------------
class Remote(NamedTuple):
    """An input's href on another host (``TREESIM_ALLOW_REMOTE_HREFS``): fetched first."""

    url: str


#: An input file as the request names it: an upload's id, or (job id, result name).
FileRef = str | tuple[str, str]

_QUALIFIED = {"value", "mediaType", "encoding", "schema"}
_LINK = {"href", "rel", "type", "hreflang", "title"}


def _own_file(path: str, field: str) -> FileRef | None:
    """The upload or job result a path of this service names (``/v1/uploads/ID``,
    ``/v1/jobs/ID/results/NAME``), or None."""
    parts = [unquote(p) for p in path.split("/")]
    if len(parts) >= 4 and parts[:3] == ["", "v1", "uploads"] and parts[3]:
        return parts[3]
    if len(parts) >= 6 and parts[:3] == ["", "v1", "jobs"] and parts[4] == "results":
        return (parts[3], "/".join(parts[5:]))
    return None


def _origin(url: SplitResult) -> tuple[str, str, int | None]:
    """Scheme, host and port (the scheme's default where none is given)."""
    port = url.port or {"http": 80, "https": 443}.get(url.scheme)
    return url.scheme, (url.hostname or "").lower(), port


def _href(href: str, field: str, base: str, settings: Settings) -> FileRef | Remote:
    """An input's href: one of this service's files, or (remote hrefs allowed) the URL to
    fetch; anything else a 400 problem."""
    try:
        url, own = urlsplit(href), urlsplit(base)
        url.port  # noqa: B018 - a malformed port raises here
    except ValueError:
        raise ServiceProblem(
            "bad-request", f"{field}: href {href!r} is no URL", field=field
        ) from None
    if url.scheme not in ("", "http", "https"):
        raise ServiceProblem(
            "bad-request", f"{field}: href {href!r} is not an http(s) URL", field=field
        )
    if not url.netloc or _origin(url) == _origin(own):
        path, prefix = url.path, own.path.rstrip("/")  # the service may live under a prefix
        if prefix and path.startswith(prefix + "/"):
            path = path[len(prefix) :]
        ref = _own_file(path, field)
        if ref is None:
            raise ServiceProblem(
                "bad-request",
                f"{field}: href {href!r} is neither an upload (/v1/uploads/ID) nor a job's "
                "result (/v1/jobs/ID/results/NAME) of this service",
                field=field,
            )
        return ref
    if not settings.allow_remote_hrefs:
        raise ServiceProblem(
            "remote-input-refused",
            f"{field}: href {href!r} is not on this service ({base}/); upload the file "
            "(POST /v1/uploads) and give its href, or have the service's operator set "
            "TREESIM_ALLOW_REMOTE_HREFS",
            field=field,
        )
    return Remote(href)


def _file_input(value: Any, field: str, base: str, settings: Settings) -> FileRef | Remote:
    if isinstance(value, str):
        if "://" in value:  # a bare URL: as {"href": URL}
            return _href(value, field, base, settings)
        return value  # treesim: an upload's id
    if isinstance(value, dict) and set(value) == {"job", "result"}:
        if isinstance(value["job"], str) and isinstance(value["result"], str):
            return (value["job"], value["result"])
    if isinstance(value, dict) and "href" in value and set(value) <= _LINK:
        if isinstance(value["href"], str):
            return _href(value["href"], field, base, settings)
    if isinstance(value, dict) and "value" in value:
        raise ServiceProblem(
            "invalid-parameter",
            f"{field} is a file: give it by reference, {{'href': URL}} of an upload "
            "(POST /v1/uploads) or of a job's result, not by value",
            field=field,
        )
    raise ServiceProblem(
        "invalid-parameter",
        f"{field} is a file: {{'href': URL}} of an upload or a job's result, an upload's "
        "id, or {'job': ID, 'result': NAME}",
        field=field,
    )


def _names_a_file(value: Any) -> bool:
    """Whether an input's value names a file (an upload id, an href, a job's result)
    rather than being a setting's value."""
    if isinstance(value, str):
        return True
    return isinstance(value, dict) and ("href" in value or set(value) == {"job", "result"})


def _setting_input(value: Any, field: str) -> Any:
    if isinstance(value, dict) and "value" in value and set(value) <= _QUALIFIED:
        return value["value"]
    if isinstance(value, dict) and "href" in value and set(value) <= _LINK:
        raise ServiceProblem(
            "invalid-parameter", f"{field} is a setting: give its value, not an href", field=field
        )
    return value


def split_inputs(
    process: Process,
    inputs: dict[str, Any],
    parameters: dict[str, Any],
    base: str,
    settings: Settings,
) -> tuple[dict[str, FileRef | Remote], dict[str, Any]]:
    """A request's inputs as (the files, the parameters object): each file input's
    reference, and the settings given as inputs merged into ``parameters`` (a setting
    given both ways is refused)."""
    files = {i.name for i in process.inputs}
    settings_names = set(process.parameters_schema()["properties"])
    refs: dict[str, FileRef | Remote] = {}
    merged = dict(parameters) if isinstance(parameters, dict) else parameters
    for name, value in inputs.items():
        field = f"inputs.{name}"
        if name in files and (name not in settings_names or _names_a_file(value)):
            if isinstance(value, list):
                raise ServiceProblem(
                    "invalid-parameter",
                    f"{field} takes one file (maxOccurs 1), not a list",
                    field=field,
                )
            refs[name] = _file_input(value, field, base, settings)
        elif name in settings_names and isinstance(merged, dict):
            if name in merged:
                raise ServiceProblem(
                    "invalid-parameter",
                    f"{name!r} is given twice, as an input and in parameters; give it once",
                    field=field,
                )
            merged[name] = _setting_input(value, field)
        else:
            known = ", ".join([*files, *sorted(settings_names)])
            raise ServiceProblem(
                "invalid-parameter",
                f"process {process.id!r} has no input {name!r}; its inputs are {known}",
                field=field,
            )
    return refs, merged


def _check_outputs(process: Process, body: ExecuteRequest) -> None:
    """The outputs a request asks for exist, by reference, in their own media type."""
    from ..jobs.worker import media_type

    ids = process.output_ids()
    for oid, want in body.outputs.items():
        field = f"outputs.{oid}"
        if oid not in ids:
            raise ServiceProblem(
                "invalid-parameter",
                f"process {process.id!r} has no output {oid!r}; its outputs are {', '.join(ids)}",
                field=field,
            )
        if want.transmissionMode == "value":
            raise ServiceProblem(
                "invalid-parameter",
                f"{field}: outputs are files, returned by reference only "
                "(outputTransmission: reference)",
                field=field,
            )
        mt = want.format.mediaType if want.format else None
        if mt and mt != media_type(ids[oid]):
            raise ServiceProblem(
                "invalid-parameter",
                f"{field} is {media_type(ids[oid])}, not {mt}",
                field=field,
            )


def _resolve_inputs(
    process: Process,
    given: dict[str, FileRef],
    store: Store,
    settings: Settings,
    owner: str | None = None,
) -> tuple[dict[str, Any], list[tuple[str, str | None, str | None]]]:
    """Each file input's record (upload or job result: its path and kind) and the links
    the store keeps from the job to what it reads; with ``owner``, only that user's
    uploads and jobs (another's is 404, as if absent)."""
    resolved: dict[str, Any] = {}
    links: list[tuple[str, str | None, str | None]] = []
    for spec in process.inputs:
        name, field = spec.name, f"inputs.{spec.name}"
        ref = given.get(name)
        if ref is None:
            if not spec.required:
                continue
            raise ServiceProblem(
                "invalid-parameter",
                f"input {name!r} is required: {spec.description} ({{'href': URL}} of an "
                "upload or a job's result)",
                field=field,
            )
        if isinstance(ref, str):
            resolved[name], link = _upload_input(ref, store, field, owner)
        else:
            resolved[name], link = _result_input(ref, store, settings, field, owner)
        links.append((name, *link))
        kind = resolved[name]["kind"]
        if kind not in spec.kinds:
            raise ServiceProblem(
                "invalid-parameter",
                f"{field} must be a {' or '.join(spec.kinds)}, got a {kind}",
                field=field,
            )
    return resolved, links


def _upload_input(
    upload_id: str, store: Store, field: str, owner: str | None = None
) -> tuple[dict[str, Any], tuple[str | None, str | None]]:
    up = store.upload(upload_id, owner=owner)
    if up is None:
        raise ServiceProblem("not-found", f"{field}: no upload {upload_id!r}", field=field)
    rec = {"upload": up["id"], "path": up["path"], "filename": up["filename"], "kind": up["kind"]}
    return rec, (up["id"], None)


def _result_input(
    ref: tuple[str, str], store: Store, settings: Settings, field: str, owner: str | None = None
) -> tuple[dict[str, Any], tuple[str | None, str | None]]:
    job_id, result = ref
    src = store.job(job_id, owner=owner)
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
    if result not in names and src["process"] in PROCESSES:  # an output id names its file
        result = PROCESSES[src["process"]].output_ids().get(result, result)
    if result not in names:
        raise ServiceProblem(
            "not-found",
            f"{field}: job {job_id} has no result {result!r}; it has {', '.join(sorted(names))}",
            field=field,
        )
    rel = f"jobs/{job_id}/results/{result}"
    kind = kind_of_result(settings.data_dir / rel)
    return {"job": job_id, "result": result, "path": rel, "kind": kind}, (None, job_id)


def submit(
    process: Process,
    inputs: dict[str, FileRef],
    parameters: dict[str, Any],
    store: Store,
    settings: Settings,
    user: User | None = None,
    outputs: list[str] | None = None,
) -> dict[str, Any]:
    """Check a job's parameters and inputs and store it, accepted: its record. ``user``:
    who submits it (its owner; a non-admin may name only their own uploads and jobs);
    ``outputs``: the output ids the request asked for (its results document lists
    those; None: every output)."""
    try:
        parsed = check_parameters(process, parameters)
    except InvalidParameterError as exc:
        raise ServiceProblem(
            "invalid-parameter", str(exc), field=getattr(exc, "field", "parameters")
        ) from None
    resolved, links = _resolve_inputs(
        process, inputs, store, settings, user.owner if user else None
    )
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

    return store.create_job(
        process=process.id,
        inputs=resolved,
        parameters=parameters,
        max_attempts=settings.max_attempts,
        time_limit_s=settings.job_time_limit_s,
        links=links,
        check=still_there,
        owner=user.owns_as if user else None,
        outputs=outputs,
    )


async def _start(
    process: Process, body: ExecuteRequest, request: Request, response: Response, prefer: str | None
) -> StatusInfo:
    """A request's job, accepted: 201, its status and ``Location``; ``Preference-Applied:
    respond-async`` when the client asked for it (every process runs as a job)."""
    settings: Settings = request.app.state.settings
    user = require_token(request)
    base = str(request.base_url).rstrip("/")
    _check_outputs(process, body)
    refs, parameters = split_inputs(process, body.inputs, body.parameters, base, settings)
    files: dict[str, FileRef] = {}
    for name, ref in refs.items():
        if isinstance(ref, Remote):
            from .uploads import fetch_remote

            got = await fetch_remote(
                request.app.state, ref.url, f"inputs.{name}", owner=user.owns_as
            )
            ref = got["id"]
        files[name] = ref
    store: Store = request.app.state.store
    outputs = list(body.outputs) or None  # checked above: ids of the process's outputs
    job = await run_in_threadpool(
        submit, process, files, parameters, store, settings, user, outputs
    )
    response.status_code = 201
    response.headers["Location"] = f"{base}/v1/jobs/{job['id']}"
    tokens = {t.strip().lower() for t in (prefer or "").replace(";", ",").split(",")}
    if "respond-async" in tokens:
        response.headers["Preference-Applied"] = "respond-async"
    return status_info(job, base)


_SUBMIT_RESPONSES = {
    201: {
        "description": "the job, accepted",
        "headers": {
            "Location": {"schema": {"type": "string"}, "description": "the job's status"},
            "Preference-Applied": {
                "schema": {"type": "string"},
                "description": "respond-async, when the request preferred it",
            },
        },
    },
    **PROBLEM_RESPONSES(400, 404, 409, 413, 415, 422, 507),
}

PreferHeader = Annotated[
    str | None,
    Header(description="respond-async (every process runs as a job: 201 and its status)"),
]


@router.post(
    "/processes/{process_id}/execution",
    status_code=201,
    response_model=StatusInfo,
    response_model_exclude_none=True,
    responses=_SUBMIT_RESPONSES,
    tags=["processes"],
    summary="Execute a process as a job (OGC API - Processes)",
)
async def execute(
    process_id: str,
    body: ExecuteRequest,
    request: Request,
    response: Response,
    prefer: PreferHeader = None,
) -> StatusInfo:
    """The standard execute request: ``{"inputs": {"cloud": {"href": URL}, "preset":
    "draft"}, "outputs": {...}, "response": "document"}``. A file input is an href of
    this service's upload or job result (treesim also takes an upload's id or
    ``{"job", "result"}``); a setting is its value. Every process runs as a job: 201,
    ``Location`` and its status."""
    return await _start(_process(process_id), body, request, response, prefer)


@router.post(
    "/jobs",
    status_code=201,
    response_model=StatusInfo,
    response_model_exclude_none=True,
    responses=_SUBMIT_RESPONSES,
    tags=["jobs"],
    summary="Start a job of a process (treesim's way)",
)
async def create_job(
    body: JobRequest, request: Request, response: Response, prefer: PreferHeader = None
) -> StatusInfo:
    """``{"process": "run", "inputs": {"cloud": UPLOAD_ID}, "parameters": {...}}``. An input
    may be an earlier successful job's result: ``{"job": ID, "result": "tree.ply"}``; the
    execute request's forms are accepted too."""
    if body.process not in PROCESSES:
        raise ServiceProblem(
            "invalid-parameter",
            f"unknown process {body.process!r}; the processes are {', '.join(PROCESSES)}",
            field="process",
        )
    return await _start(PROCESSES[body.process], body, request, response, prefer)
