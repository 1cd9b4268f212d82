"""Celery workers that run agglomeration jobs: tasks take a job id, the job record holds the state.

Imports jobqueue (records, storage, settings, queue) and models (the library); never service.
"""
