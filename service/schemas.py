"""The HTTP API's request and response bodies (pydantic), input and output apart.

Parameters are not modelled here: each process's ``parameters`` object is described by the
JSON Schema generated from the parameter model (``GET /v1/processes/{id}``) and checked by
it (:func:`treesim.service.processes.check_parameters`).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

JobStatus = Literal["accepted", "running", "successful", "failed", "dismissed"]


def iso(t: float | None) -> str | None:
    """Seconds since the epoch as an ISO 8601 UTC time (millisecond precision)."""
    if t is None:
        return None
    return datetime.fromtimestamp(t, tz=UTC).isoformat(timespec="milliseconds")


class Link(BaseModel):
    """A link (OGC API's ``link.yaml``): every one says its media type."""

    href: str
    rel: str
    type: str
    title: str


class Problem(BaseModel):
    """An RFC 9457 problem object (``application/problem+json``)."""

    model_config = ConfigDict(extra="allow")

    type: str
    title: str
    status: int
    detail: str
    field: str | None = None


class Bounds(BaseModel):
    min: list[float] = Field(min_length=3, max_length=3)
    max: list[float] = Field(min_length=3, max_length=3)


class UploadOut(BaseModel):
    """A stored upload."""

    id: str
    filename: str
    format: str = Field(
        description="las, laz, ply, e57, xyz, obj, stl, off or glb: from the content; zip "
        "for a plot archive"
    )
    kind: Literal["cloud", "mesh", "plot", "cylinders"]
    size_bytes: int
    sha256: str
    n_points: int | None = None
    n_triangles: int | None = None
    n_trees: int | None = Field(None, description="a plot's trees")
    bounds: Bounds = Field(
        description="the points' or vertices' box; a plot's square around its centre, at "
        "its terrain's height there"
    )
    fields: list[str] = []
    created: str | None
    links: list[Link] = []


class UploadList(BaseModel):
    uploads: list[UploadOut]


class JobResultRef(BaseModel):
    """A result file of an earlier successful job, used as an input (treesim's shorthand
    for ``{"href": ".../v1/jobs/ID/results/NAME"}``)."""

    model_config = ConfigDict(extra="forbid")

    job: str = Field(description="the earlier job's id")
    result: str = Field(description="the result's name, e.g. tree.ply")


class OutputFormat(BaseModel):
    """``format`` of a requested output (OGC's ``format.yaml``)."""

    mediaType: str | None = None  # noqa: N815 - OGC's name
    encoding: str | None = None
    schema_: str | dict[str, Any] | None = Field(None, alias="schema")


class OutputRequest(BaseModel):
    """One requested output: its format and how it is returned (files: by reference)."""

    model_config = ConfigDict(extra="forbid")

    format: OutputFormat | None = None
    transmissionMode: Literal["value", "reference"] | None = None  # noqa: N815 - OGC's name


class ExecuteRequest(BaseModel):
    """``POST /v1/processes/{id}/execution``: OGC API - Processes' execute request, and
    treesim's ``parameters`` object beside it."""

    model_config = ConfigDict(extra="forbid")

    inputs: dict[str, Any] = Field(
        default_factory=dict,
        description='input id → value. A file: {"href": URL of an upload or of a job\'s '
        'result on this service}, or (treesim) an upload id or {"job": ID, "result": '
        'NAME}. A setting: its value, or {"value": ...}',
    )
    outputs: dict[str, OutputRequest] = Field(
        default_factory=dict,
        description="output id → its format and transmissionMode (files are returned by "
        "reference); all outputs when empty",
    )
    response: Literal["document", "raw"] = Field(
        "document",
        description="document or raw: a job's results are the results document at "
        "/v1/jobs/{id}/results either way (every output a link)",
    )
    parameters: dict[str, Any] = Field(
        default_factory=dict,
        description="treesim's extension: the process's settings as one object (JSON "
        "Schema: the description's parameters); the same names as the inputs",
    )


class JobRequest(ExecuteRequest):
    """``POST /v1/jobs`` (treesim's way): the process, its inputs and parameters."""

    process: str = Field(description="run, reconstruct, scan, compare, plan or plot-scan")


class StatusInfo(BaseModel):
    """A job's status (OGC API – Processes ``statusInfo``, with treesim's extra fields)."""

    jobID: str  # noqa: N815 - OGC's name
    processID: str  # noqa: N815 - OGC's name
    type: Literal["process"] = "process"
    status: JobStatus
    message: str | None = None
    progress: int = Field(ge=0, le=100)
    stage: str | None = None
    created: str | None = None
    started: str | None = None
    finished: str | None = None
    updated: str | None = None
    attempt: int
    max_attempts: int
    inputs: dict[str, Any]
    parameters: dict[str, Any]
    error: Problem | None = None
    summary: dict[str, Any] | None = None
    links: list[Link] = []


class JobList(BaseModel):
    jobs: list[StatusInfo]
    links: list[Link] = []


class ResultItem(BaseModel):
    name: str
    size_bytes: int
    media_type: str
    href: str


class ResultList(BaseModel):
    """A successful job's files (treesim's listing, ``/v1/jobs/{id}/files``)."""

    jobID: str  # noqa: N815 - OGC's name
    results: list[ResultItem]


class ResultLink(BaseModel):
    """One output in a results document: where to fetch it and its media type."""

    href: str
    type: str
    title: str


#: OGC API - Processes' results document: output id → its link.
Results = dict[str, ResultLink]


class ProcessSummary(BaseModel):
    id: str
    title: str
    description: str
    version: str
    jobControlOptions: list[str]  # noqa: N815 - OGC's name
    outputTransmission: list[str] = ["reference"]  # noqa: N815 - OGC's name
    links: list[Link] = []


class ProcessList(BaseModel):
    processes: list[ProcessSummary]
    links: list[Link]


class ProcessDescription(ProcessSummary):
    inputs: dict[str, Any] = Field(
        description="input id → {title, description, schema, minOccurs, maxOccurs}: the "
        "files, and every setting of the parameters object"
    )
    outputs: dict[str, Any] = Field(description="output id → {title, description, schema}")
    parameters: dict[str, Any] = Field(
        description="treesim's extension: JSON Schema of the parameters object"
    )


class LandingPage(BaseModel):
    """OGC API's landing page: what the service is and where its resources are."""

    title: str
    description: str
    links: list[Link]


class Conformance(BaseModel):
    """The requirement classes of OGC API - Processes the service conforms to."""

    conformsTo: list[str]  # noqa: N815 - OGC's name


class Health(BaseModel):
    status: Literal["ok"]


class Readiness(BaseModel):
    status: Literal["ready", "not ready"]
    checks: dict[str, dict[str, Any]]
