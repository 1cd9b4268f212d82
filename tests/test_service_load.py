"""Load: 100 concurrent submissions from 10 clients (10 users) against uvicorn + 2 Celery workers on
Redis. Every job succeeds, none is lost, none is computed twice."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from service_fixtures import (
    SHARED_REDIS,
    service_env,
    square_mesh,
    start_api,
    start_worker,
    wait_until,
    workers_online,
)
from test_queue_redis import redis_up

pytestmark = [pytest.mark.redis, pytest.mark.slow]
USERS = [f"user{i}" for i in range(10)]


def test_100_concurrent_submissions_from_10_clients(tmp_path):
    if not redis_up():
        pytest.skip("Redis is not running at 127.0.0.1:6379")
    mesh_path = square_mesh(tmp_path / "tiny.vtu", 6)
    env = service_env(
        tmp_path / "data", broker_url=SHARED_REDIS, api_keys=",".join(f"{u}:{u}-key" for u in USERS)
    )
    api, url = start_api(env, tmp_path)
    workers = [start_worker(env, tmp_path, f"w{i}") for i in range(2)]
    clients = {
        u: httpx.Client(base_url=url, headers={"Authorization": f"Bearer {u}-key"}, timeout=120)
        for u in USERS
    }
    try:
        wait_until(lambda: workers_online(url, "user0-key") == 2, 60, 0.2, "two workers")
        mesh_ids = {}
        for u, c in clients.items():
            r = c.post(
                "/v1/meshes",
                params={"filename": "tiny.vtu"},
                content=mesh_path.read_bytes(),
                headers={"Content-Type": "application/octet-stream"},
            )
            assert r.status_code == 201
            mesh_ids[u] = r.json()["id"]
        start = threading.Barrier(100)

        def submit(user: str, k: int) -> dict:
            start.wait()
            r = clients[user].post(
                "/v1/jobs",
                json={
                    "mesh_id": mesh_ids[user],
                    "model": "metis",
                    "k": k,
                    "options": {"seed": USERS.index(user)},
                },
            )
            assert r.status_code == 202, r.text
            return r.json()

        t0 = time.monotonic()
        with ThreadPoolExecutor(100) as pool:
            futures = [pool.submit(submit, u, k) for u in USERS for k in range(2, 12)]
            submitted = [f.result() for f in futures]
        t_submit = time.monotonic() - t0
        ids = [j["id"] for j in submitted]
        assert len(set(ids)) == 100

        def all_done():
            states = [clients[u].get("/v1/jobs", params={"limit": 100}).json() for u in USERS]
            return (
                all(
                    s["total"] == 10 and all(j["status"] in ("succeeded", "failed") for j in s["items"])
                    for s in states
                )
                and states
            )

        states = wait_until(all_done, 300, 1.0, "all 100 jobs to finish")
        t_all = time.monotonic() - t0
        jobs = [j for s in states for j in s["items"]]
        assert sorted(j["id"] for j in jobs) == sorted(ids)  # none lost, none extra
        assert all(j["status"] == "succeeded" for j in jobs), [j["error"] for j in jobs if j["error"]][:3]
        assert all(j["attempts"] == 1 and not j["cached"] for j in jobs)  # each computed exactly once
        for state in states:  # each user sees exactly their own ten k values
            assert sorted(j["params"]["k"] for j in state["items"]) == list(range(2, 12))
        started = sum(w.tail(100000).count(": running {") for w in workers)
        assert started == 100, f"{started} job starts logged for 100 jobs"
        print(
            f"\nload: 100 submissions in {t_submit:.2f} s, all 100 jobs done after {t_all:.1f} s "
            f"({100 / t_all * 60:.0f} jobs/min with 2 workers)"
        )
    finally:
        for c in clients.values():
            c.close()
        for w in workers:
            w.stop()
        api.stop()
