"""Server-sent events of one job: its status, stage and progress each time they change, and its
final record, then the stream ends. Same bearer auth as the other job routes (the web page reads
the stream with fetch(), which can send the header; EventSource cannot).

Wire format (text/event-stream), every `data:` the job as GET /v1/jobs/{id} answers it:

    event: progress        while queued or running (one per change of status, stage or progress)
    event: end             once, when the job is succeeded, failed or cancelled; the stream closes
    event: gone            the job was deleted while being followed; the stream closes

A comment line (`: keep-alive`) goes out every 15 s of silence; a stream is closed after
MAX_STREAM_S and the client reconnects (the first event repeats the current state).
"""

from __future__ import annotations

import asyncio
import json
import time

from fastapi import APIRouter, Depends, Request
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from jobqueue.db import FINAL
from service.auth import current_user
from service.context import Context, get_context
from service.jobs import NotFound, visible_job
from service.routers.jobs import JOB_ID, job_out
from service.schemas import ErrorOut

router = APIRouter(prefix="/v1", tags=["jobs"])

POLL_S = 0.25
KEEPALIVE_S = 15.0
MAX_STREAM_S = 600.0


def snapshot(ctx: Context, user: str, job_id: str) -> dict:
    """The job as GET /v1/jobs/{id} answers it (NotFound when unknown or another user's)."""
    with ctx.db.session() as s:
        return job_out(visible_job(s, user, job_id)).model_dump(mode="json")


def sse(event: str, data: dict, event_id: int) -> bytes:
    return f"id: {event_id}\nevent: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


async def job_stream(request: Request, ctx: Context, user: str, job_id: str, first: dict):
    """Yield an event per change of (status, stage, progress) until the job is final."""
    job, seen, n = first, None, 0
    started = last_sent = time.monotonic()
    yield b"retry: 2000\n\n"
    while True:
        key = (job["status"], job["stage"], job["progress"])
        if key != seen:
            seen, n, last_sent = key, n + 1, time.monotonic()
            final = job["status"] in FINAL
            yield sse("end" if final else "progress", job, n)
            if final:
                return
        elif time.monotonic() - last_sent >= KEEPALIVE_S:
            last_sent = time.monotonic()
            yield b": keep-alive\n\n"
        if time.monotonic() - started > MAX_STREAM_S or await request.is_disconnected():
            return
        await asyncio.sleep(POLL_S)
        try:
            job = await run_in_threadpool(snapshot, ctx, user, job_id)
        except NotFound:
            yield sse("gone", {"id": job_id, "detail": f"job {job_id} no longer exists"}, n + 1)
            return


@router.get(
    "/jobs/{job_id}/events",
    response_class=StreamingResponse,
    responses={
        401: {"model": ErrorOut, "description": "missing or invalid API key"},
        404: {"model": ErrorOut, "description": "no such job (or another user's)"},
        200: {
            "description": "An event stream: `progress` events (the job record) while it runs, one `end` "
            "event with the final record, then the stream closes.",
            "content": {"text/event-stream": {"schema": {"type": "string"}}},
        },
    },
)
async def job_events(
    request: Request,
    job_id: str = JOB_ID,
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
):
    """Follow a job live (server-sent events): status, stage and progress as they change."""
    first = await run_in_threadpool(snapshot, ctx, user, job_id)  # 404 before the stream starts
    return StreamingResponse(
        job_stream(request, ctx, user, job_id, first),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
