"""Every error answered as ``application/problem+json`` (RFC 9457), from one table
(:mod:`treesim.service.problems`); no bad input ever gets a 500."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
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


def install(app: FastAPI) -> None:
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

    @app.exception_handler(OSError)
    async def _os_error(request: Request, exc: OSError) -> JSONResponse:
        # a full disk is the operator's to fix (507, no paths); any other is a bug
        if is_disk_full(exc):
            log.warning("%s %s: out of disk space (%s)", request.method, request.url.path, exc)
            return problem_response(problem_for(exc))
        return await _internal(request, exc)

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("internal error on %s %s", request.method, request.url.path)
        return problem_response(
            problem("internal-error", f"{type(exc).__name__}: a bug in treesim; see the log")
        )
