"""The worker's Celery app: the shared queue configuration (jobqueue.celery_app) plus the task
modules. `celery -A worker.app worker -Q cpu` works; `magnet worker` adds the right flags."""

from __future__ import annotations

from celery import Celery

from jobqueue.celery_app import make_celery
from jobqueue.settings import Settings

TASK_MODULES = ("worker.tasks", "worker.reaper", "worker.warmup")


def make_worker_app(settings: Settings | None = None) -> Celery:
    """A Celery app that runs MAGNET tasks (the API's app only sends them)."""
    return make_celery(settings, include=TASK_MODULES)


app = make_worker_app()
