"""GET /metrics in the Prometheus text format (0.0.4), read from the job store: jobs by state and
queue, queue lengths, live workers, and per-model histograms of job run time. No API key: the
numbers are aggregates (no ids, no user names); scrape it from the host's network."""

from __future__ import annotations

from collections import defaultdict
from datetime import timedelta

from fastapi import APIRouter, Depends
from fastapi.responses import PlainTextResponse
from sqlalchemy import func, select

from jobqueue.db import FAILED, QUEUED, RUNNING, SUCCEEDED, JobRecord, WorkerRecord, utcnow
from service.context import Context, get_context

router = APIRouter(tags=["health"])
STATES = ("queued", "running", "succeeded", "failed", "cancelled")
BUCKETS = (0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600, 1800, 3600)
MEDIA = "text/plain; version=0.0.4; charset=utf-8"


def _label(value: str) -> str:
    return str(value).replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def render(ctx: Context) -> str:
    """The metrics page."""
    lines: list[str] = []

    def family(name: str, kind: str, doc: str) -> None:
        lines.extend([f"# HELP {name} {doc}", f"# TYPE {name} {kind}"])

    with ctx.db.session() as s:
        by_state = s.execute(
            select(JobRecord.status, JobRecord.queue, func.count()).group_by(
                JobRecord.status, JobRecord.queue
            )
        ).all()
        waiting = s.execute(
            select(JobRecord.queue, func.count())
            .where(JobRecord.status == QUEUED, JobRecord.leader_id.is_(None))
            .group_by(JobRecord.queue)
        ).all()
        cutoff = utcnow() - timedelta(seconds=max(3 * ctx.settings.reaper_interval_s, 15))
        workers = s.scalar(
            select(func.count()).select_from(WorkerRecord).where(WorkerRecord.last_seen >= cutoff)
        )
        runs = s.execute(
            select(JobRecord.params, JobRecord.started_at, JobRecord.finished_at).where(
                JobRecord.status.in_((SUCCEEDED, FAILED)),
                JobRecord.leader_id.is_(None),
                JobRecord.cached_from.is_(None),
                JobRecord.started_at.is_not(None),
                JobRecord.finished_at.is_not(None),
            )
        ).all()
    counts = {(state, queue): 0 for state in STATES for queue in ("cpu", "gpu")}
    counts.update({(state, queue): n for state, queue, n in by_state})
    family("magnet_jobs", "gauge", "Jobs in the job store, by state and queue.")
    lines += [f'magnet_jobs{{state="{st}",queue="{_label(q)}"}} {n}' for (st, q), n in sorted(counts.items())]
    queue_len = {"cpu": 0, "gpu": 0} | {q: n for q, n in waiting}
    family("magnet_queue_length", "gauge", "Jobs waiting for a worker, per queue.")
    lines += [f'magnet_queue_length{{queue="{_label(q)}"}} {n}' for q, n in sorted(queue_len.items())]
    family("magnet_running_jobs", "gauge", "Jobs running now.")
    lines.append(f"magnet_running_jobs {sum(n for (st, _), n in counts.items() if st == RUNNING)}")
    family("magnet_workers", "gauge", "Workers alive (their reaper reported within the last few seconds).")
    lines.append(f"magnet_workers {workers or 0}")
    durations: dict[str, list[float]] = defaultdict(list)
    for params, started, finished in runs:
        model = (params or {}).get("model") or "unknown"
        durations[model].append(max(0.0, (finished - started).total_seconds()))
    family("magnet_job_duration_seconds", "histogram", "Run time of finished jobs (start to end), per model.")
    for model, values in sorted(durations.items()):
        m = _label(model)
        for le in BUCKETS:
            lines.append(
                f'magnet_job_duration_seconds_bucket{{model="{m}",le="{le}"}} {sum(v <= le for v in values)}'
            )
        lines.append(f'magnet_job_duration_seconds_bucket{{model="{m}",le="+Inf"}} {len(values)}')
        lines.append(f'magnet_job_duration_seconds_sum{{model="{m}"}} {sum(values):.6f}')
        lines.append(f'magnet_job_duration_seconds_count{{model="{m}"}} {len(values)}')
    return "\n".join(lines) + "\n"


@router.get(
    "/metrics",
    response_class=PlainTextResponse,
    responses={
        200: {"description": "Prometheus text format.", "content": {MEDIA: {"schema": {"type": "string"}}}}
    },
)
def metrics(ctx: Context = Depends(get_context)) -> PlainTextResponse:
    """Prometheus metrics: magnet_jobs, magnet_queue_length, magnet_running_jobs, magnet_workers,
    magnet_job_duration_seconds (histogram per model)."""
    return PlainTextResponse(render(ctx), media_type=MEDIA)
