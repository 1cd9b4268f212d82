"""The one Celery task: run an agglomeration job given its id.

Idempotent: a job that is final, or running under a live worker, is left alone; a finished result
for the same result key is reused instead of recomputed. Progress, stage and a heartbeat go to the
job record; cancellation is read back from it.
"""

from __future__ import annotations

import _thread
import logging
import os
import shutil
import signal
import socket
import threading
import time

from celery import shared_task
from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import update

from jobqueue import db as jobdb
from jobqueue.celery_app import TASK_NAME
from jobqueue.db import CANCELLED, FAILED, FINAL, QUEUED, RUNNING, SUCCEEDED, JobRecord, MeshRecord, utcnow
from jobqueue.settings import Settings
from jobqueue.storage import Storage

# Imported here, in the worker's parent process, so that every pool child inherits them: the first
# job after start-up then does not pay for importing numpy, scipy, meshio, pymetis (~0.5 s) and matplotlib (~1 s).
from models import api as _api  # noqa: E402, F401
from models import pipeline as _pipeline  # noqa: E402, F401
from models.partition import metis as _metis  # noqa: E402, F401
from models.quality import plot as _plot  # noqa: E402, F401  (the preview picture: matplotlib)
from models.quality import report as _metrics  # noqa: E402, F401

log = logging.getLogger("magnet.worker")
PROGRESS_EVERY_S = 0.2  # at most one progress write per this many seconds within a stage
PROGRESS_QUIET_S = 0.1  # no progress write in a job's first 0.1 s (a tiny job goes from claim to finish)


def worker_identity() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _local_process_dead(worker: str | None) -> bool:
    """True when `worker` (host:pid) ran on this host and that process no longer exists."""
    if not worker:
        return True
    host, _, pid = worker.rpartition(":")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def claim(db: jobdb.Database, job_id: str, me: str, settings: Settings) -> JobRecord | None:
    """Take the job for this process (status running, attempts + 1), or None when it is not ours
    to run: unknown, final, a follower, or running under a worker that is still alive."""
    with db.session() as s:
        job = s.get(JobRecord, job_id)
        if job is None:
            log.warning(
                "job %s is not in this worker's job store (%s, data dir %s): the API and the workers must "
                "share MAGNET_DATABASE_URL and MAGNET_DATA_DIR; message dropped",
                job_id,
                db.engine.url.render_as_string(hide_password=True),
                settings.data_dir.resolve(),
            )
            return None
        if job.status in FINAL or job.leader_id is not None:
            return None
        if job.status == RUNNING:
            age = (utcnow() - job.heartbeat_at).total_seconds() if job.heartbeat_at else 1e9
            if age < settings.heartbeat_timeout_s and not _local_process_dead(job.worker):
                log.info(
                    "job %s is running under %s (heartbeat %.1fs ago): not taking it", job_id, job.worker, age
                )
                return None
        if job.attempts >= settings.max_attempts:
            jobdb.update_job_and_followers(
                s,
                job_id,
                {
                    "status": FAILED,
                    "finished_at": utcnow(),
                    "stage": "failed",
                    "error": f"worker died {job.attempts} times while running this job",
                },
                only_if={"status": job.status, "attempts": job.attempts},
            )
            s.commit()
            return None
        now = utcnow()
        changed = jobdb.update_job_and_followers(
            s,
            job_id,
            {
                "status": RUNNING,
                "attempts": job.attempts + 1,
                "worker": me,
                "heartbeat_at": now,
                "started_at": job.started_at or now,
                "stage": "starting",
                "progress": 0.0,
            },
            only_if={"status": job.status, "attempts": job.attempts},
        )
        s.commit()
        if not changed:
            return None
        s.expire_all()  # the identity map still holds the row as read before the update
        return s.get(JobRecord, job_id)


# Prompt cancellation: the heartbeat thread, on finding the job no longer running under this
# process (cancelled, or taken over), runs this signal's Python handler in the main thread through
# _thread.interrupt_main (no OS signal is sent), which raises JobCancelled inside the library even
# between its own should_cancel() checks. Celery only uses SIGUSR2 for its remote debugger.
CANCEL_SIGNAL = signal.SIGUSR2


class Heartbeat(threading.Thread):
    """Refreshes heartbeat_at while the job runs, so reapers know this worker is alive; calls
    on_lost() once if the job stops being this worker's running job."""

    def __init__(self, db: jobdb.Database, job_id: str, me: str, interval: float, on_lost=None):
        super().__init__(daemon=True, name=f"heartbeat-{job_id}")
        self.db, self.job_id, self.me, self.interval, self.on_lost = db, job_id, me, interval, on_lost
        self.stopped = threading.Event()

    def run(self) -> None:
        while not self.stopped.wait(self.interval):
            try:
                with self.db.session() as s:
                    mine = s.execute(
                        update(JobRecord)
                        .where(
                            JobRecord.id == self.job_id,
                            JobRecord.worker == self.me,
                            JobRecord.status == RUNNING,
                        )
                        .values(heartbeat_at=utcnow())
                    ).rowcount
                    s.commit()
            except Exception as exc:  # a busy database must not kill the job; retry next beat
                log.warning("heartbeat of job %s failed: %s", self.job_id, exc)
                continue
            if not mine:
                if self.on_lost is not None and not self.stopped.is_set():
                    self.on_lost()
                return


