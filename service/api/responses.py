"""OpenAPI declarations of the problem responses a route can give; :class:`Download`, a file
response that answers HEAD without reading the file."""

from __future__ import annotations

from typing import Any

from fastapi.responses import FileResponse

from ..problems import MEDIA_TYPE
from ..schemas import Problem

_WHAT = {
    400: "malformed request",
    401: "missing or wrong token",
    404: "not found",
    409: "conflict: in use, or not in a state that allows this",
    411: "length required",
    413: "upload too large",
    415: "unsupported file format",
    422: "invalid input or parameters",
    503: "not ready",
    507: "out of disk space: the data folder's disk (or the job store) is full",
}


def PROBLEM_RESPONSES(*codes: int) -> dict[int | str, dict[str, Any]]:  # noqa: N802
    """``responses=`` entries for these status codes, each a problem object."""
    return {
        code: {
            "model": Problem,
            "description": _WHAT.get(code, "error"),
            "content": {MEDIA_TYPE: {"schema": {"$ref": "#/components/schemas/Problem"}}},
        }
        for code in codes
    }


class Download(FileResponse):
    """A file's response: for a HEAD (which :class:`~.errors.ProblemsAndHead` routes as
    the GET of the same path) the same headers as the GET (size, type, ETag,
    Last-Modified, Range's 206 and Content-Range) from the file's ``stat``, and the file
    is never opened."""

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        from .errors import HEAD_KEY

        if scope.get(HEAD_KEY):
            scope = {**scope, "method": "HEAD"}  # starlette then sends headers only
        await super().__call__(scope, receive, send)
