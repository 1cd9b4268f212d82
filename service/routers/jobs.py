"""Jobs: submit (JSON, or in one call with the mesh: multipart or form-urlencoded for Matlab/Octave),
poll, list, cancel, and download results."""

from __future__ import annotations

import base64
import binascii
import json
import re
from pathlib import Path
from typing import get_args, get_origin

from fastapi import APIRouter, Depends, Query, Request, Response, Security
from fastapi import Path as PathParam
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse
from pydantic import BaseModel, ValidationError
from sqlalchemy import delete, func, select
from starlette.concurrency import run_in_threadpool

from jobqueue.db import SUCCEEDED, JobRecord
from models.errors import ParameterError
from models.params import OPTION_NAMES
from service.auth import authenticate, bearer_scheme, current_user
from service.context import Context, get_context
from service.jobs import NotFinished, NotFound, cancel_job, submit_job, visible_job
from service.mesh_check import UploadRejected
from service.openapi import binary, errors
from service.routers.meshes import ERRORS, multipart_file
from service.schemas import JobCreate, JobList, JobOptions, JobOut, JobParams, JobResult, JobStatus
from service.uploads import FORM_HINT, MULTIPART_HINT, receive_mesh, stream_of

router = APIRouter(prefix="/v1", tags=["jobs"])
SUBMIT_ERRORS = errors(401, 413, 422, 429, 503)
JOB_ID = PathParam(description="The job id, as the submission answered it.")


def job_out(job: JobRecord) -> JobOut:
    result = None
    if job.result:
        result = JobResult(
            **{
                k: job.result.get(k) for k in ("elements", "parts_split", "fragments_absorbed", "holes_split")
            },
            timings=job.result.get("timings") or {},
            fill=job.result.get("fill"),
        )
    return JobOut(
        id=job.id,
        status=job.status,
        progress=job.progress or 0.0,
        stage=job.stage,
        created_at=job.created_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
        error=job.error,
        result=result,
        mesh_id=job.mesh_id,
        params=job.params,
        model_version=job.model_version,
        queue=job.queue,
        attempts=job.attempts,
        cached=job.cached_from is not None,
    )


def accepted(job: JobRecord, response: Response) -> JobOut:
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    return job_out(job)


@router.post("/jobs", status_code=202, response_model=JobOut, responses=errors(401, 404, 413, 422, 429, 503))
def create_job(
    body: JobCreate,
    response: Response,
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
) -> JobOut:
    """Queue an agglomeration of an uploaded mesh; parameters are validated now (422 names the field)."""
    params = body.model_dump(exclude_none=True, exclude={"mesh_id"})
    job = submit_job(ctx.db, ctx.storage, ctx.celery, ctx.settings, user, body.mesh_id, params)
    return accepted(job, response)


# --- one-call submission: mesh + job fields in one request --------------------------------------


def _kind_of(model: type[BaseModel], name: str) -> str:
    """The kind of value a wire field takes: int, float, bool, list or str."""
    annotation = model.model_fields[name].annotation
    kinds = [get_origin(a) or a for a in get_args(annotation) if a is not type(None)] or [annotation]
    return next((k.__name__ for k in kinds if k in (int, float, bool, list)), "str")


FORM_FIELDS = {
    "model": {"type": "string"},
    "mode": {"type": "string"},
    "k": {"type": "integer"},
    "nref": {"type": "integer"},
    "target_size": {"type": "number"},
    "mult_factor": {"type": "number"},
    "subset": {"type": "string", "description": "cell ids: JSON list or comma/space separated"},
    "refiner": {"type": "string"},
    "options": {
        "type": "string",
        "description": "JSON object: seed, absorb_fraction, hole_policy, physical_tag, method, boundary_tag, threshold, hierarchy, ratio, coarsest, finest, boxfit",
    },
    "seed": {"type": "integer"},
    "absorb_fraction": {"type": "number"},
    "hole_policy": {"type": "string"},
    "physical_tag": {"type": "string"},
    "method": {"type": "string"},
    "boundary_tag": {"type": "integer"},
    "threshold": {"type": "integer"},
    "hierarchy": {"type": "boolean"},
    "ratio": {
        "type": "number",
        "description": "with hierarchy: nested levels of their own, this coarsening ratio",
    },
    "coarsest": {
        "type": "integer",
        "description": "with ratio: at most this many elements on the coarsest level",
    },
    "finest": {
        "type": "string",
        "description": "with hierarchy: levels of their own, the finest made by aggregation | cuts | quality | nested",
    },
    "boxfit": {
        "type": "boolean",
        "description": "with hierarchy: levels of their own, boundary units moved towards tighter boxes",
    },
}
# every option of the library may come flat (seed=3) beside the JSON text of `options`
OPTION_FIELDS = OPTION_NAMES
JOB_FIELDS = ("model", "mode", "k", "nref", "target_size", "mult_factor", "subset", "refiner", "options")
for _name in OPTION_FIELDS:  # (the flat options not described above: their type, for the OpenAPI form)
    if _name not in FORM_FIELDS:
        _kind = _kind_of(JobOptions, _name)
        FORM_FIELDS[_name] = {
            "type": {"int": "integer", "float": "number", "bool": "boolean"}.get(_kind, "string")
        }
