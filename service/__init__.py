"""MAGNET HTTP service: FastAPI app over the agglomeration library, jobs run by Celery workers.

Imports jobqueue (records, storage, settings, queue: tasks are sent by name) and models (parameter
validation, the model list); never worker. Nothing here imports torch: neural models only ever load
inside a worker, through models.api.
"""
