"""The FastAPI application factory: `uvicorn --factory service.app:create_app` or `magnet serve`."""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from jobqueue.celery_app import make_celery
from jobqueue.db import Database
from jobqueue.dispatch import BrokerUnavailable
from jobqueue.settings import Settings
from jobqueue.storage import Storage
from models.errors import MagnetError
from service.auth import load_keys
from service.context import Context
from service.error_envelope import ErrorsInBody
from service.jobs import InUse, NotFinished, NotFound, QueueFull, QuotaExceeded
from service.limits import BodySizeLimit
from service.mesh_check import UploadRejected
from service.openapi import install as install_openapi
from service.routers import events, health, jobs, meshes, metrics, models, web

DESCRIPTION = """Mesh agglomeration as a service: upload a mesh, queue an agglomeration job (METIS,
k-means, graph neural networks), poll it, download the agglomerated mesh, its quality metrics,
labels and lymph structs. Authenticate with `Authorization: Bearer <API key>`."""


def create_app(settings: Settings | None = None) -> FastAPI:
    """A configured app; settings default to the MAGNET_* environment."""
    settings = settings or Settings()
    storage = Storage(settings.data_dir)
    db = Database(settings.resolved_database_url)
    db.create_schema()
    from models import api

    app = FastAPI(title="MAGNET Service", version=api.MODEL_VERSION, description=DESCRIPTION)
    app.state.ctx = Context(settings=settings, db=db, storage=storage, celery=make_celery(settings))
    app.state.api_keys = load_keys(settings)
    app.add_middleware(
        BodySizeLimit,
        max_bytes=settings.max_upload_bytes + (1 << 20),
        form_max_bytes=settings.max_upload_bytes * 4 // 3 + (1 << 20),
    )
    app.add_middleware(ErrorsInBody)
    for router in (health.router, metrics.router, meshes.router, jobs.router, events.router, models.router):
        app.include_router(router)
    web.mount_page(app)
    _error_handlers(app)
    install_openapi(app)
    return app


def _error(status: int, detail: str, field: str | None = None, headers: dict | None = None) -> JSONResponse:
    """Every 422 has one shape, {detail, field, errors} (as FastAPI's request errors, see
    invalid_request); field is the parameter at fault or null."""
    body: dict = {"detail": detail}
    if status == 422:
        if field is None and ":" in detail:  # "subset: expected a JSON list ..." names its field
            head = detail.split(":", 1)[0]
            field = head if head.replace(".", "").replace("_", "").isalnum() else None
        loc = ["body", *field.split(".")] if field else ["body"]
        body |= {"field": field, "errors": [{"loc": loc, "msg": detail, "type": "value_error"}]}
    elif field:
        body["field"] = field
    return JSONResponse(body, status_code=status, headers=headers)


def _error_handlers(app: FastAPI) -> None:
    """Each failure kind mapped once to its HTTP status."""

    @app.exception_handler(MagnetError)
    async def library_error(_: Request, exc: MagnetError):  # MeshError, ParameterError, ModelError
        return _error(422, str(exc) or type(exc).__name__, getattr(exc, "field", None))

    @app.exception_handler(RequestValidationError)
    async def invalid_request(_: Request, exc: RequestValidationError):
        # FastAPI's own handler echoes the input, which fails on NaN/Infinity (a 500): say where instead
        errors = [
            {
                "loc": [p if isinstance(p, int) else str(p) for p in e.get("loc", ())],
                "msg": str(e.get("msg", "")),
                "type": str(e.get("type", "")),
            }
            for e in exc.errors()
        ]
        names = [
            ".".join(p for p in e["loc"][1:] if isinstance(p, str)) or (e["loc"] or ["request"])[0]
            for e in errors
        ]
        detail = (
            "; ".join(f"{n}: {e['msg']}" for n, e in zip(names, errors, strict=True)) or "invalid request"
        )
        return JSONResponse({"detail": detail, "field": names[0] if names else None, "errors": errors}, 422)

    @app.exception_handler(UploadRejected)
    async def upload_rejected(_: Request, exc: UploadRejected):
        field = getattr(exc, "field", "file")
        error = {"loc": ["body", field], "msg": exc.message, "type": "value_error.upload"}
        return JSONResponse({"detail": exc.message, "field": field, "errors": [error]}, exc.status)

    @app.exception_handler(NotFound)
    async def not_found(_: Request, exc: NotFound):
        return _error(404, str(exc))

    @app.exception_handler(NotFinished)
    async def not_finished(_: Request, exc: NotFinished):
        return _error(409, str(exc))

    @app.exception_handler(InUse)
    async def in_use(_: Request, exc: InUse):
        return _error(409, str(exc))

    @app.exception_handler(QuotaExceeded)
    async def quota(_: Request, exc: QuotaExceeded):
        return _error(exc.status, str(exc))

    @app.exception_handler(QueueFull)
    async def queue_full(_: Request, exc: QueueFull):
        return _error(429, str(exc), headers={"Retry-After": "30"})

    @app.exception_handler(BrokerUnavailable)
    async def broker_down(_: Request, exc: BrokerUnavailable):
        return _error(
            503,
            "the job queue is unavailable (cannot reach the broker); the job was not queued: try again later",
            headers={"Retry-After": "10"},
        )
