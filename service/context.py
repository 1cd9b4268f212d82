"""What every request handler needs (settings, job store, blob storage, queue), built once per app."""

from __future__ import annotations

from dataclasses import dataclass

from celery import Celery
from fastapi import Request

from jobqueue.db import Database
from jobqueue.settings import Settings
from jobqueue.storage import Storage


@dataclass
class Context:
    settings: Settings
    db: Database
    storage: Storage
    celery: Celery


def get_context(request: Request) -> Context:
    """FastAPI dependency: the app's Context."""
    return request.app.state.ctx
