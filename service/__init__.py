"""MAGNET HTTP service: FastAPI app over the agglomeration library, jobs run by Celery workers.

Nothing here imports torch: neural models only ever load inside a worker, through models.api.
"""