del _name


def _typed(name: str, kind: str, text: str):
    """A form field's text as the JSON value it stands for: "0" -> 0, "true" -> true; text that is
    no such value stays text (the library then says what it expected, as for JSON)."""
    if kind in ("int", "float"):
        for number in (int, float):
            try:
                return number(text)
            except ValueError:
                pass
        return text
    if kind == "bool":
        return {"true": True, "1": True, "yes": True, "on": True, "false": False, "0": False, "no": False,
                "off": False}.get(text.lower(), text)  # fmt: skip
    if kind == "list":
        what = "cell ids" if name == "subset" else "numbers"
        try:
            if text.startswith("["):
                return json.loads(text)
            items = [_typed(name, "float", t) for t in re.split(r"[,\s]+", text) if t]
            return items[0] if len(items) == 1 and name != "subset" else items  # (kappa=50: got 50)
        except ValueError:
            raise _refused(f"{name}: expected a JSON list or comma-separated {what}", name) from None
    return text


def _refused(message: str, field: str) -> ParameterError:
    error = ParameterError(message)
    error.field = field
    return error


def params_from_form(form, transport: tuple[str, ...] = ()) -> dict:
    """Job parameters from form fields (text) -> library params; 422 naming the bad field, in the
    library's words as for JSON (POST /v1/jobs) and the CLI. `transport`: the request's own fields
    (the file, its name, the key); any other field the job does not know is refused."""
    unknown = sorted({n for n in form.keys() if n not in (*JOB_FIELDS, *OPTION_FIELDS, *transport)})
    if unknown:  # (a misspelt seeed=5 would run the job with the default seed)
        raise _refused(f"unknown parameter(s): {', '.join(unknown)}", unknown[0])
    raw: dict = {}
    for name in JOB_FIELDS:
        value = form.get(name)
        if name != "options" and isinstance(value, str) and value.strip() != "":
            raw[name] = _typed(name, _kind_of(JobParams, name), value.strip())
    options: dict = {}
    text = form.get("options")
    if isinstance(text, str) and text.strip():
        try:
            options = json.loads(text)
        except ValueError:
            raise _refused("options: expected a JSON object", "options") from None
        if not isinstance(options, dict):
            raise _refused("options: expected a JSON object", "options")
    for name in OPTION_FIELDS:
        value = form.get(name)
        if isinstance(value, str) and value.strip():
            options[name] = _typed(name, _kind_of(JobOptions, name), value.strip())
    if options:
        raw["options"] = options
    from models import api

    api.validate_params(raw)  # ParameterError: the library's sentence ("k must be >= 1, got 0")
    try:
        return JobParams.model_validate(raw, strict=False).library_params()  # (the wire's own limits)
    except ValidationError as exc:
        raise RequestValidationError(exc.errors(include_url=False)) from None


def form_body(file_field: dict, media: str, extra: dict | None = None) -> dict:
    props = {**file_field, **FORM_FIELDS, **(extra or {})}
    return {
        "requestBody": {
            "required": True,
            "content": {
                media: {"schema": {"type": "object", "required": list(file_field), "properties": props}}
            },
        }
    }


