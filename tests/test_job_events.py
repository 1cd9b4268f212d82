"""GET /v1/jobs/{id}/events: server-sent events from a real uvicorn server with its embedded worker,
read with httpx as a stream (keys on: the same bearer auth as the other job routes)."""

from __future__ import annotations

import json
import threading
import time

import httpx
import pytest
from service_fixtures import Api, service_env, square_mesh, start_api, wait_until, workers_online

pytestmark = pytest.mark.slow
KEYS = "alice:alice-token,bob:bob-token"


def read_events(url: str, job_id: str, token: str, timeout: float = 120) -> list[tuple[str, dict]]:
    """All (event, data) of one stream, until the server closes it."""
    events, event, data = [], None, []
    headers = {"Authorization": f"Bearer {token}"}
    with httpx.stream("GET", f"{url}/v1/jobs/{job_id}/events", headers=headers, timeout=timeout) as r:
        assert r.status_code == 200, r.read()
        assert r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if line.startswith("event:"):
                event = line.split(":", 1)[1].strip()
            elif line.startswith("data:"):
                data.append(line.split(":", 1)[1].strip())
            elif line == "" and data:
                events.append((event, json.loads("\n".join(data))))
                event, data = None, []
    return events


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("events")
    proc, url = start_api(service_env(tmp / "data", api_keys=KEYS), tmp, embedded_worker=True)
    try:
        wait_until(lambda: workers_online(url, "alice-token") >= 1, 60, 0.2, "the embedded worker")
        yield url, tmp
    finally:
        proc.stop()


def test_events_follow_a_job_to_its_end(server):
    url, tmp = server
    api = Api(url, "alice-token")
    mesh = api.upload(square_mesh(tmp / "square80.vtu", 80))
    job = api.submit(mesh["id"], model="metis", k=200)
    events = read_events(url, job["id"], "alice-token")
    names = [e for e, _ in events]
    assert names[-1] == "end" and set(names[:-1]) <= {"progress"}, names
    final = events[-1][1]
    assert final["id"] == job["id"] and final["status"] == "succeeded" and final["progress"] == 1.0
    assert final["result"]["elements"] > 0 and final == api.job(job["id"])
    fractions = [d["progress"] for _, d in events]
    assert fractions == sorted(fractions), fractions
    running = [d for _, d in events if d["status"] == "running"]
    assert running and {d["stage"] for d in running} - {"starting"}, events  # stages of the run seen live
    assert any(0 < d["progress"] < 1 for d in running), fractions
    # a finished job: one `end` event at once
    again = read_events(url, job["id"], "alice-token", timeout=10)
    assert [e for e, _ in again] == ["end"] and again[0][1]["status"] == "succeeded"


def test_events_of_a_cancelled_job_end_cancelled(server):
    url, tmp = server
    api = Api(url, "alice-token")
    mesh = api.upload(square_mesh(tmp / "square140.vtu", 140))
    job = api.submit(mesh["id"], model="metis", k=500)
    api.wait_running(job["id"])
    t0 = time.monotonic()
    assert api.http.delete(f"/v1/jobs/{job['id']}").status_code == 200
    events = read_events(url, job["id"], "alice-token", timeout=30)
    assert events[-1][0] == "end" and events[-1][1]["status"] == "cancelled", events
    assert time.monotonic() - t0 < 30


def test_events_auth_and_unknown_jobs(server):
    url, tmp = server
    alice = Api(url, "alice-token")
    job = alice.submit(alice.upload(square_mesh(tmp / "square8.vtu", 8))["id"], k=4)
    path = f"{url}/v1/jobs/{job['id']}/events"
    r = httpx.get(path, timeout=10)
    assert r.status_code == 401 and "API key" in r.json()["detail"]
    r = httpx.get(path, headers={"Authorization": "Bearer wrong"}, timeout=10)
    assert r.status_code == 401
    # bob cannot follow alice's job: the same 404 as an unknown id
    r = httpx.get(path, headers={"Authorization": "Bearer bob-token"}, timeout=10)
    assert r.status_code == 404 and job["id"] in r.json()["detail"]
    r = httpx.get(f"{url}/v1/jobs/nope/events", headers={"Authorization": "Bearer alice-token"}, timeout=10)
    assert r.status_code == 404
    assert read_events(url, job["id"], "alice-token")[-1][1]["status"] == "succeeded"


def test_events_end_when_the_job_is_purged(server):
    """A job removed (DELETE ?purge=true) while followed: the stream ends at once, never hangs."""
    url, tmp = server
    api = Api(url, "alice-token")
    mesh = api.upload(square_mesh(tmp / "square150.vtu", 150))
    busy = api.submit(mesh["id"], model="metis", k=700)
    api.wait_running(busy["id"])
    waiting = api.submit(mesh["id"], model="metis", k=701)  # queued behind it: one embedded worker
    found: list = []
    reader = threading.Thread(target=lambda: found.extend(read_events(url, waiting["id"], "alice-token", 30)))
    reader.start()
    wait_until(lambda: api.job(waiting["id"])["status"] == "queued" and time.sleep(0.5) is None, 10)
    assert api.http.delete(f"/v1/jobs/{waiting['id']}", params={"purge": "true"}).status_code == 204
    reader.join(20)
    assert not reader.is_alive() and found, found
    assert found[0][0] == "progress"
    last_event, last = found[-1]
    assert last_event == "gone" or (last_event == "end" and last["status"] == "cancelled"), found
    assert api.http.get(f"/v1/jobs/{waiting['id']}").status_code == 404
    api.http.delete(f"/v1/jobs/{busy['id']}")
