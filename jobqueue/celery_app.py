"""The Celery application, configured from MAGNET_* settings.

Embedded default (no MAGNET_BROKER_URL): kombu's SQLAlchemy transport on a SQLite file in the data
directory (jobqueue/embedded_transport.py), so `magnet serve` needs no server. Production: MAGNET_BROKER_URL=redis://host:6379/0.
No result backend: the job record in the database is the source of truth. Messages are JSON only
(nothing a client sends is ever unpickled).

The worker's app (with its task modules) is worker.app: `celery -A worker.app worker -Q cpu` works
too; `magnet worker` adds the right flags.
"""

from __future__ import annotations

from celery import Celery
from kombu import Queue

from jobqueue import embedded_transport  # noqa: F401  (registers the embedded broker's URL scheme)
from jobqueue.settings import Settings

TASK_NAME = "magnet.run_agglomeration"
EMBEDDED_POLL_S = 0.05
QUEUES = ("cpu", "gpu")


def make_celery(settings: Settings | None = None, include: tuple[str, ...] = ()) -> Celery:
    """A Celery app for `settings` (same tasks, only the configuration differs per deployment).
    The API's app sends tasks by name (TASK_NAME); a worker's app `include`s its task modules."""
    settings = settings or Settings()
    broker = settings.resolved_broker_url
    if settings.embedded_broker:
        # a publish wakes the worker through a local socket (jobqueue/embedded_transport.py); this
        # interval is the polling fallback where no wake-up socket can be bound
        transport_options = {"polling_interval": EMBEDDED_POLL_S, "connect_args": {"timeout": 30}}
    else:
        transport_options = {
            "visibility_timeout": settings.task_time_limit_s + 300,
            "socket_connect_timeout": 3,
            "socket_timeout": 10,
        }
        if settings.broker_key_prefix:
            transport_options["global_keyprefix"] = settings.broker_key_prefix
    app = Celery("magnet", broker=broker, include=list(include))
    app.conf.update(
        broker_transport_options=transport_options,
        broker_connection_timeout=3,
        broker_connection_retry_on_startup=True,
        broker_connection_max_retries=None,
        task_publish_retry=True,
        task_publish_retry_policy={
            "max_retries": 2,
            "interval_start": 0.2,
            "interval_step": 0.5,
            "interval_max": 1.0,
        },
        result_backend=None,
        task_ignore_result=True,
        task_serializer="json",
        accept_content=["json"],
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_acks_on_failure_or_timeout=True,
        task_soft_time_limit=settings.task_time_limit_s,
        task_time_limit=settings.task_time_limit_s + 60,
        task_default_queue="cpu",
        task_queues=[Queue(name) for name in QUEUES],
        worker_prefetch_multiplier=1,
        worker_max_tasks_per_child=200,
        worker_enable_remote_control=not settings.embedded_broker,
        worker_send_task_events=False,
        worker_cancel_long_running_tasks_on_connection_loss=False,
        worker_hijack_root_logger=False,
    )
    app.magnet_settings = settings
    return app
