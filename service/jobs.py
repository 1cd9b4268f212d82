"""Job life cycle as the API sees it: submit (with dedup), cancel, look up (enqueueing and
followers: jobqueue.dispatch, shared with the workers).

Dedup: a request gets its own job id, always. If an identical job (same mesh, same normalized
parameters, same MODEL_VERSION: same result_key) already succeeded, the new job is born succeeded
and points at that result; if one is in flight, the new job follows it (leader_id) and finishes
with it. Nothing is computed twice.

No FastAPI here: failures are the exceptions below, mapped to HTTP codes in service.app.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re

from celery import Celery
from sqlalchemy import delete, func, select, update
from sqlalchemy.orm import Session

from jobqueue.db import (
    ACTIVE,
    CANCELLED,
    FINAL,
    QUEUED,
    SUCCEEDED,
    Database,
    JobRecord,
    MeshOwner,
    MeshRecord,
    lock_user,
    new_id,
    utcnow,
)
from jobqueue.dispatch import BrokerUnavailable, enqueue, settle_follower
from jobqueue.settings import Settings
from jobqueue.storage import Storage

log = logging.getLogger("magnet.jobs")
ID = re.compile(r"[0-9a-f]{1,64}")  # mesh ids are sha256 hex, job ids uuid4 hex
NEURAL_MODEL_PREFIX = "sage"


class NotFound(Exception):
    """Unknown id, or an id of another user."""


class QueueFull(Exception):
    """The user has too many queued/running jobs."""


class NotFinished(Exception):
    """The job has no results (yet)."""


class InUse(Exception):
    """The resource is used by a queued or running job (409)."""


class QuotaExceeded(Exception):
    """The user's storage quota is used up; `status` 413 (an upload) or 429 (a submission)."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def storage_used(db: Database, storage: Storage, user: str) -> int:
    """Bytes charged to `user`: the meshes they own and the results of their succeeded jobs."""
    with db.session() as s:
        meshes = s.scalar(
            select(func.coalesce(func.sum(MeshRecord.size), 0))
            .select_from(MeshOwner)
            .join(MeshRecord, MeshRecord.id == MeshOwner.mesh_id)
            .where(MeshOwner.user == user)
        )
        keys = s.scalars(
            select(JobRecord.result_key)
            .where(JobRecord.user == user, JobRecord.status == SUCCEEDED)
            .distinct()
        ).all()
    return int(meshes or 0) + sum(storage.result_bytes(k) for k in keys)


def check_quota(
    db: Database, storage: Storage, settings: Settings, user: str, adding: int, status: int
) -> None:
    """QuotaExceeded when `adding` more bytes would take `user` over MAGNET_MAX_STORAGE_BYTES_PER_USER."""
    quota = settings.max_storage_bytes_per_user
    if not quota:
        return
    used = storage_used(db, storage, user)
    if used + adding > quota or (adding == 0 and used >= quota):
        mb = 1024 * 1024
        raise QuotaExceeded(
            status,
            f"storage quota exceeded: you hold {used / mb:.1f} MB of your {quota / mb:.1f} MB"
            + (f" and this upload needs {adding / mb:.1f} MB" if adding else "")
            + "; delete meshes (DELETE /v1/meshes/{id}) or jobs (DELETE /v1/jobs/{id}?purge=true) to free space",
        )


def delete_mesh(db: Database, storage: Storage, user: str, mesh_id: str) -> None:
    """Forget `user`'s upload of a mesh; InUse (409) while one of their jobs on it is queued or running.
    The file goes once nobody owns the mesh and no job uses it (else the cleanup removes it later)."""
    with db.session() as s:
        _, owner = visible_mesh(s, user, mesh_id)
        active = s.scalar(
            select(func.count())
            .select_from(JobRecord)
            .where(JobRecord.mesh_id == mesh_id, JobRecord.user == user, JobRecord.status.in_(ACTIVE))
        )
        if active:
            raise InUse(
                f"mesh {mesh_id[:12]}... is used by {active} queued or running job(s) of yours: "
                "cancel them (DELETE /v1/jobs/{id}) or wait for them to finish"
            )
        s.delete(owner)
        s.commit()
        others = s.scalar(select(func.count()).select_from(MeshOwner).where(MeshOwner.mesh_id == mesh_id))
        busy = s.scalar(
            select(func.count())
            .select_from(JobRecord)
            .where(JobRecord.mesh_id == mesh_id, JobRecord.status.in_(ACTIVE))
        )
        if others or busy:
            return
        mesh = s.get(MeshRecord, mesh_id)
        if mesh is not None:
            s.delete(mesh)
            s.commit()
            storage.mesh_path(mesh_id, mesh.ext).unlink(missing_ok=True)


