"""Service and worker configuration, read from MAGNET_* environment variables (pydantic-settings).

The API process, the embedded worker and `magnet worker` all build their Settings the same way, so
one set of environment variables configures a whole deployment.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Every knob of the service; defaults give the embedded single-machine setup."""

    model_config = SettingsConfigDict(env_prefix="MAGNET_", extra="ignore")

    data_dir: Path = Field(Path("var"), description="Blobs (meshes, results) and the embedded databases.")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL of the job store; default SQLite in data_dir."
    )
    broker_url: str | None = Field(
        None, description="Celery broker; default: SQLite in data_dir (no server)."
    )
    broker_key_prefix: str = Field(
        "", description="Prefix of every Redis key (several deployments, one Redis)."
    )

    api_keys: str | None = Field(None, description="'user:token,user2:token2'; each token is a user.")
    api_keys_file: Path | None = Field(None, description="File with one 'user:token' per line (# comments).")

    max_upload_bytes: int = 256 * 1024 * 1024
    max_cells: int = 5_000_000
    max_queued_jobs_per_user: int = 50
    parse_timeout_s: float = 120.0
    parse_memory_bytes: int = 4 * 1024**3

    task_time_limit_s: int = 3600
    max_attempts: int = 3
    heartbeat_interval_s: float = 5.0
    heartbeat_timeout_s: float = 60.0
    requeue_after_s: float = 300.0
    gpu_queue: bool = Field(False, description="Route neural models to the 'gpu' queue (a GPU worker runs).")
    preload_models: bool = Field(
        False,
        description="Workers load torch and the shipped networks when they start (not at the first job).",
    )

    retention_days: float = Field(
        0.0,
        ge=0,
        description="Finished jobs (and their result files) older than this are removed; 0 keeps them.",
    )
    cleanup_interval_s: float = Field(
        3600.0, gt=0, description="How often a worker's reaper cleans up storage."
    )
    max_storage_bytes_per_user: int = Field(
        0, ge=0, description="Bytes of meshes and results one user may hold; 0 = no quota."
    )

    @property
    def resolved_database_url(self) -> str:
        return self.database_url or f"sqlite:///{(self.data_dir / 'magnet.sqlite').resolve()}"

    @property
    def resolved_broker_url(self) -> str:
        return self.broker_url or f"magnetsql+sqlite:///{(self.data_dir / 'broker.sqlite').resolve()}"

    @property
    def embedded_broker(self) -> bool:
        return self.resolved_broker_url.startswith(("magnetsql+", "sqla+", "sqlalchemy+"))

    @property
    def reaper_interval_s(self) -> float:
        return max(0.2, min(self.heartbeat_interval_s, self.heartbeat_timeout_s / 3))
