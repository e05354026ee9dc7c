"""``GET /``: the jobs page (plain HTML and JavaScript, no build step, no external
resources), and ``GET /problems``: the problem types."""

from __future__ import annotations

import html
from importlib import resources

from fastapi import APIRouter
from fastapi.responses import HTMLResponse, Response

from ..problems import PROBLEMS

router = APIRouter(include_in_schema=False)


@router.get("/", response_class=HTMLResponse)
def index() -> HTMLResponse:
    page = (resources.files("treesim.service") / "static" / "index.html").read_text("utf-8")
    return HTMLResponse(page, headers={"Cache-Control": "no-store"})


@router.get("/favicon.ico")
def favicon() -> Response:
    """No icon (204), so that browsers opening reports log no 404."""
    return Response(status_code=204)


@router.get("/problems", response_class=HTMLResponse)
def problems() -> HTMLResponse:
    rows = "".join(
        f'<tr id="{p.slug}"><td><code>{p.slug}</code></td><td>{p.status}</td>'
        f"<td>{html.escape(p.title)}</td><td>{html.escape(p.doc)}</td></tr>"
        for p in PROBLEMS.values()
    )
    return HTMLResponse(
        "<!doctype html><meta charset=utf-8><title>treesim problem types</title>"
        "<style>body{font:14px system-ui,sans-serif;margin:2em}td{padding:.3em .8em;"
        "border-bottom:1px solid #ddd}</style><h1>Problem types</h1><p>Every error is "
        "<code>application/problem+json</code> (RFC 9457) whose <code>type</code> is "
        "<code>/problems#SLUG</code>.</p><table><tr><th>slug</th><th>status</th><th>title"
        f"</th><th>meaning</th></tr>{rows}</table>"
    )
