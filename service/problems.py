"""One table from treesim's errors to RFC 9457 problem details and HTTP statuses.

Every error the service answers, and every error a job ends with, is a problem object
``{"type", "title", "status", "detail", ...}`` built here: :data:`PROBLEMS` lists the
problem types (``GET /problems`` shows them), :data:`ERROR_TABLE` maps each
:class:`~treesim.errors.TreesimError` subclass to one. No web framework is imported here:
a job's own process uses it too.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass
from typing import Any

from treesim import errors as e

__all__ = [
    "ERROR_TABLE",
    "OGC_EXCEPTIONS",
    "PROBLEMS",
    "ProblemType",
    "ServiceProblem",
    "is_disk_full",
    "problem",
    "problem_for",
]

MEDIA_TYPE = "application/problem+json"


@dataclass(frozen=True)
class ProblemType:
    """A kind of problem: its slug, title, status; its type URI is ``/problems#<slug>``, or
    the standard's own (``type_uri``: OGC API - Processes' exception types)."""

    slug: str
    title: str
    status: int
    doc: str
    type_uri: str | None = None

    @property
    def uri(self) -> str:
        return self.type_uri or f"/problems#{self.slug}"


#: OGC API - Processes - Part 1's exception types.
OGC_EXCEPTIONS = "http://www.opengis.net/def/exceptions/ogcapi-processes-1/1.0/"


#: Every problem type the service uses, by slug.
PROBLEMS: dict[str, ProblemType] = {
    p.slug: p
    for p in (
        ProblemType(
            "invalid-parameter",
            "Invalid parameter",
            422,
            "a parameter is unknown, of the wrong type, out of range, or inconsistent with another",
        ),
        ProblemType(
            "unsupported-format",
            "Unsupported file format",
            415,
            "the uploaded "
            "bytes are not a format treesim reads (LAS, LAZ, PLY, OBJ, XYZ, E57), or "
            "do not match the file name's format",
        ),
        ProblemType(
            "bad-input-file",
            "Unreadable input file",
            422,
            "the file is of a known format but corrupt, truncated or inconsistent",
        ),
        ProblemType("empty-input", "Empty input", 422, "the input holds no points or faces"),
        ProblemType(
            "invalid-geometry",
            "Invalid geometry",
            422,
            "NaN or infinite coordinates, or a degenerate shape",
        ),
        ProblemType(
            "scan-failed", "Scan not possible", 422, "the virtual scan cannot run as asked"
        ),
        ProblemType(
            "resource-limit",
            "Resource limit",
            422,
            "the work would exceed a configured limit (rays, memory, time)",
        ),
        ProblemType(
            "reconstruction-failed",
            "Reconstruction failed",
            422,
            "no tree model could be reconstructed from the cloud",
        ),
        ProblemType(
            "invalid-model", "Invalid tree model", 422, "a tree model or cylinder table is invalid"
        ),
        ProblemType("treesim-error", "treesim error", 422, "treesim refused the input"),
        ProblemType(
            "validation-error",
            "Invalid request",
            422,
            "the request's body or query does not match the API's schema",
        ),
        ProblemType("bad-request", "Bad request", 400, "the request is malformed"),
        ProblemType(
            "unauthorized", "Unauthorized", 401, "a valid 'Authorization: Bearer' token is required"
        ),
        ProblemType("not-found", "Not found", 404, "no such route, upload, job or result"),
        ProblemType(
            "no-such-process",
            "No such process",
            404,
            "no process of this id (OGC API - Processes' exception)",
            OGC_EXCEPTIONS + "no-such-process",
        ),
        ProblemType(
            "no-such-job",
            "No such job",
            404,
            "no job of this id (OGC API - Processes' exception)",
            OGC_EXCEPTIONS + "no-such-job",
        ),
        ProblemType(
            "result-not-ready",
            "Result not ready",
            404,
            "the job has not finished: its results appear when it is successful (OGC API - "
            "Processes' exception)",
            OGC_EXCEPTIONS + "result-not-ready",
        ),
        ProblemType(
            "remote-input-refused",
            "Remote input refused",
            400,
            "an input's href names a file on another host; this service reads only its own "
            "uploads and job results unless TREESIM_ALLOW_REMOTE_HREFS is set",
        ),
        ProblemType(
            "remote-input-blocked",
            "Remote input blocked",
            422,
            "an input's href (or a redirect it took) resolves to a loopback, link-local, "
            "private, multicast or otherwise non-public address, and its host is not one "
            "TREESIM_REMOTE_HREF_HOSTS lists: the service does not read its own network for "
            "a request",
        ),
        ProblemType(
            "method-not-allowed", "Method not allowed", 405, "the route does not take this method"
        ),
        ProblemType(
            "conflict", "Conflict", 409, "the resource is in use or not in a state that allows this"
        ),
        ProblemType(
            "payload-too-large",
            "Upload too large",
            413,
            "the body exceeds TREESIM_MAX_UPLOAD_BYTES",
        ),
        ProblemType(
            "length-required",
            "Length required",
            411,
            "an upload must say how long it is or be sent in chunks",
        ),
        ProblemType(
            "range-not-satisfiable",
            "Range not satisfiable",
            416,
            "the Range header asks for bytes past the file's end, or is inverted",
        ),
        ProblemType(
            "upload-stalled",
            "Upload stalled",
            408,
            "the upload's body stopped arriving for TREESIM_UPLOAD_STALL_S; send it again",
        ),
        ProblemType(
            "client-closed",
            "Client closed the request",
            400,
            "the client closed the connection before its request's body arrived",
        ),
        ProblemType("not-ready", "Not ready", 503, "a dependency of the service is down"),
        ProblemType(
            "time-limit",
            "Time limit exceeded",
            422,
            "the job ran past TREESIM_JOB_TIME_LIMIT_S and was stopped",
        ),
        ProblemType(
            "job-crashed",
            "Job process died",
            500,
            "the job's process crashed or was killed (e.g. out of memory)",
        ),
        ProblemType(
            "worker-lost",
            "Worker lost",
            500,
            "the worker running the job stopped renewing its lease",
        ),
        ProblemType("out-of-memory", "Out of memory", 507, "the job ran out of memory"),
        ProblemType(
            "insufficient-storage",
            "Out of disk space",
            507,
            "the server's data folder is full (no space left on the device, or a quota); "
            "an operator must free space, then send the request again",
        ),
        ProblemType(
            "internal-error",
            "Internal error",
            500,
            "a bug in treesim; a failed job's status shows its log (error.log) with the traceback",
        ),
    )
}

#: treesim's error classes → problem slug; the most specific class wins.
ERROR_TABLE: dict[type[BaseException], str] = {
    e.InvalidParameterError: "invalid-parameter",
    e.UnsupportedFormatError: "unsupported-format",
    e.InputFormatError: "bad-input-file",
    e.EmptyInputError: "empty-input",
    e.InvalidGeometryError: "invalid-geometry",
    e.ScanError: "scan-failed",
    e.ResourceLimitError: "resource-limit",
    e.ReconstructionError: "reconstruction-failed",
    e.ModelError: "invalid-model",
    e.TreesimError: "treesim-error",
    MemoryError: "out-of-memory",
}


def problem(slug: str, detail: str, **extra: Any) -> dict[str, Any]:
    """The problem object of type ``slug`` with ``detail`` and extension members."""
    p = PROBLEMS[slug]
    return {"type": p.uri, "title": p.title, "status": p.status, "detail": detail, **extra}


def slug_for(exc: BaseException) -> str:
    for cls in type(exc).__mro__:
        if cls in ERROR_TABLE:
            return ERROR_TABLE[cls]
    return "internal-error"


#: The errno values of a full disk (no space left; a quota exceeded).
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})

#: A full disk's problem detail: no path of the server's in it.
DISK_FULL_DETAIL = (
    "out of disk space: the server's data folder is full; an operator must free space, "
    "then send it again"
)


#: SQLite's result code of a full database or disk (``SQLITE_FULL``).
SQLITE_FULL = 13
#: Postgres's SQLSTATE of a full disk (``disk_full``).
PG_DISK_FULL = "53100"


def _db_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` is a database driver's own "disk full": SQLite's ``SQLITE_FULL``
    ("database or disk is full", also past ``max_page_count``) or Postgres's
    ``disk_full``; SQLAlchemy's wrapper is looked through by the caller (``orig``)."""
    import sqlite3

    if isinstance(exc, sqlite3.Error):
        code = getattr(exc, "sqlite_errorcode", None)
        if code is not None:
            return code & 0xFF == SQLITE_FULL
        return "database or disk is full" in str(exc)
    return getattr(exc, "sqlstate", None) == PG_DISK_FULL  # psycopg's DiskFull


