"""Dependencies of the API's routes, as ``Annotated`` aliases."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, Request

from ..jobs.store import Store
from ..problems import ServiceProblem
from ..settings import Settings

#: The cookie the jobs page sets so that a browser can open reports while a token is set.
TOKEN_COOKIE = "treesim_token"


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_base(request: Request) -> str:
    """The service's own base URL as the client reached it (no trailing slash): links are
    absolute, and an input's href naming it is one of this service's files."""
    return str(request.base_url).rstrip("/")


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
BaseDep = Annotated[str, Depends(get_base)]


def require_token(request: Request) -> None:
    """With ``TREESIM_API_TOKEN`` set, every ``/v1`` request needs ``Authorization: Bearer
    <token>`` (compared in constant time). Reading requests (GET, HEAD) may carry it in the
    jobs page's cookie instead, so that a browser can follow links to reports."""
    token = request.app.state.settings.token()
    if token is None:
        return
    given = None
    auth = request.headers.get("authorization", "")
    scheme, _, value = auth.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        given = value.strip()
    elif request.method in ("GET", "HEAD"):
        given = request.cookies.get(TOKEN_COOKIE)
    if given is None or not hmac.compare_digest(given.encode(), token.encode()):
        raise ServiceProblem(
            "unauthorized",
            "missing or wrong token: send 'Authorization: Bearer <TREESIM_API_TOKEN>'",
            headers={"WWW-Authenticate": 'Bearer realm="treesim"'},
        )
