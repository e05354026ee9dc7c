"""``GET /``: the jobs page (plain HTML and JavaScript, ``static/index.html`` and
``static/jobs.js``, no build step, no external resources, under a Content-Security-Policy)
or, for a client asking for JSON, the OGC landing page; and ``GET /problems``: the problem
types."""

from __future__ import annotations

import base64
import hashlib
import html
import re
from importlib import resources

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse, JSONResponse, Response
from pydantic import BaseModel, Field

from ..problems import PROBLEMS, ServiceProblem
from .deps import SESSION_COOKIE, SESSION_S, check_session, known_tokens, make_session

router = APIRouter(include_in_schema=False)


def wants_html(accept: str, f: str | None) -> bool:
    """Whether ``GET /`` answers the jobs page (HTML) rather than the JSON landing page:
    ``?f=html``/``?f=json`` decide; else HTML only when the client names ``text/html`` in
    ``Accept`` (a browser does) with at least the weight of ``application/json``. ``*/*``
    or no ``Accept`` (curl, requests, OWSLib) is JSON.

    Examples
    --------
    >>> wants_html("text/html,application/xhtml+xml,*/*;q=0.8", None)
    True
    >>> wants_html("*/*", None), wants_html("application/json", "html")
    (False, True)
    """
    if f in ("html", "json"):
        return f == "html"
    weights: dict[str, float] = {}
    for part in accept.split(","):
        kind, *params = (x.strip() for x in part.split(";"))
        q = 1.0
        for p in params:
            if p.startswith("q="):
                try:
                    q = float(p[2:])
                except ValueError:
                    q = 0.0
        weights[kind.lower()] = max(q, weights.get(kind.lower(), 0.0))
    html_q = weights.get("text/html", 0.0)
    return html_q > 0 and html_q >= weights.get("application/json", 0.0)


@router.get("/", response_class=HTMLResponse)
def index(request: Request, f: str | None = None) -> Response:
    """The jobs page for a browser; OGC API - Processes' landing page (JSON) for a client
    (``Accept: application/json``, ``?f=json``, or no preference)."""
    from .ogc import landing_page

    headers = {"Cache-Control": "no-store", "Vary": "Accept"}
    if not wants_html(request.headers.get("accept", ""), f):
        doc = landing_page(str(request.base_url).rstrip("/"))
        return JSONResponse(doc.model_dump(), headers=headers)
    page = (resources.files("treesim.service") / "static" / "index.html").read_text("utf-8")
    return HTMLResponse(page, headers={**headers, "Content-Security-Policy": page_csp(page)})


def page_csp(page: str) -> str:
    """The jobs page's Content-Security-Policy: its script from this origin only
    (``/static/jobs.js``; no inline script), its own ``<style>`` by hash, requests and the
    embedded reports (``frame-src``) to this origin only, nothing from elsewhere.

    Examples
    --------
    >>> csp = page_csp("<style>p { color: red }</style>")
    >>> "script-src 'self';" in csp and "style-src 'sha256-" in csp
    True
    """
    hashes = " ".join(
        "'sha256-" + base64.b64encode(hashlib.sha256(m.encode()).digest()).decode() + "'"
        for m in re.findall(r"<style>(.*?)</style>", page, flags=re.DOTALL)
    )
    styles = hashes or "'none'"
    return (
        f"default-src 'none'; script-src 'self'; style-src {styles}; "
        "img-src 'self' data:; connect-src 'self'; frame-src 'self'; base-uri 'none'; "
        "form-action 'self'; frame-ancestors 'none'"
    )


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


class SessionRequest(BaseModel):
    token: str = Field(min_length=1, max_length=4096)


def _whoami(request: Request) -> JSONResponse:
    users = known_tokens(request.app.state.settings)
    if users is None:
        return JSONResponse({"user": None, "role": "admin", "token_required": False})
    user = check_session(request.app.state.settings, users, request.cookies.get(SESSION_COOKIE))
    if user is None:
        raise ServiceProblem("unauthorized", "no session: send your token to POST /session")
    return JSONResponse({"user": user.name, "role": user.role, "token_required": True})


