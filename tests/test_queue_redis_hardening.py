"""Redis deployments done wrong or hit by a broker restart, with real processes: a worker that does
not share the API's job store says so (log and /readyz); a Redis that restarts empty has its queued
jobs re-sent at once, not after MAGNET_REQUEUE_AFTER_S."""

from __future__ import annotations

import shutil
import time

import httpx
import pytest
from service_fixtures import (
    SHARED_REDIS,
    Api,
    RedisServer,
    service_env,
    square_mesh,
    start_api,
    start_worker,
    wait_until,
    workers_online,
)
from test_queue_redis import redis_up

pytestmark = [pytest.mark.redis, pytest.mark.slow]


def test_a_worker_that_cannot_see_the_jobs_says_so(tmp_path):
    if not redis_up():
        pytest.skip("Redis is not running at 127.0.0.1:6379")
    env = service_env(tmp_path / "api-data", broker_url=SHARED_REDIS)
    other = {**env, "MAGNET_DATA_DIR": str(tmp_path / "worker-data")}  # the README's old mistake
    api_proc, url = start_api(env, tmp_path)
    worker = start_worker(other, tmp_path, "stranger")
    try:
        api = Api(url)
        job = api.submit(api.upload(square_mesh(tmp_path / "sq.vtu", 6))["id"], k=3)

        def readyz_explains():
            r = httpx.get(url + "/readyz", timeout=10)
            return r.status_code == 503 and "do not share" in r.json()["checks"]["workers"] and r.json()

        body = wait_until(readyz_explains, 60, 0.5, "/readyz to name the mismatch")
        assert "MAGNET_DATABASE_URL" in body["checks"]["workers"]
        wait_until(
            lambda: "not in this worker's job store" in worker.tail(200), 60, 0.5, "the worker's warning"
        )
        assert "WARNING" in worker.tail(200) and job["id"] in worker.tail(200)
        assert api.job(job["id"])["status"] == "queued"
    finally:
        worker.stop()
        api_proc.stop()


def test_queued_jobs_are_resent_as_soon_as_redis_is_back(tmp_path):
    if shutil.which("redis-server") is None:
        pytest.skip("redis-server not found: this test runs (and restarts) a private Redis")
    server = RedisServer(tmp_path)
    server.start()
    env = service_env(tmp_path / "data", broker_url=server.url, requeue_after_s=900)
    api_proc, url = start_api(env, tmp_path)
    procs = [api_proc]
    try:
        # a worker on the 'gpu' queue only: it sees the broker restart, but cannot run the cpu jobs
        procs.append(start_worker(env, tmp_path, "watcher", queues="gpu"))
        wait_until(lambda: workers_online(url) >= 1, 180, 0.5, "the watcher")
        time.sleep(3)  # its reaper has seen this Redis
        api = Api(url)
        mesh = api.upload(square_mesh(tmp_path / "sq.vtu", 8))
        waiting = [api.submit(mesh["id"], k=k) for k in (2, 3)]  # sitting in Redis: nobody takes 'cpu'
        server.stop()
        server.start()  # back, empty: this Redis keeps nothing on disk
        wait_until(lambda: "broker restarted" in procs[-1].tail(400), 60, 0.5, "the watcher to notice")
        procs.append(start_worker(env, tmp_path, "cpu", queues="cpu"))
        for job in waiting:  # without the re-send they would wait MAGNET_REQUEUE_AFTER_S = 900 s
            assert api.wait(job["id"], 90)["status"] == "succeeded"
    finally:
        for p in procs:
            p.stop()
        server.stop()
