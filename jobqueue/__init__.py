"""What the API and the workers share: settings, job and mesh records, blob storage, the queue.

Arrows point one way (README, Layout):  service -> jobqueue <- worker -> models; service -> models
(parameter validation and the model list only). jobqueue imports neither service, worker nor
models, nor FastAPI; it names the Celery task (TASK_NAME) so the API sends jobs by name without
importing any worker code.
"""
