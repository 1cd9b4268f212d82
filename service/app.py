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
from models.errors import MagnetError, ParameterError
from service.auth import load_keys
from service.context import Context
from service.error_envelope import ErrorsInBody
from service.jobs import InUse, NotFinished, NotFound, QueueFull, QuotaExceeded
from service.limits import BodySizeLimit
from service.mesh_check import UploadRejected
from service.openapi import install as install_openapi
from service.routers import events, health, jobs, meshes, metrics, models, web
from service.wording import json_value, json_values

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
        file_limit=settings.max_upload_bytes,
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


def _said(name: str, error: dict) -> str:
    """One wire-format (pydantic) error in the library's words ('k must be an integer, got "8"'; the
    bound of a range from the error's ctx: "k must be >= 1, got 0")."""
    kind, got, ctx = str(error.get("type", "")), error.get("input"), error.get("ctx") or {}
    shown = json_value(got)  # (as the request wrote it: true, "8")
    if kind.startswith("int_"):
        return f"{name} must be an integer, got {shown}"
    if kind.startswith("float_") or kind == "finite_number":
        return f"{name} must be a finite number, got {shown}"
    if kind.startswith("bool_"):
        return f"{name} must be true or false, got {shown}"
    if kind.startswith("string_type"):
        return f"{name} must be a string, got {shown}"
    if kind == "string_too_long":
        return f"{name} is too long: at most {ctx.get('max_length')} characters"
    if kind == "string_too_short":
        return f"{name} must not be empty"
    bounds = {"greater_than_equal": ">=", "greater_than": ">", "less_than_equal": "<=", "less_than": "<"}
    if kind in bounds:
        limit = next((v for k, v in ctx.items() if k in ("ge", "gt", "le", "lt")), "")
        return f"{name} must be {bounds[kind]} {limit}, got {shown}"
    if kind == "extra_forbidden":
        return f"unknown parameter {name}"
    if kind == "missing":
        return f"{name} is required"
    if kind in ("list_type", "tuple_type"):
        return f"{name} must be a list, got {shown}"
    if kind in ("dict_type", "model_type", "model_attributes_type"):
        return f"{name} must be an object, got {shown}"
    if kind == "json_invalid":
        return "the request body is not valid JSON"
    if kind == "literal_error":
        return f"{name} must be one of {ctx.get('expected', '')}, got {shown}"
    return f"{name} is not valid here, got {shown}"


def _library_sentence(request: Request, exc: RequestValidationError):
    """The library's ParameterError for a job's JSON parameters that the wire format refused (a
    string where a number goes, true for k, an unknown field), or None (other requests, or the
    library accepts them: the wire format's own words then)."""
    body = getattr(exc, "body", None)
    if request.method != "POST" or not request.url.path.endswith("/jobs") or not isinstance(body, dict):
        return None
    from models import api

    try:
        api.validate_params({k: v for k, v in body.items() if k != "mesh_id"})
    except ParameterError as said:
        return said
    except Exception:  # noqa: BLE001  (anything else: the wire format's words)
        return None
    return None


def _as_requested(text: str, field: str | None) -> str:
    """A ParameterError's sentence as the request names things: the field by its path (Python's
    keyword seed is options.seed here) and the values it echoes as JSON (true, "8")."""
    text = json_values(text)
    if field and "." in field and text.startswith(field.rsplit(".", 1)[1] + " "):
        text = f"{field.rsplit('.', 1)[0]}.{text}"
    return text


def _error_handlers(app: FastAPI) -> None:
    """Each failure kind mapped once to its HTTP status."""

    @app.exception_handler(MagnetError)
    async def library_error(_: Request, exc: MagnetError):  # MeshError, ParameterError, ModelError
        text, field = str(exc) or type(exc).__name__, getattr(exc, "field", None)
        if isinstance(exc, ParameterError):
            text = _as_requested(text, field)
        return _error(422, text, field)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError):
        said = _library_sentence(request, exc)
        if said is not None:  # a job's parameters: refused in the library's words, as the CLI and Python
            loc = [str(p) for p in (exc.errors() or [{}])[0].get("loc", ()) if isinstance(p, str)][1:]
            field = getattr(said, "field", None) or (".".join(loc) or None)
            return _error(422, _as_requested(str(said), field), field)
        # FastAPI's own handler echoes the input, which fails on NaN/Infinity (a 500): say where instead
        raw = list(exc.errors())
        errors = [
            {
                "loc": [p if isinstance(p, int) else str(p) for p in e.get("loc", ())],
                "msg": str(e.get("msg", "")),
                "type": str(e.get("type", "")),
            }
            for e in raw
        ]
        names = [
            ".".join(p for p in e["loc"][1:] if isinstance(p, str)) or (e["loc"] or ["request"])[0]
            for e in errors
        ]
        for e, n, r in zip(errors, names, raw, strict=True):  # in our words, not the wire format's
            e["msg"] = _said(n, r)
        detail = "; ".join(e["msg"] for e in errors) or "invalid request"
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
