"""OGC API - Processes - Part 1: Core's entry points: the landing page (``/v1/``, and ``/``
for a client that asks for JSON), ``/v1/conformance``, and ``/conformance``,
``/processes…`` and ``/jobs…`` redirected to ``/v1`` so that a client given the server's
root (OWSLib's ``Processes("http://host:port/")``) finds them."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, RedirectResponse

from ..openapi30 import OPENAPI30_JSON, to_openapi30
from ..schemas import Conformance, LandingPage, Link
from .deps import BaseDep

router = APIRouter(tags=["OGC API"])
root_router = APIRouter(include_in_schema=False)

_CONF = "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/"

#: The requirement classes of OGC API - Processes - Part 1 the service implements.
CONFORMANCE = [
    _CONF + c for c in ("core", "ogc-process-description", "json", "oas30", "job-list", "dismiss")
]

_OGC_REL = "http://www.opengis.net/def/rel/ogc/1.0/"
JSON = "application/json"
#: FastAPI writes OpenAPI 3.1 (its schemas are JSON Schema 2020-12)
OPENAPI_JSON = "application/vnd.oai.openapi+json;version=3.1"


def landing_page(base: str) -> LandingPage:
    """The landing page with the links Part 1 requires (API definition, conformance,
    processes) and the job list; ``base`` is the service's URL."""
    api = f"{base}/v1"
    links = [
        Link(href=f"{api}/", rel="self", type=JSON, title="this document"),
        Link(href=f"{base}/", rel="alternate", type="text/html", title="the jobs page"),
        Link(
            href=f"{api}/openapi-3.0.json",
            rel="service-desc",
            type=OPENAPI30_JSON,
            title="the API (OpenAPI 3.0)",
        ),
        Link(
            href=f"{base}/openapi.json",
            rel="service-desc",
            type=OPENAPI_JSON,
            title="the API (OpenAPI 3.1, as FastAPI writes it)",
        ),
        Link(href=f"{base}/docs", rel="service-doc", type="text/html", title="the API's docs"),
        Link(
            href=f"{api}/conformance",
            rel=_OGC_REL + "conformance",
            type=JSON,
            title="conformance classes",
        ),
        Link(href=f"{api}/conformance", rel="conformance", type=JSON, title="conformance"),
        Link(href=f"{api}/processes", rel=_OGC_REL + "processes", type=JSON, title="processes"),
        Link(href=f"{api}/jobs", rel=_OGC_REL + "job-list", type=JSON, title="jobs"),
    ]
    return LandingPage(
        title="treesim",
        description="OGC API - Processes server of treesim: reconstruct trees from field "
        "point clouds, scan them with a virtual TLS scanner, compare.",
        links=links,
    )


@router.get(
    "/",
    response_model=LandingPage,
    summary="The landing page (OGC API - Processes)",
    response_model_exclude_none=True,
)
def get_landing_page(base: BaseDep) -> LandingPage:
    return landing_page(base)


@router.get(
    "/conformance",
    response_model=Conformance,
    summary="The OGC API - Processes conformance classes",
)
def get_conformance() -> Conformance:
    return Conformance(conformsTo=CONFORMANCE)


class OpenAPIResponse(JSONResponse):
    """An OpenAPI document, as its media type says."""

    media_type = "application/vnd.oai.openapi+json"


@router.get(
    "/openapi-3.0.json",
    summary="The API's definition in OpenAPI 3.0 (the oas30 conformance class)",
    response_class=OpenAPIResponse,
)
def get_openapi30(request: Request) -> OpenAPIResponse:
    return OpenAPIResponse(to_openapi30(request.app.openapi()))


def _to_v1(request: Request) -> RedirectResponse:
    """308 (method and body kept) to the same path under ``/v1``."""
    url = "/v1" + request.url.path
    if request.url.query:
        url += "?" + request.url.query
    return RedirectResponse(url, status_code=308)


_METHODS = ["GET", "HEAD", "POST", "DELETE"]
for _path in ("/conformance", "/processes", "/processes/{rest:path}", "/jobs", "/jobs/{rest:path}"):
    root_router.add_api_route(_path, _to_v1, methods=_METHODS)
