"""The embedded default: `magnet serve` alone (API + worker on the SQLite broker, no server to
install) runs jobs, restarts a worker that died mid-job without losing the job, and loses nothing
when the whole service restarts."""

from __future__ import annotations

import os
import signal

import pytest
from service_fixtures import Api, child_pids, service_env, square_mesh, start_api, wait_until, workers_online

pytestmark = pytest.mark.slow


def test_embedded_serve_runs_jobs_survives_worker_death_and_restart(tmp_path):
    tiny = square_mesh(tmp_path / "tiny.vtu", 8)
    slow = square_mesh(tmp_path / "slow.vtu", 110)
    env = service_env(tmp_path / "data")
    serve, url = start_api(env, tmp_path, embedded_worker=True)
    try:
        wait_until(lambda: workers_online(url) >= 1, 180, 0.2, "the embedded worker")
        api = Api(url)
        mesh = api.upload(tiny)
        for k in (2, 5):
            done = api.wait(api.submit(mesh["id"], k=k)["id"], 60)
            assert done["status"] == "succeeded", done
        # kill the embedded worker (its main process and pool child) in the middle of a job
        job = api.submit(api.upload(slow)["id"], model="metis", k=64)
        api.wait_running(job["id"])
        workers = child_pids(serve.pid)
        assert workers, "no embedded worker process"
        for pid in workers:
            for child in child_pids(pid):
                os.kill(child, signal.SIGKILL)
            os.kill(pid, signal.SIGKILL)
        done = api.wait(job["id"], 120)
        assert done["status"] == "succeeded" and done["attempts"] == 2, done
        # stop the whole service with jobs still queued; start it again: they finish
        queued = [api.submit(mesh["id"], k=k) for k in (3, 4, 6)]
        serve.stop()
        serve, url = start_api(
            env, tmp_path, port=int(url.rsplit(":", 1)[1]), embedded_worker=True, name="serve2"
        )
        api = Api(url)
        for j in queued:
            assert api.wait(j["id"], 90)["status"] == "succeeded"
        assert api.http.get("/v1/jobs").json()["total"] == 6
    finally:
        serve.stop()


def test_the_embedded_broker_wakes_a_waiting_consumer_and_removes_dead_sockets(tmp_path):
    """A publish wakes a consumer waiting between polls (a datagram on its socket); a socket left by
    a dead process is removed by the next publish, and the messages still come out in order."""
    import socket
    from queue import Empty

    from kombu import Connection

    from jobqueue.embedded_transport import Waker, wake_consumers, wake_dir

    url = f"sqlite:///{tmp_path}/broker.sqlite"
    folder = wake_dir(url)
    waker = Waker(folder)
    assert waker.sock is not None, "no wake-up socket (path too long?)"
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    dead.bind(str(folder / "999999999.sock"))
    dead.close()  # its file stays, nobody listens
    assert not waker.wait(0)
    wake_consumers(folder)
    assert waker.wait(30) is True  # woken, not timed out
    assert not waker.wait(0)  # the wake-up was consumed
    assert sorted(os.listdir(folder)) == [os.path.basename(waker.path)]

    with Connection("magnetsql+" + url, transport_options={"polling_interval": 30}) as conn:
        q = conn.SimpleQueue("q")
        for i in range(3):
            q.put({"n": i})
        assert waker.wait(30) is True  # the publishes woke the (stand-in) consumer
        assert [q.get(timeout=5).payload["n"] for _ in range(3)] == [0, 1, 2]
        with pytest.raises(Empty):
            q.get_nowait()  # delivered messages are deleted, not kept invisible
        q.close()
    waker.close()
    assert not os.path.exists(waker.path)
