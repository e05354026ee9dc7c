"""Every error answered as ``application/problem+json`` (RFC 9457), from one table
(:mod:`treesim.service.problems`); no bad input ever gets a 500."""

from __future__ import annotations

import json
import logging
import sqlite3
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from treesim.errors import TreesimError

from ..problems import MEDIA_TYPE, ServiceProblem, is_disk_full, problem, problem_for

log = logging.getLogger("treesim.api")

_HTTP_SLUGS = {
    400: "bad-request",
    401: "unauthorized",
    404: "not-found",
    405: "method-not-allowed",
    408: "upload-stalled",
    409: "conflict",
    411: "length-required",
    413: "payload-too-large",
    415: "unsupported-format",
    416: "range-not-satisfiable",
    422: "validation-error",
    503: "not-ready",
    507: "insufficient-storage",
}


def problem_response(body: dict[str, Any], headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse(body, status_code=body["status"], media_type=MEDIA_TYPE, headers=headers)


def _loc(loc: tuple[Any, ...]) -> str:
    parts = [str(p) for p in loc]
    if parts and parts[0] in ("body", "query", "path", "header"):
        parts = parts[1:]
    return ".".join(parts)


#: The scope key that marks a HEAD request the middleware routes as its GET: a response
#: that would read a file (:class:`~.responses.Download`) sends its headers only.
HEAD_KEY = "treesim.head"


class ProblemsAndHead:
    """ASGI middleware: an error answered as plain text by the framework itself (a file's
    416 or malformed Range, ...) becomes ``application/problem+json``; ``HEAD`` is served
    as the ``GET`` of the same route, headers only."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        head = scope["method"] == "HEAD"
        if head:  # routed as GET; a download reads the flag and sends no file (HEAD_KEY)
            scope = {**scope, "method": "GET", HEAD_KEY: True}
        state: dict[str, Any] = {"start": None, "done": False}

        async def wrapped(message: dict) -> None:
            if state["done"]:
                return  # HEAD: the body is not sent
            if message["type"] == "http.response.start":
                headers = dict(message.get("headers") or [])
                ctype = headers.get(b"content-type", b"")
                if message["status"] >= 400 and not ctype.startswith(
                    (b"application/problem+json", b"application/json")
                ):
                    state["start"] = message  # rewritten once its body is read
                    state["text"] = b""
                    return
                await send(message)
                if head:
                    await send({"type": "http.response.body", "body": b"", "more_body": False})
                    state["done"] = True
                return
            if state["start"] is not None and message["type"] == "http.response.body":
                state["text"] += message.get("body", b"")
                if message.get("more_body"):
                    return
                await _send_problem(send, state["start"], state["text"], head)
                state["done"] = True
                return
            await send(message)

        await self.app(scope, receive, wrapped)


async def _send_problem(send: Any, start: dict, text: bytes, head: bool) -> None:
    """The plain error ``start``/``text`` sent as a problem object (its headers kept, but
    the type and length)."""
    status = int(start["status"])
    slug = _HTTP_SLUGS.get(status)
    detail = text.decode("utf-8", "replace").strip() or f"HTTP {status}"
    if status == 416:
        detail = f"{detail}: the Range asks for bytes past the file's end, or is inverted"
    body = (
        problem(slug, detail)
        if slug
        else {"type": "about:blank", "title": detail, "status": status, "detail": detail}
    )
    data = json.dumps(body).encode()
    keep = [
        (k, v)
        for k, v in start.get("headers") or []
        if k.lower() not in (b"content-type", b"content-length")
    ]
    keep += [(b"content-type", MEDIA_TYPE.encode()), (b"content-length", str(len(data)).encode())]
    await send({"type": "http.response.start", "status": status, "headers": keep})
    await send({"type": "http.response.body", "body": b"" if head else data, "more_body": False})


def install(app: FastAPI) -> None:
    app.add_middleware(ProblemsAndHead)

    @app.exception_handler(ServiceProblem)
    async def _service(request: Request, exc: ServiceProblem) -> JSONResponse:
        return problem_response(exc.body(), exc.headers)

    @app.exception_handler(TreesimError)
    async def _treesim(request: Request, exc: TreesimError) -> JSONResponse:
        return problem_response(problem_for(exc))

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {"field": _loc(tuple(e.get("loc", ()))), "message": e.get("msg", "")}
            for e in exc.errors()
        ]
        first = errors[0] if errors else {"field": "", "message": "invalid request"}
        detail = f"{first['field'] or 'request'}: {first['message']}"
        return problem_response(
            problem("validation-error", detail, field=first["field"] or None, errors=errors)
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        slug = _HTTP_SLUGS.get(exc.status_code)
        if slug is None:
            body = {
                "type": "about:blank",
                "title": str(exc.detail),
                "status": exc.status_code,
                "detail": str(exc.detail),
            }
        else:
            detail = str(exc.detail)
            if exc.status_code == 404 and detail == "Not Found":
                detail = f"no route {request.url.path}; the API is described at /docs"
            body = problem(slug, detail)
        return problem_response(body, dict(exc.headers or {}))

    @app.exception_handler(ClientDisconnect)
    async def _gone(request: Request, exc: ClientDisconnect) -> JSONResponse:
        # the client's choice, not a bug: one warning line, no traceback, not a 500
        log.warning("%s %s: the client closed the connection", request.method, request.url.path)
        return problem_response(
            problem("client-closed", "the connection closed before the body arrived")
        )

    async def _disk_full_or_bug(request: Request, exc: Exception) -> JSONResponse:
        # a full disk is the operator's to fix (507, no paths); any other is a bug
        if is_disk_full(exc):
            log.warning("%s %s: out of disk space (%s)", request.method, request.url.path, exc)
            return problem_response(problem_for(exc))
        return await _internal(request, exc)

    # OSError: ENOSPC, EDQUOT; the job store's errors: SQLite's "database or disk is full"
    # (SQLAlchemy's OperationalError around sqlite3's), Postgres's disk_full
    for cls in (OSError, sqlite3.Error, DBAPIError):
        app.add_exception_handler(cls, _disk_full_or_bug)

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("internal error on %s %s", request.method, request.url.path)
        return problem_response(
            problem("internal-error", f"{type(exc).__name__}: a bug in treesim; see the log")
        )