@router.post(
    "/agglomerate",
    status_code=202,
    response_model=JobOut,
    responses=SUBMIT_ERRORS,
    openapi_extra=form_body({"file": {"type": "string", "format": "binary"}}, "multipart/form-data"),
)
async def agglomerate(
    request: Request,
    response: Response,
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
) -> JobOut:
    """One call: multipart mesh file (field `file`) + job fields; answers 202 with the job."""
    if not request.headers.get("content-type", "").startswith("multipart/form-data"):
        raise UploadRejected(422, "send multipart/form-data with the mesh in field 'file' and the job fields")
    form, upload = await multipart_file(request)
    params = params_from_form(form, ("file", "filename"))
    named = form.get("filename")  # (a client that cannot name the part)
    filename = upload.filename or (named if isinstance(named, str) else None)
    mesh = await receive_mesh(ctx, user, stream_of(upload), filename, MULTIPART_HINT)
    job = await run_in_threadpool(
        submit_job, ctx.db, ctx.storage, ctx.celery, ctx.settings, user, mesh.id, params
    )
    return accepted(job, response)


@router.post(
    "/agglomerate/form",
    status_code=202,
    response_model=JobOut,
    responses=SUBMIT_ERRORS,
    openapi_extra=form_body(
        {
            "file_b64": {"type": "string", "description": "the mesh file, base64"},
            "filename": {"type": "string"},
        },
        "application/x-www-form-urlencoded",
        {"token": {"type": "string", "description": "API key (or the header)"}},
    ),
    dependencies=[Security(bearer_scheme)],
)
async def agglomerate_form(
    request: Request, response: Response, ctx: Context = Depends(get_context)
) -> JobOut:
    """For Matlab/Octave webwrite: form-urlencoded fields, the mesh base64-encoded in `file_b64`."""
    if not request.headers.get("content-type", "").startswith("application/x-www-form-urlencoded"):
        raise UploadRejected(
            422, "send application/x-www-form-urlencoded fields file_b64, filename and job fields"
        )
    form = await request.form(
        max_files=0, max_fields=100, max_part_size=ctx.settings.max_upload_bytes * 4 // 3 + 16
    )
    token = form.get("token")
    user = authenticate(request, token if isinstance(token, str) else None)
    data = form.get("file_b64")
    if not isinstance(data, str) or not data:
        raise UploadRejected(422, "file_b64: missing (the mesh file, base64-encoded)")
    try:
        content = base64.b64decode(re.sub(r"\s+", "", data), validate=True)
    except (binascii.Error, ValueError):
        raise UploadRejected(422, "file_b64: not valid base64") from None
    params = params_from_form(form, ("file_b64", "filename", "token"))
    filename = form.get("filename")

    async def one_chunk():
        yield content

    mesh = await receive_mesh(
        ctx, user, one_chunk(), filename if isinstance(filename, str) else None, FORM_HINT
    )
    job = await run_in_threadpool(
        submit_job, ctx.db, ctx.storage, ctx.celery, ctx.settings, user, mesh.id, params
    )
    return accepted(job, response)


# --- polling, listing, cancelling ----------------------------------------------------------------


@router.get("/jobs", response_model=JobList, responses=errors(401, 422))
def list_jobs(
    limit: int = Query(50, ge=1, le=500, description="Jobs per page."),
    offset: int = Query(0, ge=0, le=10**9, description="Jobs to skip (newest first)."),
    status: JobStatus | None = Query(None, description="Only jobs in this state."),
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
) -> JobList:
    """Your jobs, newest first."""
    where = [JobRecord.user == user] + ([JobRecord.status == status] if status else [])
    with ctx.db.session() as s:
        total = s.scalar(select(func.count()).select_from(JobRecord).where(*where))
        rows = s.scalars(
            select(JobRecord)
            .where(*where)
            .order_by(JobRecord.created_at.desc(), JobRecord.id)
            .limit(limit)
            .offset(offset)
        ).all()
    return JobList(items=[job_out(j) for j in rows], total=total, limit=limit, offset=offset)


@router.get("/jobs/{job_id}", response_model=JobOut, responses=ERRORS)
def get_job(
    job_id: str = JOB_ID, user: str = Depends(current_user), ctx: Context = Depends(get_context)
) -> JobOut:
    """Status, progress, stage, timestamps, error or result summary."""
    with ctx.db.session() as s:
        return job_out(visible_job(s, user, job_id))


