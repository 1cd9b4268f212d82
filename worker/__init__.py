"""Celery workers that run agglomeration jobs: tasks take a job id, the job record holds the state."""
