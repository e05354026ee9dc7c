"""The FastAPI application: ``create_app(settings)`` builds it, no import-time singletons.

Routers are composed here: ``/v1`` (OGC API - Processes' landing page and conformance,
open; uploads, processes, jobs, results, where the token applies), the health and
metrics routes, the pages, and redirects from the root's ``/processes``, ``/jobs`` and
``/conformance`` to ``/v1``. The lifespan opens the job store
(creating or migrating its schema), starts the upload inspector, and, with
``settings.workers > 0``, the embedded worker; at shutdown the worker hands its running
jobs back.
"""

from __future__ import annotations

import logging
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import Depends, FastAPI
from fastapi.middleware.cors import CORSMiddleware

from .api import errors, health, jobs, ogc, pages, processes, uploads
from .api.deps import require_token
from .inspect import Inspector
from .jobs.store import Store
from .metrics import Metrics
from .settings import Settings

__all__ = ["create_app"]

log = logging.getLogger("treesim.api")


def _clean_tmp(data_dir: Path, older_than_s: float = 3600.0) -> None:
    """Remove uploads interrupted more than an hour ago (a restart cut them off)."""
    tmp = data_dir / "uploads" / "tmp"
    if not tmp.is_dir():
        return
    now = time.time()
    for p in tmp.glob("*.part"):
        try:
            if now - p.stat().st_mtime > older_than_s:
                p.unlink()
        except OSError:
            pass


def create_app(settings: Settings | None = None, *, store: Store | None = None) -> FastAPI:
    """The service for ``settings`` (default: from the environment)."""
    from treesim._version import __version__

    settings = settings or Settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    store = store or Store(settings.db_url)
    metrics = Metrics(store, live_within_s=max(3 * settings.poll_interval_s, settings.lease_s))

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        _clean_tmp(settings.data_dir)
        app.state.inspector.warm()
        worker = None
        if settings.workers > 0:
            from .jobs.worker import Worker

            worker = Worker(settings, store)
            worker.start()
            expirer = None
        else:  # no worker here: the API itself hands back jobs whose worker died
            from .jobs.worker import LeaseExpirer

            expirer = LeaseExpirer(store, min(settings.lease_s / 2, 5.0)).start()
        app.state.worker = worker
        try:
            yield
        finally:
            if worker is not None:
                worker.stop()
            if expirer is not None:
                expirer.stop()
            app.state.inspector.close()

    app = FastAPI(
        docs_url=None,  # /docs and /redoc: pages.py, from the package's files (no CDN)
        redoc_url=None,
        title="treesim",
        version=__version__,
        summary="Reconstruct trees from field point clouds, scan them with a virtual TLS "
        "scanner, and compare (AVOHD), as jobs over HTTP.",
        description="An OGC API - Processes - Part 1: Core server (landing page `/v1/`, "
        "`/v1/conformance`). Upload a cloud (`POST /v1/uploads`), execute a process "
        "(`POST /v1/processes/{id}/execution`, or treesim's `POST /v1/jobs`), follow the "
        "job (`GET /v1/jobs/{id}`), and fetch its results (`GET /v1/jobs/{id}/results`) "
        "and report. Every error is `application/problem+json` (types at `/problems`, "
        "OGC's exception URIs for no-such-process, no-such-job, result-not-ready). With "
        "users (`TREESIM_TOKENS_FILE`) or one token (`TREESIM_API_TOKEN`) set, `/v1` needs "
        "`Authorization: Bearer <token>`, and each user sees only their own uploads and "
        "jobs (an admin sees all).",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.store = store
    app.state.metrics = metrics
    app.state.inspector = Inspector()
    errors.install(app)
    v1 = [Depends(require_token)]
    app.include_router(ogc.router, prefix="/v1")  # landing page, conformance: open
    app.include_router(uploads.router, prefix="/v1", dependencies=v1)
    app.include_router(processes.router, prefix="/v1", dependencies=v1)
    app.include_router(jobs.router, prefix="/v1", dependencies=v1)
    app.include_router(health.router)
    app.include_router(pages.router)
    app.include_router(ogc.root_router)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "DELETE"],
            allow_headers=["Authorization", "Content-Type"],
        )
    app.add_middleware(_MetricsMiddleware, metrics=metrics)
    app.openapi = lambda: _openapi(app)  # type: ignore[method-assign]
    return app


def _openapi(app: FastAPI) -> dict:
    """FastAPI's schema, with every error response documented as what it is: a problem
    object (``application/problem+json``), including the 422 FastAPI adds by itself, and
    401 on ``/v1`` (a token may be set)."""
    if app.openapi_schema:
        return app.openapi_schema
    from fastapi.openapi.utils import get_openapi

    from .problems import MEDIA_TYPE
    from .schemas import Problem

    schema = get_openapi(
        title=app.title,
        version=app.version,
        summary=app.summary,
        description=app.description,
        routes=app.routes,
    )
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components.setdefault(
        "Problem", Problem.model_json_schema(ref_template="#/components/schemas/{model}")
    )
    for name in ("HTTPValidationError", "ValidationError"):
        components.pop(name, None)
    problem = {MEDIA_TYPE: {"schema": {"$ref": "#/components/schemas/Problem"}}}
    for path, item in schema.get("paths", {}).items():
        for op in item.values():
            responses = op.setdefault("responses", {})
            if path.startswith("/v1") and path not in ("/v1/", "/v1/conformance"):
                responses.setdefault("401", {"description": "missing or wrong token"})
            for code, resp in responses.items():
                if code[0] in "45" and path != "/readyz":  # readyz's 503 is its report
                    resp["content"] = dict(problem)
    app.openapi_schema = schema
    return schema


class _MetricsMiddleware:
    def __init__(self, app: object, metrics: Metrics) -> None:
        self._app = metrics.middleware(app)

    async def __call__(self, scope: dict, receive: object, send: object) -> None:
        await self._app(scope, receive, send)
