"""Liveness (process up) and readiness (database, storage, broker reachable, workers online)."""

from __future__ import annotations

from datetime import timedelta

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse
from sqlalchemy import func, select

from jobqueue.db import WorkerRecord, utcnow
from service.context import Context, get_context
from service.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
def healthz() -> Health:
    """The API process is up."""
    return Health(status="ok")


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}})
def readyz(ctx: Context = Depends(get_context)):
    """Ready to take jobs: database and storage usable, broker reachable, at least one worker alive."""
    checks: dict[str, str] = {}
    try:
        ctx.db.ping()
        checks["database"] = "ok"
    except Exception as exc:
        checks["database"] = f"unreachable: {type(exc).__name__}"
    try:
        ctx.storage.check_writable()
        checks["storage"] = "ok"
    except Exception as exc:
        checks["storage"] = f"not writable: {type(exc).__name__}"
    try:
        with ctx.celery.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, interval_start=0, timeout=3)
        checks["broker"] = "ok"
    except Exception as exc:
        checks["broker"] = f"unreachable: {type(exc).__name__}"
    if checks["database"] == "ok":
        cutoff = utcnow() - timedelta(seconds=max(3 * ctx.settings.reaper_interval_s, 15))
        with ctx.db.session() as s:
            alive = s.scalar(
                select(func.count()).select_from(WorkerRecord).where(WorkerRecord.last_seen >= cutoff)
            )
        checks["workers"] = f"{alive} online" if alive else "none online"
        if not alive and checks["broker"] == "ok" and not ctx.settings.embedded_broker:
            strangers = _workers_on_broker(ctx)
            if strangers:
                checks["workers"] = (
                    f"none online in this job store, but {strangers} on the broker: they do not share the "
                    "API's MAGNET_DATABASE_URL / MAGNET_DATA_DIR, so they cannot see its jobs"
                )
    else:
        checks["workers"] = "unknown"
    ready = (
        all(v == "ok" for k, v in checks.items() if k != "workers")
        and checks["workers"].endswith(" online")
        and not checks["workers"].startswith("none")
    )
    body = Health(status="ready" if ready else "not ready", checks=checks)
    return body if ready else JSONResponse(body.model_dump(), status_code=503)


def _workers_on_broker(ctx: Context) -> int:
    """Workers answering a ping over the broker (Redis only: remote control is off when embedded)."""
    try:
        return len(ctx.celery.control.ping(timeout=1.0) or [])
    except Exception:
        return 0
