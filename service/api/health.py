"""``/healthz``, ``/readyz`` and ``/metrics`` (no token needed)."""

from __future__ import annotations

import os
import uuid

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from ..schemas import Health, Readiness
from .deps import SettingsDep, StoreDep

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="The process answers")
def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    response_model=Readiness,
    responses={503: {"model": Readiness, "description": "a check failed"}},
    summary="Database, data folder and a live worker",
)
def readyz(store: StoreDep, settings: SettingsDep) -> JSONResponse:
    checks: dict[str, dict] = {}
    try:
        store.ping()
        checks["database"] = {"ok": True}
    except Exception as exc:  # noqa: BLE001 - reported, not raised
        checks["database"] = {"ok": False, "detail": f"{type(exc).__name__}: {exc}"[:300]}
    try:
        probe = settings.data_dir / f".ready-{uuid.uuid4().hex}"
        probe.write_bytes(b"")
        probe.unlink()
        checks["data_dir"] = {"ok": True}
    except OSError as exc:
        checks["data_dir"] = {"ok": False, "detail": f"{settings.data_dir}: {exc.strerror}"}
    try:
        live = store.live_workers(max(3 * settings.poll_interval_s, settings.lease_s))
        checks["worker"] = {"ok": bool(live), "live": len(live)}
        if not live:
            checks["worker"]["detail"] = "no worker has beaten its heartbeat lately"
    except Exception as exc:  # noqa: BLE001
        checks["worker"] = {"ok": False, "detail": f"{type(exc).__name__}"}
    ok = all(c["ok"] for c in checks.values())
    body = Readiness(status="ready" if ok else "not ready", checks=checks)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


@router.get(
    "/metrics",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "Prometheus text"}},
    summary="Prometheus metrics",
)
def metrics(request: Request) -> Response:
    data = generate_latest(request.app.state.metrics.registry)
    return Response(data, media_type=CONTENT_TYPE_LATEST, headers={"X-Pid": str(os.getpid())})
