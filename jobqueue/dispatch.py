"""Putting jobs on the queue and keeping followers in line: used by the API (at submission and
cancellation) and by the workers' reaper (re-sending lost messages).

A message carries only the job id and names the task (TASK_NAME); the job record holds the rest.
"""

from __future__ import annotations

import logging

from celery import Celery
from sqlalchemy import update

from jobqueue.celery_app import TASK_NAME
from jobqueue.db import ACTIVE, CANCELLED, FINAL, QUEUED, Database, JobRecord, utcnow

log = logging.getLogger("magnet.jobs")


class BrokerUnavailable(Exception):
    """The broker cannot be reached; nothing was queued."""


def enqueue(celery: Celery, job_id: str, queue: str) -> None:
    """Send the job id to the broker; BrokerUnavailable when it cannot be reached."""
    try:
        celery.send_task(TASK_NAME, args=[job_id], queue=queue)
    except Exception as exc:  # kombu/redis/sqlalchemy connection errors all mean the same here
        log.warning("broker unreachable while enqueuing job %s: %s", job_id, exc)
        raise BrokerUnavailable(str(exc)) from exc


def settle_follower(db: Database, celery: Celery, job_id: str) -> None:
    """Bring a follower in line with its leader once the leader is final (the leader's worker may
    have finished before the follower was committed). A cancelled leader hands over: the follower
    becomes a leader and is queued."""
    with db.session() as s:
        job = s.get(JobRecord, job_id)
        if job is None or job.leader_id is None or job.status in FINAL:
            return
        leader = s.get(JobRecord, job.leader_id)
        if leader is not None and leader.status in ACTIVE:
            return
        if leader is None or leader.status == CANCELLED:
            promoted = s.execute(
                update(JobRecord)
                .where(JobRecord.id == job_id, JobRecord.status.in_(ACTIVE))
                .values(leader_id=None, status=QUEUED, progress=0.0, stage=None, enqueued_at=utcnow())
            ).rowcount
            s.commit()
            if promoted:
                try:
                    enqueue(celery, job_id, job.queue)
                except BrokerUnavailable:
                    pass  # stays queued; a worker's reaper re-sends old queued jobs
            return
        s.execute(
            update(JobRecord)
            .where(JobRecord.id == job_id, JobRecord.status.in_(ACTIVE))
            .values(
                status=leader.status,
                progress=leader.progress,
                stage=leader.stage,
                error=leader.error,
                result=leader.result,
                started_at=leader.started_at,
                finished_at=leader.finished_at,
            )
        )
        s.commit()
