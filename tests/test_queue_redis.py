"""The queue with real processes: uvicorn API, Celery workers, Redis (the machine's, and a private
redis-server for the tests that stop it). Faults: SIGKILLed workers, a job that keeps killing its
worker, cancellation of a running job, Redis going away, the API restarting."""

from __future__ import annotations

import os
import shutil
import signal
import time

import httpx
import pytest
import redis
from service_fixtures import (
    SHARED_REDIS,
    Api,
    RedisServer,
    child_pids,
    service_env,
    square_mesh,
    start_api,
    start_worker,
    wait_until,
    workers_online,
)

pytestmark = [pytest.mark.redis, pytest.mark.slow]
# on a 160 x 160 square (51,200 triangles): about 7-8 s of CPU (fm refinement, flows first, at every
# coarsening level), with progress and cancellation points all along; on a 110 x 110 square the flow
# refiner is done in about 4 s now, and a plain METIS job in about a second: too fast to kill mid-job
SLOW = {"model": "metis", "mode": "multilevel", "nref": 6, "refiner": "fm"}


def redis_up() -> bool:
    try:
        return bool(redis.Redis.from_url(SHARED_REDIS, socket_timeout=1).ping())
    except redis.RedisError:
        return False


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    return {"tiny": square_mesh(d / "tiny.vtu", 8), "slow": square_mesh(d / "slow.vtu", 160)}


@pytest.fixture
def deployment(tmp_path):
    """Start/stop helpers for one deployment on the shared Redis; everything is torn down after."""
    if not redis_up():
        pytest.skip("Redis is not running at 127.0.0.1:6379")
    procs = []

    class D:
        env = service_env(tmp_path / "data", broker_url=SHARED_REDIS)

        def api(self, **kw):
            proc, url = start_api(self.env, tmp_path, **kw)
            procs.append(proc)
            self.url = url
            return proc, url

        def worker(self, name, **kw):
            proc = start_worker(self.env, tmp_path, name, **kw)
            procs.append(proc)
            return proc

    yield D()
    for p in procs:
        p.stop()


def test_workers_run_jobs_and_a_killed_worker_loses_nothing(deployment, meshes):
    _, url = deployment.api()
    first = deployment.worker("w1")
    wait_until(lambda: workers_online(url) >= 1, 30, 0.2, "worker online")
    api = Api(url)
    tiny = api.upload(meshes["tiny"])
    quick = [api.submit(tiny["id"], k=k) for k in (2, 3, 4)]
    for job in quick:
        done = api.wait(job["id"], 60)
        assert done["status"] == "succeeded" and done["result"]["elements"] >= 2, done
    slow = api.upload(meshes["slow"])
    job = api.submit(slow["id"], **SLOW)
    api.wait_running(job["id"])
    first.kill(signal.SIGKILL)  # the worker and its pool child, mid-job
    time.sleep(1)
    assert api.job(job["id"])["status"] == "running"  # nobody knows yet
    second = deployment.worker("w2")
    done = api.wait(job["id"], 120)
    assert done["status"] == "succeeded" and done["attempts"] == 2, done
    assert done["result"]["elements"] >= 64
    # only the pool process dies (OOM killer, segfault): Celery re-delivers the message at once
    # (reject_on_worker_lost) and the same worker takes the job over from its dead child
    job = api.submit(slow["id"], **{**SLOW, "nref": 5})  # another job (not a cached result), as slow
    api.wait_running(job["id"])
    (child,) = child_pids(second.pid)
    os.kill(child, signal.SIGKILL)
    done = api.wait(job["id"], 120)
    assert done["status"] == "succeeded" and done["attempts"] == 2, done
    # Usually Celery's redelivery takes it over at once; on a loaded machine the reaper may get
    # there first. Either way the job must run exactly once more and succeed (checked above).


def test_a_job_that_keeps_killing_its_worker_ends_failed(deployment, meshes):
    deployment.env["MAGNET_MAX_ATTEMPTS"] = "2"
    _, url = deployment.api()
    api = Api(url)
    job = api.submit(api.upload(meshes["slow"])["id"], **SLOW)
    for n in range(2):
        w = deployment.worker(f"victim{n}")
        api.wait_running(job["id"], 60, attempt=n + 1)
        w.kill(signal.SIGKILL)
    deployment.worker("survivor")
    done = api.wait(job["id"], 60)
    assert done["status"] == "failed" and done["error"] == "worker died 2 times while running this job", done
    assert done["attempts"] == 2