def result_key(mesh_id: str, params: dict, model_version: str) -> str:
    blob = json.dumps({"mesh": mesh_id, "params": params, "version": model_version}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def queue_for(params: dict, settings: Settings) -> str:
    """Neural models go to the 'gpu' queue when a GPU worker is configured; all else to 'cpu'."""
    neural = str(params.get("model", "")).startswith(NEURAL_MODEL_PREFIX)
    return "gpu" if neural and settings.gpu_queue else "cpu"


def visible_mesh(session: Session, user: str, mesh_id: str) -> tuple[MeshRecord, MeshOwner]:
    if not ID.fullmatch(mesh_id):  # e.g. a NUL byte, which PostgreSQL text cannot even compare
        raise NotFound(f"no mesh {mesh_id!r}")
    owner = session.get(MeshOwner, (mesh_id, user))
    mesh = session.get(MeshRecord, mesh_id) if owner else None
    if mesh is None:
        raise NotFound(f"no mesh {mesh_id!r}")
    return mesh, owner


def visible_job(session: Session, user: str, job_id: str) -> JobRecord:
    job = session.get(JobRecord, job_id) if ID.fullmatch(job_id) else None
    if job is None or job.user != user:
        raise NotFound(f"no job {job_id!r}")
    return job


def groups_under_tag(db: Database, storage: Storage, settings: Settings, mesh: MeshRecord, tag: str) -> dict:
    """The mesh summary with the physical groups of cell-data array `tag` (read once in the limited
    child process, then kept in the mesh record); ParameterError naming options.physical_tag when the
    mesh has no such array."""
    from models.errors import ParameterError
    from service.mesh_check import UploadRejected, inspect_upload

    known = (mesh.info.get("groups_by_tag") or {}).get(tag)
    if known is None:
        try:
            found = inspect_upload(
                storage.mesh_path(mesh.id, mesh.ext),
                mesh.ext,
                settings.max_cells,
                settings.parse_memory_bytes,
                settings.parse_timeout_s,
                physical_tag=tag,
            )
        except UploadRejected as exc:
            error = ParameterError(f"options.physical_tag: {exc.message}")
            error.field = "options.physical_tag"
            raise error from None
        known = found.get("physical_groups", [])
        with db.session() as s:
            record = s.get(MeshRecord, mesh.id)
            if record is not None:
                by_tag = dict(record.info.get("groups_by_tag") or {})
                by_tag[tag] = known
                record.info = {**record.info, "groups_by_tag": by_tag}
                s.commit()
    return {**mesh.info, "physical_groups": known}


def submit_job(
    db: Database,
    storage: Storage,
    celery: Celery,
    settings: Settings,
    user: str,
    mesh_id: str,
    params_in: dict,
) -> JobRecord:
    """Validate, dedup and queue one job of `user`. Raises NotFound, ParameterError, QueueFull,
    BrokerUnavailable (the job record is then removed: the caller never got its id).

    Dedup never tells one user about another's work: only the user's own earlier job makes a new
    one `cached`; another user's finished result is reused by the worker (the job goes through the
    queue like any other), another user's job in flight is followed without saying so."""
    from models import api

    with db.session() as s:
        mesh, _ = visible_mesh(s, user, mesh_id)
    opts = params_in.get("options") if isinstance(params_in, dict) else None
    tag = opts.get("physical_tag") if isinstance(opts, dict) else None
    info = (
        mesh.info
        if not isinstance(tag, str) or not tag
        else groups_under_tag(db, storage, settings, mesh, tag)
    )
    params = api.validate_params(params_in, info)
    key = result_key(mesh.id, params, api.MODEL_VERSION)
    now = utcnow()
    with db.session() as s:
        lock_user(s, user)  # (the count and the insert below: one step, whoever submits in parallel)
        active = s.scalar(
            select(func.count())
            .select_from(JobRecord)
            .where(JobRecord.user == user, JobRecord.status.in_(ACTIVE))
        )
        check_quota(db, storage, settings, user, 0, 429)
        if active >= settings.max_queued_jobs_per_user:
            raise QueueFull(
                f"you have {active} queued or running jobs; the limit is "
                f"{settings.max_queued_jobs_per_user}: wait for some to finish"
            )
        job = JobRecord(
            id=new_id(),
            user=user,
            mesh_id=mesh.id,
            params=params,
            result_key=key,
            model_version=api.MODEL_VERSION,
            queue=queue_for(params, settings),
            status=QUEUED,
            progress=0.0,
            attempts=0,
            created_at=now,
        )
        done = s.scalars(
            select(JobRecord)
            .where(JobRecord.result_key == key, JobRecord.status == SUCCEEDED, JobRecord.user == user)
            .order_by(JobRecord.finished_at.desc())
            .limit(1)
        ).first()
        if done is not None and storage.has_result(key):
            job.status, job.progress, job.stage, job.result = SUCCEEDED, 1.0, "done", done.result
            job.cached_from = done.cached_from or done.id
            job.started_at = job.finished_at = now
            s.add(job)
            s.commit()
            return job
        leader = s.scalars(
            select(JobRecord)
            .where(JobRecord.result_key == key, JobRecord.status.in_(ACTIVE), JobRecord.leader_id.is_(None))
            .order_by(JobRecord.created_at)
            .limit(1)
        ).first()
        if leader is not None:
            own = leader.user == user
            job.leader_id, job.cached_from = leader.id, leader.id if own else None
            job.status, job.progress, job.stage, job.started_at = (
                leader.status,
                leader.progress,
                leader.stage,
                leader.started_at if own or leader.started_at is None else now,
            )
            s.add(job)
            s.commit()
        else:
            job.enqueued_at = now
            s.add(job)
            s.commit()
    if job.leader_id:
        settle_follower(db, celery, job.id)
    else:
        try:
            enqueue(celery, job.id, job.queue)
        except BrokerUnavailable:
            # the caller gets a 503 and no id: leave no trace of the job in their list
            with db.session() as s:
                s.execute(delete(JobRecord).where(JobRecord.id == job.id))
                s.commit()
                followers = s.scalars(select(JobRecord.id).where(JobRecord.leader_id == job.id)).all()
            for follower in followers:  # submitted meanwhile: they take over (queued, re-sent later)
                settle_follower(db, celery, follower)
            raise
    with db.session() as s:
        return s.get(JobRecord, job.id)


def cancel_job(db: Database, celery: Celery, user: str, job_id: str) -> JobRecord:
    """Mark a queued/running job cancelled (its worker notices and stops); its followers, if any,
    carry on under a new leader. NotFinished is not raised: cancelling a final job is a no-op."""
    with db.session() as s:
        job = visible_job(s, user, job_id)
        if job.status in FINAL:
            return job
        s.execute(
            update(JobRecord)
            .where(JobRecord.id == job_id, JobRecord.status.in_(ACTIVE))
            .values(status=CANCELLED, finished_at=utcnow(), stage="cancelled")
        )
        s.commit()
        followers = s.scalars(
            select(JobRecord.id)
            .where(JobRecord.leader_id == job_id, JobRecord.status.in_(ACTIVE))
            .order_by(JobRecord.created_at)
        ).all()
    if followers:
        new_leader = followers[0]
        with db.session() as s:
            s.execute(
                update(JobRecord)
                .where(
                    JobRecord.leader_id == job_id, JobRecord.id != new_leader, JobRecord.status.in_(ACTIVE)
                )
                .values(leader_id=new_leader)
            )
            s.commit()
        settle_follower(db, celery, new_leader)
    with db.session() as s:
        return s.get(JobRecord, job_id)
