"""Keeping jobs alive across dying workers and a forgetful broker.

Every worker's main process runs a Reaper thread that, each few seconds:
- records the worker as alive (the `workers` table; /readyz reads it);
- re-queues running jobs whose heartbeat went silent (their worker died), or fails them with
  "worker died N times while running this job" after MAGNET_MAX_ATTEMPTS attempts;
- re-sends queued jobs that waited longer than MAGNET_REQUEUE_AFTER_S (their message may have been
  lost); duplicates are harmless, the task is idempotent;
- re-sends every queued job at once when the broker restarted (Redis: its run_id changed), since a
  Redis without persistence comes back empty;
- settles followers whose leader finished;
- every MAGNET_CLEANUP_INTERVAL_S, cleans up storage (jobqueue.cleanup: retention policy,
  unreferenced results and meshes, abandoned temp folders).
Several workers may reap at once: every change is a conditional UPDATE, only one wins.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from datetime import timedelta

from celery import signals
from sqlalchemy import delete, select, update

from jobqueue import db as jobdb
from jobqueue.cleanup import clean_up
from jobqueue.db import ACTIVE, FAILED, FINAL, QUEUED, RUNNING, JobRecord, WorkerRecord, utcnow
from jobqueue.dispatch import BrokerUnavailable, enqueue, settle_follower
from jobqueue.settings import Settings
from jobqueue.storage import Storage

log = logging.getLogger("magnet.reaper")


def reap_once(db: jobdb.Database, celery, settings: Settings, resend_all: bool = False) -> dict[str, int]:
    """One pass over the job table; returns counts of what it did. resend_all: re-send every queued
    job now, not only those older than MAGNET_REQUEUE_AFTER_S (the broker lost its messages)."""
    now = utcnow()
    done = {"requeued": 0, "failed": 0, "resent": 0, "settled": 0}
    stale_cut = now - timedelta(seconds=settings.heartbeat_timeout_s)
    with db.session() as s:
        stale = s.scalars(
            select(JobRecord).where(
                JobRecord.status == RUNNING, JobRecord.leader_id.is_(None), JobRecord.heartbeat_at < stale_cut
            )
        ).all()
    for job in stale:
        same = {"status": RUNNING, "worker": job.worker, "attempts": job.attempts}
        with db.session() as s:
            if job.attempts >= settings.max_attempts:
                n = jobdb.update_job_and_followers(
                    s,
                    job.id,
                    {
                        "status": FAILED,
                        "finished_at": now,
                        "stage": "failed",
                        "error": f"worker died {job.attempts} times while running this job",
                    },
                    only_if=same,
                )
                s.commit()
                done["failed"] += n
                continue
            n = jobdb.update_job_and_followers(
                s,
                job.id,
                {"status": QUEUED, "worker": None, "stage": "requeued", "progress": 0.0, "enqueued_at": now},
                only_if=same,
            )
            s.commit()
        if n:
            log.warning(
                "job %s: worker %s went silent; re-queued (attempt %d done)", job.id, job.worker, job.attempts
            )
            done["requeued"] += 1
            _send(celery, job)
    resend_cut = (
        now + timedelta(seconds=1) if resend_all else now - timedelta(seconds=settings.requeue_after_s)
    )
    with db.session() as s:
        waiting = s.scalars(
            select(JobRecord).where(
                JobRecord.status == QUEUED, JobRecord.leader_id.is_(None), JobRecord.enqueued_at < resend_cut
            )
        ).all()
        for job in waiting:
            n = s.execute(
                update(JobRecord)
                .where(
                    JobRecord.id == job.id,
                    JobRecord.status == QUEUED,
                    JobRecord.enqueued_at == job.enqueued_at,
                )
                .values(enqueued_at=now)
            ).rowcount
            s.commit()
            if n:
                done["resent"] += 1
                _send(celery, job)
        orphans = s.scalars(
            select(JobRecord.id).where(JobRecord.leader_id.is_not(None), JobRecord.status.in_(ACTIVE))
        ).all()
    for job_id in orphans:
        with db.session() as s:
            job = s.get(JobRecord, job_id)
            leader = s.get(JobRecord, job.leader_id) if job and job.leader_id else None
        if leader is None or leader.status in FINAL:
            settle_follower(db, celery, job_id)
            done["settled"] += 1
    return done


def _send(celery, job: JobRecord) -> None:
    try:
        enqueue(celery, job.id, job.queue)
    except BrokerUnavailable:
        pass  # still queued in the database; the next pass re-sends it


def broker_epoch(celery, settings: Settings) -> str | None:
    """An id that changes whenever the broker restarts (Redis run_id); None for the embedded broker
    or while the broker is unreachable."""
    if settings.embedded_broker:
        return None
    try:
        with celery.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, interval_start=0, timeout=3)
            client = getattr(conn.default_channel, "client", None)
            run_id = client.info("server").get("run_id") if client is not None else None
        return str(run_id) if run_id else None
    except Exception:
        return None


def heartbeat_worker(db: jobdb.Database, name: str, queues: str) -> None:
    now = utcnow()
    with db.session() as s:
        record = s.get(WorkerRecord, name)
        if record is None:
            s.add(WorkerRecord(name=name, queues=queues, started_at=now, last_seen=now))
        else:
            record.last_seen = now
        s.execute(delete(WorkerRecord).where(WorkerRecord.last_seen < now - timedelta(days=1)))
        s.commit()


class Reaper(threading.Thread):
    def __init__(self, celery, settings: Settings, name: str, queues: str):
        super().__init__(daemon=True, name="magnet-reaper")
        self.celery, self.settings, self.worker_name, self.queues = celery, settings, name, queues
        self.stopped = threading.Event()

    def run(self) -> None:
        db = jobdb.for_process(self.settings.resolved_database_url)
        epoch, last_cleanup = None, None
        while True:
            try:
                heartbeat_worker(db, self.worker_name, self.queues)
                now_epoch = broker_epoch(self.celery, self.settings)
                restarted = bool(epoch and now_epoch and now_epoch != epoch)
                if restarted:
                    log.warning(
                        "reaper: the broker restarted (it may have lost its messages): re-sending queued jobs"
                    )
                epoch = now_epoch or epoch
                counts = reap_once(db, self.celery, self.settings, resend_all=restarted)
                if (
                    last_cleanup is None
                    or time.monotonic() - last_cleanup >= self.settings.cleanup_interval_s
                ):
                    last_cleanup = time.monotonic()
                    removed = clean_up(db, Storage(self.settings.data_dir), self.settings)
                    if any(removed.values()):
                        log.info("cleanup: removed %s", removed)
                if any(counts.values()):
                    log.info("reaper: %s", counts)
            except Exception as exc:  # never let the reaper die: the database may be briefly away
                log.warning("reaper pass failed: %s", exc)
            if self.stopped.wait(self.settings.reaper_interval_s):
                break
        try:
            with db.session() as s:
                s.execute(delete(WorkerRecord).where(WorkerRecord.name == self.worker_name))
                s.commit()
        except Exception:
            pass


_reaper: Reaper | None = None


@signals.worker_init.connect
def _prepare(sender=None, **_):
    settings = getattr(sender.app, "magnet_settings", None) or Settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)


@signals.worker_ready.connect
def _start_reaper(sender=None, **_):
    global _reaper
    app = sender.app
    settings = getattr(app, "magnet_settings", None) or Settings()
    queues = ",".join(sorted(app.amqp.queues.consume_from or app.amqp.queues))
    _reaper = Reaper(app, settings, f"{sender.hostname}:{os.getpid()}", queues)
    _reaper.start()


@signals.worker_shutdown.connect
def _stop_reaper(**_):
    if _reaper is not None:
        _reaper.stopped.set()
        _reaper.join(timeout=5)