@router.post("/session")
def start_session(body: SessionRequest, request: Request) -> Response:
    """The jobs page's sign-in: the token, sent once, is exchanged for a session cookie
    (``HttpOnly``, ``SameSite=Strict``, ``Secure`` over https) that opens reading requests;
    the page never stores the token where script or a cookie could leak it."""
    settings = request.app.state.settings
    users = known_tokens(settings)
    if users is None:  # an open service: nothing to sign in to
        return JSONResponse({"user": None, "role": "admin", "token_required": False})
    value = make_session(settings, users, body.token)
    if value is None:
        raise ServiceProblem(
            "unauthorized",
            "wrong token",
            headers={"WWW-Authenticate": 'Bearer realm="treesim"'},
        )
    response = _whoami_after(value, request)
    response.set_cookie(
        SESSION_COOKIE,
        value,
        max_age=SESSION_S,
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return response


def _whoami_after(value: str, request: Request) -> JSONResponse:
    settings = request.app.state.settings
    user = check_session(settings, known_tokens(settings) or {}, value)
    assert user is not None
    return JSONResponse({"user": user.name, "role": user.role, "token_required": True})


@router.get("/session")
def get_session(request: Request) -> Response:
    """Who the page's session is (401 without one; ``token_required`` false on an open
    service)."""
    return _whoami(request)


@router.delete("/session")
def end_session(request: Request) -> Response:
    """Sign out: the cookie is cleared."""
    response = Response(status_code=204)
    response.delete_cookie(
        SESSION_COOKIE,
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return response


# -- /docs and /redoc from the package's own files (service/static/THIRD_PARTY.md) ---------
_ASSETS = {
    "swagger-ui-bundle.js": "text/javascript",
    "swagger-ui.css": "text/css",
    "redoc.standalone.js": "text/javascript",
    "jobs.js": "text/javascript",  # the jobs page's own script
}
#: the page's own script changes with the package: revalidated, not kept a day
_NO_CACHE = {"jobs.js"}


def docs_csp(page: str) -> str:
    """The Content-Security-Policy of a docs page: scripts from this origin and the page's
    own inline script (by its hash), nothing from elsewhere.

    Examples
    --------
    >>> "'sha256-" in docs_csp("<script>init()</script>")
    True
    """
    hashes = " ".join(
        "'sha256-" + base64.b64encode(hashlib.sha256(m.encode()).digest()).decode() + "'"
        for m in re.findall(r"<script>(.*?)</script>", page, flags=re.DOTALL)
    )
    return (
        f"default-src 'none'; script-src 'self' {hashes}; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data:; font-src 'self' data:; connect-src 'self'; "
        "worker-src 'self' blob:; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
    )


def _docs_page(html_response: HTMLResponse) -> HTMLResponse:
    page = bytes(html_response.body).decode()
    return HTMLResponse(
        page, headers={"Content-Security-Policy": docs_csp(page), "Cache-Control": "no-store"}
    )


@router.get("/docs", response_class=HTMLResponse)
def swagger_ui(request: Request) -> HTMLResponse:
    """Swagger UI, from the package's files (no CDN)."""
    from fastapi.openapi.docs import get_swagger_ui_html

    return _docs_page(
        get_swagger_ui_html(
            openapi_url="/openapi.json",
            title="treesim API",
            swagger_js_url="/static/swagger-ui-bundle.js",
            swagger_css_url="/static/swagger-ui.css",
            swagger_favicon_url="/favicon.ico",
        )
    )


@router.get("/redoc", response_class=HTMLResponse)
def redoc(request: Request) -> HTMLResponse:
    """ReDoc, from the package's files (no CDN, no web fonts)."""
    from fastapi.openapi.docs import get_redoc_html

    return _docs_page(
        get_redoc_html(
            openapi_url="/openapi.json",
            title="treesim API",
            redoc_js_url="/static/redoc.standalone.js",
            redoc_favicon_url="/favicon.ico",
            with_google_fonts=False,
        )
    )


@router.get("/static/{name}")
def static_asset(name: str) -> Response:
    """The docs pages' and the jobs page's scripts and styles (a fixed list; anything else
    is 404)."""
    if name not in _ASSETS:
        raise ServiceProblem("not-found", f"no file {name!r}", field="name")
    path = resources.files("treesim.service") / "static" / name
    cache = "no-cache" if name in _NO_CACHE else "public, max-age=86400"
    return Response(
        path.read_bytes(),
        media_type=_ASSETS[name],
        headers={"Cache-Control": cache, "X-Content-Type-Options": "nosniff"},
    )
