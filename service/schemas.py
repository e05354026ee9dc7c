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
    href: str
    rel: str
    type: str | None = None
    title: str | None = None


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
    """A result file of an earlier successful job, used as an input."""

    model_config = ConfigDict(extra="forbid")

    job: str = Field(description="the earlier job's id")
    result: str = Field(description="the result's name, e.g. tree.ply")


InputRef = str | JobResultRef


class ExecuteRequest(BaseModel):
    """``POST /v1/processes/{id}/execution``: inputs and parameters."""

    model_config = ConfigDict(extra="forbid")

    inputs: dict[str, InputRef] = Field(
        default_factory=dict,
        description='input name → upload id, or {"job": ID, "result": NAME}',
    )
    parameters: dict[str, Any] = Field(
        default_factory=dict,
        description="the process's parameters (JSON Schema: GET /v1/processes/{id}); "
        "presets by name",
    )


class JobRequest(ExecuteRequest):
    """``POST /v1/jobs``: the process, its inputs and parameters."""

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
    jobID: str  # noqa: N815 - OGC's name
    results: list[ResultItem]


class ProcessSummary(BaseModel):
    id: str
    title: str
    description: str
    version: str
    jobControlOptions: list[str]  # noqa: N815 - OGC's name
    links: list[Link] = []


class ProcessList(BaseModel):
    processes: list[ProcessSummary]


class ProcessDescription(ProcessSummary):
    inputs: dict[str, Any]
    parameters: dict[str, Any] = Field(description="JSON Schema of the parameters object")
    outputs: dict[str, Any]


class Health(BaseModel):
    status: Literal["ok"]


class Readiness(BaseModel):
    status: Literal["ready", "not ready"]
    checks: dict[str, dict[str, Any]]
