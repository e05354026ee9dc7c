"""OpenAPI declarations of the problem responses a route can give."""

from __future__ import annotations

from typing import Any

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
