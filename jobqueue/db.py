"""Job and mesh records (SQLAlchemy): SQLite by default, PostgreSQL by URL. The job record is the
source of truth for a job's state; the broker only carries job ids.

Shared by the API and the workers; imports neither FastAPI nor Celery.
"""

from __future__ import annotations

import hashlib
import os
import time
import uuid
from datetime import UTC, datetime

from sqlalchemy import (
    JSON,
    DateTime,
    Engine,
    Float,
    Integer,
    String,
    Text,
    and_,
    create_engine,
    event,
    or_,
    text,
    update,
)
from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

QUEUED, RUNNING, SUCCEEDED, FAILED, CANCELLED = "queued", "running", "succeeded", "failed", "cancelled"
ACTIVE = (QUEUED, RUNNING)
FINAL = (SUCCEEDED, FAILED, CANCELLED)


def utcnow() -> datetime:
    """Naive UTC now: stored the same way in SQLite and PostgreSQL."""
    return datetime.now(UTC).replace(tzinfo=None)


def new_id() -> str:
    return uuid.uuid4().hex


class Base(DeclarativeBase):
    pass


class MeshRecord(Base):
    """An uploaded mesh, content-addressed: id = sha256 of its bytes."""

    __tablename__ = "meshes"
    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    ext: Mapped[str] = mapped_column(String(16))
    size: Mapped[int] = mapped_column(Integer)
    info: Mapped[dict] = mapped_column(JSON)  # models.api.inspect_mesh output
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class MeshOwner(Base):
    """Which users uploaded a mesh: a user sees only meshes they uploaded themselves."""

    __tablename__ = "mesh_owners"
    mesh_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    user: Mapped[str] = mapped_column(String(200), primary_key=True)
    filename: Mapped[str] = mapped_column(String(300))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class JobRecord(Base):
    """One agglomeration request of one user.

    result_key = hash(mesh, normalized params, model version): jobs with the same key share one
    result directory. A job with leader_id set follows an in-flight job with the same key instead of
    computing; the leader's worker updates its followers along with itself.
    """

    __tablename__ = "jobs"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    user: Mapped[str] = mapped_column(String(200), index=True)
    mesh_id: Mapped[str] = mapped_column(String(64))
    params: Mapped[dict] = mapped_column(JSON)
    result_key: Mapped[str] = mapped_column(String(64), index=True)
    model_version: Mapped[str] = mapped_column(String(40))
    queue: Mapped[str] = mapped_column(String(16), default="cpu")
    status: Mapped[str] = mapped_column(String(16), index=True, default=QUEUED)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    stage: Mapped[str | None] = mapped_column(String(64), nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    result: Mapped[dict | None] = mapped_column(JSON, nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    leader_id: Mapped[str | None] = mapped_column(String(32), nullable=True, index=True)
    cached_from: Mapped[str | None] = mapped_column(String(32), nullable=True)
    worker: Mapped[str | None] = mapped_column(String(200), nullable=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow, index=True)
    enqueued_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    started_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)


class WorkerRecord(Base):
    """A live worker process (its reaper thread refreshes last_seen): readiness and monitoring."""

    __tablename__ = "workers"
    name: Mapped[str] = mapped_column(String(200), primary_key=True)
    queues: Mapped[str] = mapped_column(String(100))
    started_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    last_seen: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class ApiKey(Base):
    """An API key managed with `magnet keys`: only its SHA-256 is stored."""

    __tablename__ = "api_keys"
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    user: Mapped[str] = mapped_column(String(200), index=True)
    sha256: Mapped[str] = mapped_column(String(64), unique=True)
    note: Mapped[str] = mapped_column(String(200), default="")
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime, nullable=True)


def _sqlite_pragmas(dbapi_connection, _record) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.close()


def make_engine(url: str) -> Engine:
    """An engine with the settings a multi-process job store needs (WAL + busy timeout on SQLite)."""
    if url.startswith("sqlite"):
        path = url.split(":///", 1)[-1]
        if path and path != ":memory:":
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        engine = create_engine(url, connect_args={"timeout": 30, "check_same_thread": False})
        event.listen(engine, "connect", _sqlite_pragmas)
    else:
        if url.startswith("postgresql://"):
            url = "postgresql+psycopg://" + url[len("postgresql://") :]
        engine = create_engine(url, pool_pre_ping=True, pool_size=10, max_overflow=20)
    return engine


class Database:
    """Engine + session factory for one process (rebuild it after fork: see for_process)."""

    def __init__(self, url: str):
        self.url = url
        self.engine = make_engine(url)
        self.session = sessionmaker(self.engine, expire_on_commit=False)
        self.pid = os.getpid()

    def create_schema(self) -> None:
        """Create the tables that are missing. Several processes (API, worker, its pool children,
        the reaper) may meet a fresh store at once: a CREATE that loses the race to another process
        ("table ... already exists") is retried, each try skipping the tables that exist by then."""
        for attempt in range(8):
            try:
                Base.metadata.create_all(self.engine)
                return
            except (OperationalError, ProgrammingError, IntegrityError):
                if attempt == 7:
                    raise
                time.sleep(0.05 * (attempt + 1))

    def ping(self) -> None:
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))


_by_url: dict[tuple[str, int], Database] = {}


def for_process(url: str) -> Database:
    """The Database of this process for `url` (engines must not cross a fork)."""
    key = (url, os.getpid())
    if key not in _by_url:
        db = Database(url)
        db.create_schema()
        _by_url[key] = db
    return _by_url[key]


def lock_user(session: Session, user: str) -> None:
    """Hold `user`'s submissions until this session's transaction ends (commit or rollback), across
    threads, processes and hosts: a check of their jobs and the insert that follows it are then one
    step (the queue limit cannot be passed by submitting in parallel). Call it first in the session.
    PostgreSQL: an advisory transaction lock on the user; SQLite: the database's write lock taken now
    (BEGIN IMMEDIATE; other writers wait on the busy timeout, readers go on under WAL)."""
    dialect = session.get_bind().dialect.name
    if dialect == "postgresql":
        key = int.from_bytes(hashlib.sha256(f"magnet-user:{user}".encode()).digest()[:8], "big", signed=True)
        session.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": key})
    elif dialect == "sqlite":
        session.connection().exec_driver_sql("BEGIN IMMEDIATE")


def update_job_and_followers(session: Session, job_id: str, values: dict, only_if: dict | None = None) -> int:
    """Set `values` on a leader job (when it matches only_if) and on its still-active followers.

    Returns the number of leader rows changed (0 means the leader no longer matched only_if and
    nothing was written).
    """
    cond = [JobRecord.id == job_id] + [getattr(JobRecord, k) == v for k, v in (only_if or {}).items()]
    changed = session.execute(update(JobRecord).where(and_(*cond)).values(**values)).rowcount
    if changed:
        follower_values = {k: v for k, v in values.items() if k not in ("worker", "attempts", "heartbeat_at")}
        session.execute(
            update(JobRecord)
            .where(and_(JobRecord.leader_id == job_id, JobRecord.status.in_(ACTIVE)))
            .values(**follower_values)
        )
    return changed


def active_filter():
    return or_(JobRecord.status == QUEUED, JobRecord.status == RUNNING)