def test_cancel_stops_a_running_job(deployment, meshes):
    _, url = deployment.api()
    w = deployment.worker("w")
    api = Api(url)
    job = api.submit(api.upload(meshes["slow"])["id"], **SLOW)
    api.wait_running(job["id"])
    r = api.http.delete(f"/v1/jobs/{job['id']}")
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    # the worker stops it within a heartbeat or two (the whole job takes a few seconds)
    wait_until(lambda: f"job {job['id']}: cancelled" in w.tail(400), 3, 0.1, "the worker to stop the job")
    quick = api.submit(api.upload(meshes["tiny"])["id"], k=3)
    assert api.wait(quick["id"], 60)["status"] == "succeeded"  # the worker is free again
    assert api.job(job["id"])["status"] == "cancelled"
    assert api.http.get(f"/v1/jobs/{job['id']}/mesh").status_code == 409


def test_api_restart_loses_no_job(deployment, meshes):
    api_proc, url = deployment.api()
    api = Api(url)
    mesh = api.upload(meshes["tiny"])
    jobs = [api.submit(mesh["id"], k=k) for k in range(2, 8)]
    api_proc.kill(signal.SIGKILL)
    port = int(url.rsplit(":", 1)[1])
    deployment.worker("w")
    _, url = deployment.api(port=port, name="api2")
    api = Api(url)
    for job in jobs:
        assert api.wait(job["id"], 60)["status"] == "succeeded"
    assert api.http.get("/v1/jobs").json()["total"] == len(jobs)


def test_redis_down_gives_503_and_work_resumes(tmp_path, meshes):
    if shutil.which("redis-server") is None:
        pytest.skip("redis-server not found: this test runs (and stops) a private Redis")
    server = RedisServer(tmp_path)
    server.start()
    env = service_env(tmp_path / "data", broker_url=server.url, requeue_after_s=3)
    api_proc, url = start_api(env, tmp_path)
    procs = [api_proc]
    try:
        api = Api(url)
        mesh = api.upload(meshes["tiny"])
        waiting = [api.submit(mesh["id"], k=k) for k in (2, 3)]  # no worker yet: sitting in Redis
        server.stop()  # and lost with it: this Redis keeps nothing on disk
        t0 = time.monotonic()
        r = api.http.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 4})
        assert r.status_code == 503, r.text
        assert "broker" in r.json()["detail"] and time.monotonic() - t0 < 20
        assert httpx.get(url + "/readyz", timeout=30).status_code == 503
        server.start()
        procs.append(start_worker(env, tmp_path, "w"))
        for job in waiting:  # re-sent from the job records by the worker's reaper
            assert api.wait(job["id"], 60)["status"] == "succeeded"
        again = api.submit(mesh["id"], k=4)
        assert api.wait(again["id"], 60)["status"] == "succeeded"
        wait_until(lambda: httpx.get(url + "/readyz", timeout=10).status_code == 200, 30, 0.5, "ready")
    finally:
        for p in procs:
            p.stop()
        server.stop()


def test_neural_jobs_go_to_the_gpu_queue_when_configured(deployment, meshes):
    deployment.env["MAGNET_GPU_QUEUE"] = "true"
    _, url = deployment.api()
    deployment.worker("gpu", queues="gpu")  # a "GPU worker" (this machine runs it on the CPU)
    api = Api(url)
    mesh = api.upload(meshes["tiny"])
    neural = api.submit(mesh["id"], model="sage-base", mode="nref", nref=2)
    classic = api.submit(mesh["id"], model="metis", k=4)
    assert (neural["queue"], classic["queue"]) == ("gpu", "cpu")
    done = api.wait(neural["id"], 120)
    assert done["status"] == "succeeded" and done["result"]["elements"] >= 4, done
    assert api.job(classic["id"])["status"] == "queued"  # nobody consumes 'cpu' yet
    deployment.worker("cpu", queues="cpu")
    assert api.wait(classic["id"], 60)["status"] == "succeeded"