@router.delete(
    "/jobs/{job_id}",
    response_model=JobOut,
    responses={**errors(401, 404, 409, 422), 204: {"description": "purged: the job is gone from your list"}},
)
def delete_job(
    job_id: str = JOB_ID,
    purge: bool = Query(
        False,
        description="also remove the job from your list, finished or not (a running one is cancelled "
        "first); its result files stay while another job refers to them",
    ),
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
):
    """Cancel a queued or running job (its worker stops it); 409 if it already ended, unless `purge`."""
    with ctx.db.session() as s:
        job = visible_job(s, user, job_id)
    if purge:
        if job.status in ("queued", "running"):
            cancel_job(ctx.db, ctx.celery, user, job_id)
        with ctx.db.session() as s:
            s.execute(delete(JobRecord).where(JobRecord.id == job_id, JobRecord.user == user))
            s.commit()
        return Response(status_code=204)
    if job.status not in ("queued", "running"):
        raise NotFinished(f"job already ended: {job.status} (DELETE with ?purge=true removes it)")
    return job_out(cancel_job(ctx.db, ctx.celery, user, job_id))


# --- results --------------------------------------------------------------------------------------


def result_file(ctx: Context, user: str, job_id: str, filename: str) -> Path:
    with ctx.db.session() as s:
        job = visible_job(s, user, job_id)
    if job.status != SUCCEEDED:
        why = f": {job.error}" if job.error else ""
        raise NotFinished(f"job is {job.status}{why}; results exist once it succeeded")
    path = ctx.storage.result_dir(job.result_key) / filename
    if not path.exists():
        raise NotFound(
            f"job {job_id} has no {filename}"
            + (" (lymph output is for 2D meshes only)" if filename.startswith("lymph") else "")
            + (" (submit it with options.hierarchy = true)" if filename == "hierarchy.zip" else "")
        )
    return path


def _download(name: str, media: str, doc: str):
    def endpoint(
        job_id: str = JOB_ID, user: str = Depends(current_user), ctx: Context = Depends(get_context)
    ):
        return FileResponse(
            result_file(ctx, user, job_id, name), media_type=media, filename=f"{job_id}-{name}"
        )

    endpoint.__doc__ = doc
    return endpoint


RESULT_ERRORS = errors(401, 404, 409)
# the result files of a finished job: (path, stored file, media type, description, route name)
for _path, _file, _media, _doc, _name in (
    ("mesh", "mesh.vtu", "application/octet-stream", "The agglomerated mesh (VTU).", "job_mesh"),
    (
        "metrics",
        "metrics.json",
        "application/json",
        "Quality metrics of the agglomerated mesh (JSON).",
        "job_metrics",
    ),
    (
        "labels",
        "labels.json",
        "application/json",
        "Element label of every fine cell (JSON list).",
        "job_labels",
    ),
    ("preview.png", "preview.png", "image/png", "A picture of the agglomerated mesh.", "job_preview"),
    (
        "hierarchy",
        "hierarchy.zip",
        "application/zip",
        "Every nested level (zip: hierarchy.json, level_L.vtu/.labels.json/.parent.json/.metrics.json, 2D "
        "level_L.lymph.json) of a job run with options.hierarchy = true.",
        "job_hierarchy",
    ),
):
    router.add_api_route(
        f"/jobs/{{job_id}}/{_path}",
        _download(_file, _media, _doc),
        methods=["GET"],
        responses={**RESULT_ERRORS, **binary(_media, _doc)},
        response_class=FileResponse,
        name=_name,
    )


@router.get(
    "/jobs/{job_id}/lymph",
    responses={
        **errors(401, 404, 409, 422),
        200: {
            "description": "lymph structs: JSON, or a MATLAB .mat file.",
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "application/x-matlab-data": {"schema": {"type": "string", "format": "binary"}},
            },
        },
    },
    response_class=FileResponse,
)
def job_lymph(
    request: Request,
    job_id: str = JOB_ID,
    format: str | None = Query(
        None,
        pattern="^(json|mat)$",
        description="json (default) or mat; or send Accept: application/x-matlab-data",
    ),
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
):
    """lymph `region`/`neighbor` structs (2D): JSON, or a .mat file with `?format=mat` or
    `Accept: application/x-matlab-data`."""
    mat = format == "mat" or (
        format is None and "application/x-matlab-data" in request.headers.get("accept", "")
    )
    if mat:
        return FileResponse(
            result_file(ctx, user, job_id, "lymph.mat"),
            media_type="application/x-matlab-data",
            filename=f"{job_id}-lymph.mat",
        )
    return FileResponse(
        result_file(ctx, user, job_id, "lymph.json"),
        media_type="application/json",
        filename=f"{job_id}-lymph.json",
    )
