"""PostgreSQL as the job store (multi-host deployments): a fresh database for the test, dropped after.
API and worker share it; jobs run, dedup works, a restart of the API loses nothing."""

from __future__ import annotations

import signal

import pytest
from service_fixtures import SHARED_REDIS, Api, service_env, square_mesh, start_api, start_worker, store_url
from test_queue_redis import redis_up

pytestmark = [pytest.mark.postgres, pytest.mark.redis, pytest.mark.slow]


@pytest.fixture
def pg_database():
    with store_url("postgresql") as url:
        yield url


def test_postgres_job_store(tmp_path, pg_database):
    if not redis_up():
        pytest.skip("Redis is not running at 127.0.0.1:6379")
    env = service_env(tmp_path / "data", broker_url=SHARED_REDIS, database_url=pg_database)
    api_proc, url = start_api(env, tmp_path)
    worker = start_worker(env, tmp_path, "pg")
    try:
        api = Api(url)
        mesh = api.upload(square_mesh(tmp_path / "tiny.vtu", 8))
        first = api.wait(api.submit(mesh["id"], model="kmeans", k=4, options={"seed": 1})["id"], 60)
        assert first["status"] == "succeeded", first
        again = api.submit(mesh["id"], model="kmeans", k=4, options={"seed": 1})
        assert again["status"] == "succeeded" and again["cached"] and again["result"] == first["result"]
        pending = [api.submit(mesh["id"], k=k) for k in (2, 3, 5)]
        api_proc.kill(signal.SIGKILL)
        api_proc, url = start_api(env, tmp_path, port=int(url.rsplit(":", 1)[1]), name="api2")
        api = Api(url)
        for job in pending:
            assert api.wait(job["id"], 60)["status"] == "succeeded"
        assert api.http.get("/v1/jobs").json()["total"] == 5
        import psycopg

        with psycopg.connect(pg_database) as conn:
            count = conn.execute("SELECT count(*) FROM jobs WHERE status = 'succeeded'").fetchone()[0]
        assert count == 5
    finally:
        worker.stop()
        api_proc.stop()
