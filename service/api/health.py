"""``/healthz`` and ``/readyz`` (no token needed), ``/metrics`` (an admin's token while a
token is set, unless ``TREESIM_METRICS_OPEN``)."""

from __future__ import annotations

import os
import shutil
import uuid
from pathlib import Path

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from ..schemas import Health, Readiness
from .deps import SettingsDep, StoreDep, metrics_access

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="The process answers")
def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    response_model=Readiness,
    responses={503: {"model": Readiness, "description": "a check failed"}},
    summary="Database, data folder, its free space and a live worker",
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
    checks["disk"] = _disk_check(settings.data_dir, settings.min_free_mb)
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


def _disk_check(data_dir: Path, min_free_mb: float) -> dict:
    """The data folder's free space against the floor ``TREESIM_MIN_FREE_MB``."""
    try:
        free_mb = shutil.disk_usage(data_dir).free / 2**20
    except OSError as exc:
        return {"ok": False, "detail": f"free space unknown: {exc.strerror}"}
    check: dict = {"ok": free_mb >= min_free_mb, "free_mb": round(free_mb, 1)}
    if not check["ok"]:
        check["detail"] = (
            f"{free_mb:,.0f} MiB free in the data folder, below TREESIM_MIN_FREE_MB "
            f"{min_free_mb:,.0f}"
        )
    return check


@router.get(
    "/metrics",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "Prometheus text"}},
    summary="Prometheus metrics",
)
def metrics(request: Request) -> Response:
    metrics_access(request)  # an admin's token while a token is set (TREESIM_METRICS_OPEN)
    data = generate_latest(request.app.state.metrics.registry)
    return Response(data, media_type=CONTENT_TYPE_LATEST, headers={"X-Pid": str(os.getpid())})
