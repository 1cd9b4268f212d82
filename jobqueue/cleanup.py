"""Storage that cleans up after itself: a retention policy for finished jobs and the removal of
blobs nothing refers to. Run by every worker's reaper every MAGNET_CLEANUP_INTERVAL_S; each step
is idempotent, so several workers may run it at once.

- MAGNET_RETENTION_DAYS (0 = keep forever): finished jobs (succeeded, failed, cancelled) older than
  that are removed, records and result files.
- Result directories no job refers to any more are removed.
- Meshes nobody owns any more (every owner deleted them) and no queued/running job uses are removed.
- Mesh blobs without a record and abandoned temp folders older than GRACE_S are removed (an upload
  files its blob just before recording it, hence the grace period).
"""

from __future__ import annotations

import shutil
import time
from datetime import timedelta
from pathlib import Path

from sqlalchemy import delete, select

from jobqueue.db import ACTIVE, FINAL, Database, JobRecord, MeshOwner, MeshRecord, utcnow
from jobqueue.settings import Settings
from jobqueue.storage import Storage

GRACE_S = 3600.0


def _older_than(path: Path, seconds: float) -> bool:
    try:
        return time.time() - path.stat().st_mtime > seconds
    except FileNotFoundError:
        return False


def clean_up(db: Database, storage: Storage, settings: Settings, grace_s: float = GRACE_S) -> dict[str, int]:
    """One cleanup pass; returns how many jobs, results, meshes and temp folders it removed."""
    now = utcnow()
    done = {"jobs": 0, "results": 0, "meshes": 0, "temp": 0}
    if settings.retention_days > 0:
        cut = now - timedelta(days=settings.retention_days)
        with db.session() as s:
            done["jobs"] = s.execute(
                delete(JobRecord).where(JobRecord.status.in_(FINAL), JobRecord.finished_at < cut)
            ).rowcount
            s.commit()
    with db.session() as s:
        keys = set(s.scalars(select(JobRecord.result_key).distinct()))
        owned = set(s.scalars(select(MeshOwner.mesh_id).distinct()))
        in_use = set(s.scalars(select(JobRecord.mesh_id).where(JobRecord.status.in_(ACTIVE)).distinct()))
        records = {m.id: m for m in s.scalars(select(MeshRecord))}
    results = storage.root / "results"
    for folder in results.iterdir() if results.is_dir() else ():
        # published (renamed into place) after the snapshot of keys above: younger than the grace
        if folder.name not in keys and _older_than(folder, min(grace_s, 30.0)):
            shutil.rmtree(folder, ignore_errors=True)
            done["results"] += 1
    grace_cut = now - timedelta(seconds=grace_s)
    for mesh_id, mesh in records.items():
        if mesh_id in owned or mesh_id in in_use or mesh.created_at > grace_cut:
            continue
        with db.session() as s:
            gone = s.execute(delete(MeshRecord).where(MeshRecord.id == mesh_id)).rowcount
            s.commit()
        if gone:
            storage.mesh_path(mesh_id, mesh.ext).unlink(missing_ok=True)
            done["meshes"] += 1
    for blob in (storage.root / "meshes").glob("*/*"):
        if blob.stem not in records and _older_than(blob, grace_s):
            blob.unlink(missing_ok=True)
            done["meshes"] += 1
    for folder in (storage.root / "tmp").iterdir():
        if folder.is_dir() and _older_than(folder, max(grace_s, settings.task_time_limit_s + 600)):
            shutil.rmtree(folder, ignore_errors=True)
            done["temp"] += 1
    return done