def _as_uploaded(db, job, mesh_path, said: str) -> str:
    """A refusal naming the stored file (its content hash) names the file as its user uploaded it."""
    stored = os.path.basename(str(mesh_path))
    if stored not in said:
        return said
    from jobqueue.db import MeshOwner

    try:
        with db.session() as s:
            owner = s.get(MeshOwner, (job.mesh_id, job.user))
    except Exception:  # (the job's own words stand where the name cannot be looked up)
        return said
    return said.replace(stored, owner.filename) if owner is not None and owner.filename else said


def execute_job(job_id: str, settings: Settings) -> str:
    """Run one job to its end; returns what happened (for logs and tests)."""
    from models import api
    from models.errors import MagnetError

    db = jobdb.for_process(settings.resolved_database_url)
    storage = Storage(settings.data_dir)
    me = worker_identity()
    job = claim(db, job_id, me, settings)
    if job is None:
        return "skipped"
    mine = {"status": RUNNING, "worker": me}

    def finish(values: dict) -> None:
        with db.session() as s:
            jobdb.update_job_and_followers(s, job_id, {"finished_at": utcnow(), **values}, only_if=mine)
            s.commit()

    if storage.has_result(job.result_key):
        finish(
            {
                "status": SUCCEEDED,
                "progress": 1.0,
                "stage": "done",
                "result": storage.read_summary(job.result_key),
            }
        )
        return "reused"

    with db.session() as s:
        mesh = s.get(MeshRecord, job.mesh_id)
    mesh_path = storage.mesh_path(mesh.id, mesh.ext)
    # claim() just wrote "starting" and found the job ours: the first progress write and the first
    # cancellation read wait a while, so a tiny job costs no job-store round-trip between its claim
    # and its finish (7 stage writes cost a tiny job 25-80 ms on a busy machine). After that every new
    # stage is written at once; cancellation is also caught by the heartbeat thread.
    started = time.monotonic()
    last = {"progress": started, "cancel_check": started, "cancelled": False}

    def progress(fraction: float, stage: str) -> None:
        now = time.monotonic()
        if fraction >= 1.0 or now - started < PROGRESS_QUIET_S:
            return  # the end is written by finish(), with the result; a tiny job writes nothing between
        if stage == last.get("stage") and now - last["progress"] < PROGRESS_EVERY_S:
            return  # a new stage is shown at once (the web page and the client follow it), fractions throttled
        last["progress"], last["stage"] = now, stage
        with db.session() as s:
            jobdb.update_job_and_followers(
                s,
                job_id,
                {"progress": max(0.0, min(1.0, float(fraction))), "stage": str(stage)[:64]},
                only_if=mine,
            )
            s.commit()

    def should_cancel() -> bool:
        now = time.monotonic()
        if not last["cancelled"] and now - last["cancel_check"] >= 0.5:
            last["cancel_check"] = now
            with db.session() as s:
                current = s.get(JobRecord, job_id)
                last["cancelled"] = current is None or current.status != RUNNING or current.worker != me
        return last["cancelled"]

    in_library = threading.Event()

    def interrupt(_signum=None, _frame=None):
        if in_library.is_set():
            in_library.clear()
            raise api.JobCancelled("the job was cancelled or taken over")

    prompt = threading.current_thread() is threading.main_thread()
    previous = signal.signal(CANCEL_SIGNAL, interrupt) if prompt else None
    work = storage.work_dir(job_id)
    beat = Heartbeat(
        db,
        job_id,
        me,
        settings.heartbeat_interval_s,
        on_lost=(lambda: _thread.interrupt_main(CANCEL_SIGNAL)) if prompt else None,
    )
    beat.start()
    try:
        log.info("job %s: running %s on %s (attempt %d)", job_id, job.params, mesh.id[:12], job.attempts)
        in_library.set()
        try:
            summary = api.run_job(
                str(mesh_path), str(work), job.params, progress=progress, should_cancel=should_cancel
            )
        finally:
            in_library.clear()
        storage.publish_result(work, job.result_key, summary)
        finish(
            {
                "status": SUCCEEDED,
                "progress": 1.0,
                "stage": "done",
                "result": storage.read_summary(job.result_key),
            }
        )
        return "succeeded"
    except api.JobCancelled:
        log.info("job %s: cancelled", job_id)
        return "cancelled"
    except SoftTimeLimitExceeded:
        finish(
            {
                "status": FAILED,
                "stage": "failed",
                "error": f"the job exceeded the time limit of {settings.task_time_limit_s} s",
            }
        )
        return "failed"
    except MagnetError as exc:
        said = str(exc) or type(exc).__name__
        finish({"status": FAILED, "stage": "failed", "error": _as_uploaded(db, job, mesh_path, said)})
        return "failed"
    except Exception:
        log.exception("job %s: internal error", job_id)
        finish(  # (one sentence of ours: the exception's own text is in the worker's log, not the job's)
            {
                "status": FAILED,
                "stage": "failed",
                "error": f"internal error: this is a bug in magnet, not a fault of your input; the "
                f"server's log has the details under job {job_id}",
            }
        )
        return "failed"
    finally:
        beat.stopped.set()
        if prompt:
            signal.signal(CANCEL_SIGNAL, previous)
        shutil.rmtree(work, ignore_errors=True)


@shared_task(name=TASK_NAME, bind=True)
def run_agglomeration(self, job_id: str) -> str:
    """Celery entry point: the message carries only the job id."""
    settings = getattr(self.app, "magnet_settings", None) or Settings()
    return execute_job(job_id, settings)


__all__ = ["run_agglomeration", "execute_job", "claim", "CANCELLED", "QUEUED"]
