"""Storage that cleans up, quotas, keys managed while the API runs, Prometheus metrics, warm
networks: against the real app (in-process, SQLite job store; jobs run with the worker's own
execute_job; keys managed with the real `magnet keys` command in a child process)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from datetime import timedelta

import pytest
import yaml
from fastapi.testclient import TestClient
from service_fixtures import ROOT, square_mesh
from sqlalchemy import update

from jobqueue.cleanup import clean_up
from jobqueue.db import JobRecord, utcnow
from jobqueue.settings import Settings
from jobqueue.storage import Storage
from service.app import create_app
from worker.tasks import execute_job

KEYS = "alice:alice-token,bob:bob-token"


def auth(user: str) -> dict:
    return {"Authorization": f"Bearer {user}-token"}


def upload(client, path, user="alice", status=201):
    r = client.post(
        "/v1/meshes", params={"filename": path.name}, content=path.read_bytes(), headers=auth(user)
    )
    assert r.status_code == status, r.text
    return r.json()


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    return [square_mesh(d / f"sq{n}.vtu", n) for n in (6, 7, 8)]


def make(tmp_path, **overrides):
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEYS, **overrides)
    return TestClient(create_app(settings)), settings


def test_delete_mesh_refused_while_a_job_uses_it(tmp_path, meshes):
    client, settings = make(tmp_path)
    with client:
        mesh = upload(client, meshes[0])
        blob = Storage(settings.data_dir).mesh_path(mesh["id"], "vtu")
        job = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 3}, headers=auth("alice")).json()
        r = client.delete(f"/v1/meshes/{mesh['id']}", headers=auth("alice"))
        assert r.status_code == 409 and "queued or running" in r.json()["detail"], r.text
        assert client.delete(f"/v1/meshes/{mesh['id']}", headers=auth("bob")).status_code == 404
        upload(client, meshes[0], "bob")  # bob holds the same bytes
        assert execute_job(job["id"], settings) == "succeeded"
        assert client.delete(f"/v1/meshes/{mesh['id']}", headers=auth("alice")).status_code == 204
        assert client.get(f"/v1/meshes/{mesh['id']}", headers=auth("alice")).status_code == 404
        assert (
            client.get(f"/v1/jobs/{job['id']}/mesh", headers=auth("alice")).status_code == 200
        )  # results stay
        assert (
            blob.exists() and client.get(f"/v1/meshes/{mesh['id']}", headers=auth("bob")).status_code == 200
        )
        assert client.delete(f"/v1/meshes/{mesh['id']}", headers=auth("bob")).status_code == 204
        assert not blob.exists()  # nobody holds it any more
        assert client.delete(f"/v1/meshes/{mesh['id']}", headers=auth("bob")).status_code == 404


def test_retention_and_unreferenced_blobs(tmp_path, meshes):
    client, settings = make(tmp_path, retention_days=7)
    storage = Storage(settings.data_dir)
    with client:
        old_mesh = upload(client, meshes[1])
        old = client.post("/v1/jobs", json={"mesh_id": old_mesh["id"], "k": 4}, headers=auth("alice")).json()
        new = client.post("/v1/jobs", json={"mesh_id": old_mesh["id"], "k": 5}, headers=auth("alice")).json()
        for job in (old, new):
            assert execute_job(job["id"], settings) == "succeeded"
        keys = {
            j["id"]: client.app.state.ctx.db.session().get(JobRecord, j["id"]).result_key for j in (old, new)
        }
        db = client.app.state.ctx.db
        with db.session() as s:  # the first job finished 8 days ago
            s.execute(
                update(JobRecord)
                .where(JobRecord.id == old["id"])
                .values(finished_at=utcnow() - timedelta(days=8))
            )
            s.commit()
        stray = storage.root / "meshes" / "ff" / ("f" * 64 + ".vtu")  # a blob without a record
        stray.parent.mkdir(parents=True, exist_ok=True)
        stray.write_text("x")
        removed = clean_up(db, storage, settings, grace_s=0)
        assert removed["jobs"] == 1 and removed["results"] == 1 and removed["meshes"] == 1, removed
        assert client.get(f"/v1/jobs/{old['id']}", headers=auth("alice")).status_code == 404
        assert not storage.result_dir(keys[old["id"]]).exists() and not stray.exists()
        assert client.get(f"/v1/jobs/{new['id']}/metrics", headers=auth("alice")).status_code == 200
        # a mesh its owner deleted goes with the next pass; results of live jobs stay
        assert client.delete(f"/v1/meshes/{old_mesh['id']}", headers=auth("alice")).status_code == 204
        assert clean_up(db, storage, settings, grace_s=0) == {"jobs": 0, "results": 0, "meshes": 0, "temp": 0}
        assert storage.result_dir(keys[new["id"]]).exists()


def test_storage_quota(tmp_path, meshes):
    sizes = [p.stat().st_size for p in meshes]
    client, settings = make(tmp_path, max_storage_bytes_per_user=sizes[0] + sizes[1] // 2)
    with client:
        first = upload(client, meshes[0])
        r = client.post(
            "/v1/meshes", params={"filename": "b.vtu"}, content=meshes[1].read_bytes(), headers=auth("alice")
        )
        assert r.status_code == 413 and "storage quota" in r.json()["detail"], r.text
        assert "DELETE /v1/meshes" in r.json()["detail"]
        upload(client, meshes[1], "bob")  # the quota is per user
        upload(client, meshes[0])  # the same bytes again: nothing new to hold
        job = client.post("/v1/jobs", json={"mesh_id": first["id"], "k": 3}, headers=auth("alice")).json()
        assert execute_job(job["id"], settings) == "succeeded"  # its result takes alice over the quota
        r = client.post("/v1/jobs", json={"mesh_id": first["id"], "k": 4}, headers=auth("alice"))
        assert r.status_code == 429 and "storage quota" in r.json()["detail"], r.text
        assert client.delete(f"/v1/jobs/{job['id']}?purge=true", headers=auth("alice")).status_code == 204
        assert (
            client.post("/v1/jobs", json={"mesh_id": first["id"], "k": 4}, headers=auth("alice")).status_code
            == 202
        )


def keys_cli(data_dir, *args) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MAGNET_")}
    env["PYTHONPATH"] = str(ROOT)
    return subprocess.run(
        [sys.executable, "-m", "service", "keys", *args, "--data-dir", str(data_dir)],
        env=env,
        cwd=str(ROOT),
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_keys_managed_while_the_api_runs_and_stored_hashed(tmp_path, meshes):
    settings = Settings(data_dir=tmp_path / "data")  # no keys yet: anonymous on loopback
    with TestClient(create_app(settings)) as client:
        assert client.get("/v1/jobs").status_code == 200
        out = keys_cli(settings.data_dir, "add", "carol", "--note", "laptop")
        assert out.returncode == 0, out.stderr
        key_id, token = re.fullmatch(r"key (\w+) for carol: (\S+)", out.stdout.strip()).groups()
        # the running API sees the key at once: anonymous calls are refused from now on
        assert client.get("/v1/jobs").status_code == 401
        assert client.get("/v1/jobs", headers={"Authorization": "Bearer wrong"}).status_code == 401
        carol = {"Authorization": f"Bearer {token}"}
        r = client.post(
            "/v1/meshes", params={"filename": "a.vtu"}, content=meshes[0].read_bytes(), headers=carol
        )
        assert r.status_code == 201
        listed = keys_cli(settings.data_dir, "list")
        assert key_id in listed.stdout and "carol" in listed.stdout and token not in listed.stdout
        assert token.encode() not in (settings.data_dir / "magnet.sqlite").read_bytes()  # only the hash
        assert keys_cli(settings.data_dir, "revoke", key_id).returncode == 0
        assert client.get("/v1/jobs", headers=carol).status_code == 401
        assert client.get("/v1/jobs").status_code == 401  # every key revoked: still closed, not anonymous
        assert keys_cli(settings.data_dir, "revoke", key_id).returncode == 2  # nothing left to revoke
        assert keys_cli(settings.data_dir, "add").returncode == 2


def test_keys_file_may_hold_hashes(tmp_path):
    import hashlib

    keys = tmp_path / "keys.txt"
    keys.write_text(f"# hashed\ndave:sha256:{hashlib.sha256(b'dave-secret').hexdigest()}\nerin:erin-token\n")
    settings = Settings(data_dir=tmp_path / "data", api_keys_file=keys)
    with TestClient(create_app(settings)) as client:
        assert client.get("/v1/jobs", headers={"Authorization": "Bearer dave-secret"}).status_code == 200
        assert client.get("/v1/jobs", headers={"Authorization": "Bearer erin-token"}).status_code == 200
        assert (
            client.get("/v1/jobs", headers={"Authorization": f"Bearer sha256:{'0' * 64}"}).status_code == 401
        )
        assert "erin-token" not in repr(client.app.state.api_keys)


def test_prometheus_metrics(tmp_path, meshes):
    client, settings = make(tmp_path)
    with client:
        mesh = upload(client, meshes[0])
        done = client.post("/v1/jobs", json={"mesh_id": mesh["id"], "k": 3}, headers=auth("alice")).json()
        assert execute_job(done["id"], settings) == "succeeded"
        client.post(
            "/v1/jobs", json={"mesh_id": mesh["id"], "model": "kmeans", "k": 4}, headers=auth("alice")
        )
        r = client.get("/metrics")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain; version=0.0.4")
        text = r.text
    samples = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            samples[name] = float(value)
    assert samples['magnet_jobs{state="succeeded",queue="cpu"}'] == 1
    assert samples['magnet_jobs{state="queued",queue="cpu"}'] == 1
    assert (
        samples['magnet_queue_length{queue="cpu"}'] == 1 and samples['magnet_queue_length{queue="gpu"}'] == 0
    )
    assert samples["magnet_workers"] == 0 and samples["magnet_running_jobs"] == 0
    assert samples['magnet_job_duration_seconds_count{model="metis"}'] == 1
    assert samples['magnet_job_duration_seconds_bucket{model="metis",le="+Inf"}'] == 1
    assert "# TYPE magnet_job_duration_seconds histogram" in text
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    prom = compose["services"]["prometheus"]
    assert prom["profiles"] == ["metrics"]
    config = yaml.safe_load((ROOT / "deploy" / "prometheus.yml").read_text())
    assert config["scrape_configs"][0]["static_configs"][0]["targets"] == ["api:8000"]
    assert config["scrape_configs"][0]["metrics_path"] == "/metrics"


def test_networks_stay_loaded_in_the_worker_process(monkeypatch):
    from models.partition import sage
    from worker.cli import apply_overrides, register_worker
    from worker.warmup import warm_up

    parser = __import__("argparse").ArgumentParser()
    register_worker(parser.add_subparsers(dest="command"))
    monkeypatch.delenv("MAGNET_PRELOAD_MODELS", raising=False)
    apply_overrides(parser.parse_args(["worker", "--preload-models"]))
    assert Settings().preload_models is True
    assert len(warm_up()) == 4  # what a pool process runs at start with MAGNET_PRELOAD_MODELS
    loaded = sage.warm_up("cpu")
    assert sorted(loaded) == ["sage-base-2d", "sage-base-3d", "sage-hetero-2d", "sage-hetero-3d"]
    cached = dict(sage._CACHE)
    assert sage.warm_up("cpu") == loaded and all(sage._CACHE[k] is v for k, v in cached.items())


def test_a_real_worker_applies_the_retention_policy(tmp_path, meshes):
    """`magnet serve` with its embedded worker: the worker's reaper removes a finished job (record and
    result files) once it is older than MAGNET_RETENTION_DAYS."""
    from service_fixtures import Api, service_env, start_api, wait_until, workers_online

    env = service_env(tmp_path / "data", retention_days=3 / 86400, cleanup_interval_s=1)  # 3 seconds
    proc, url = start_api(env, tmp_path, embedded_worker=True)
    try:
        wait_until(lambda: workers_online(url) >= 1, 90, 0.5, "the embedded worker")
        api = Api(url)
        job = api.wait(api.submit(api.upload(meshes[2])["id"], k=4)["id"], 120)
        assert job["status"] == "succeeded"
        results = tmp_path / "data" / "results"
        assert any(results.iterdir())
        wait_until(lambda: api.http.get(f"/v1/jobs/{job['id']}").status_code == 404, 60, 0.5, "the cleanup")
        wait_until(lambda: not any(results.iterdir()), 90, 0.5, "the result files to go")
    finally:
        proc.stop()