def is_disk_full(exc: BaseException | None) -> bool:
    """Whether ``exc``, or an error it was raised from or while handling, is a full
    disk (``ENOSPC`` or ``EDQUOT``; a database's "disk full": SQLite's ``SQLITE_FULL``,
    Postgres's ``53100``), however a reader or SQLAlchemy wrapped it.

    Examples
    --------
    >>> import errno, sqlite3
    >>> is_disk_full(OSError(errno.ENOSPC, "No space left on device"))
    True
    >>> is_disk_full(sqlite3.OperationalError("database or disk is full"))
    True
    >>> is_disk_full(ValueError("x"))
    False
    """
    seen: set[int] = set()
    todo = [exc]
    while todo:
        exc = todo.pop()
        if exc is None or id(exc) in seen:
            continue
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in DISK_FULL_ERRNOS:
            return True
        if _db_disk_full(exc):
            return True
        orig = getattr(exc, "orig", None)  # SQLAlchemy's DBAPIError: the driver's error
        todo += [orig if isinstance(orig, BaseException) else None]
        todo += [exc.__cause__, exc.__context__]
    return False


def problem_for(exc: BaseException) -> dict[str, Any]:
    """The problem object for an exception (``field`` kept when the error names one; a
    full disk, however wrapped, is ``insufficient-storage`` without the server's paths)."""
    if is_disk_full(exc):
        return problem("insufficient-storage", DISK_FULL_DETAIL)
    slug = slug_for(exc)
    detail = str(exc) or type(exc).__name__
    if slug == "internal-error":
        detail = f"{type(exc).__name__}: {detail}"
    if slug == "out-of-memory":
        detail = "out of memory; coarsen the resolution or lower chunk_rays"
    extra = {}
    field = getattr(exc, "field", None)
    if field:
        extra["field"] = field
    return problem(slug, detail, **extra)


class ServiceProblem(Exception):
    """An HTTP error answered as a problem object."""

    def __init__(
        self, slug: str, detail: str, *, headers: dict[str, str] | None = None, **extra: Any
    ) -> None:
        super().__init__(detail)
        self.slug = slug
        self.detail = detail
        self.headers = headers or {}
        self.extra = extra

    @property
    def status(self) -> int:
        return PROBLEMS[self.slug].status

    def body(self) -> dict[str, Any]:
        return problem(self.slug, self.detail, **self.extra)
