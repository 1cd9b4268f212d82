"""Helpers for the service tests: tiny meshes, real server/worker/Redis processes, polling.

No mocks: every process here is the real thing (uvicorn via `python -m service serve`, Celery
workers via `python -m worker worker`, redis-server). Each test gets its own data directory and
Redis key prefix, so nothing collides with other users of the machine's Redis.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
BRAIN = DATA / "BrainCoronalNoHoles.vtu"
PY = sys.executable
SHARED_REDIS = "redis://127.0.0.1:6379/0"
PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/test"


def square_mesh(path: Path, n: int = 20) -> Path:
    """A triangulated n x n unit square (2 n^2 triangles) written with meshio."""
    import meshio

    xs = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(xs, xs)
    points = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    a = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    tri = np.r_[np.c_[a, a + 1, a + n + 2], np.c_[a, a + n + 2, a + n + 1]]
    meshio.write(str(path), meshio.Mesh(points, [("triangle", tri)]))
    return Path(path)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(fn, timeout: float, interval: float = 0.1, what: str = "condition"):
    """Poll fn() until it returns something truthy; AssertionError after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    last_exc = None
    while time.monotonic() < deadline:
        try:
            value = fn()
            if value:
                return value
        except Exception as exc:  # the process may not be up yet
            last_exc = exc
        time.sleep(interval)
    raise AssertionError(
        f"timed out after {timeout} s waiting for {what}" + (f" (last error: {last_exc})" if last_exc else "")
    )


def service_env(
    data_dir: Path, broker_url: str | None = None, database_url: str | None = None, **extra
) -> dict:
    """Environment of a test deployment: fast heartbeats so dead workers are noticed in seconds."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MAGNET_")}
    env.update(
        {
            "MAGNET_DATA_DIR": str(data_dir),
            "MAGNET_HEARTBEAT_INTERVAL_S": "0.5",
            "MAGNET_HEARTBEAT_TIMEOUT_S": "4",
            "MAGNET_REQUEUE_AFTER_S": "10",
            "MAGNET_BROKER_KEY_PREFIX": f"magnet-test-{uuid.uuid4().hex[:10]}:",
            "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p),
            "OMP_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1",
        }
    )
    if broker_url:
        env["MAGNET_BROKER_URL"] = broker_url
    if database_url:
        env["MAGNET_DATABASE_URL"] = database_url
    env.update({f"MAGNET_{k.upper()}": str(v) for k, v in extra.items()})
    return env


class Proc:
    """A child process in its own session (so a SIGKILL takes its children too), logging to a file."""

    def __init__(self, cmd: list[str], env: dict, log: Path, cwd: Path | None = None):
        self.cmd, self.log = cmd, log
        self.logfile = open(log, "ab")
        self.popen = subprocess.Popen(
            cmd,
            env=env,
            cwd=str(cwd or ROOT),
            stdout=self.logfile,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def kill(self, sig: int = signal.SIGKILL) -> None:
        """Signal the whole process group (the worker and its pool children)."""
        try:
            os.killpg(self.popen.pid, sig)
        except ProcessLookupError:
            pass
        if sig == signal.SIGKILL:
            self.popen.wait(timeout=10)

    def stop(self, timeout: float = 20) -> None:
        """SIGTERM to the process itself (as `docker stop` does), then SIGKILL to what is left."""
        if self.alive():
            self.popen.send_signal(signal.SIGTERM)
            try:
                self.popen.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        if self.alive():
            self.popen.wait(timeout=10)
        self.logfile.close()

    def tail(self, n: int = 60) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""


def start_api(
    env: dict, tmp: Path, port: int | None = None, embedded_worker: bool = False, name: str = "api"
) -> tuple[Proc, str]:
    """`python -m service serve` on a free port (API only unless embedded_worker); waits for /healthz."""
    port = port or free_port()
    cmd = [PY, "-m", "service", "serve", "--port", str(port), "--log-level", "warning"]
    if not embedded_worker:
        cmd.append("--no-worker")
    proc = Proc(cmd, env, tmp / f"{name}-{port}.log")
    url = f"http://127.0.0.1:{port}"
    try:
        wait_until(lambda: httpx.get(url + "/healthz", timeout=2).status_code == 200, 60, 0.2, "the API")
    except AssertionError:
        proc.stop()
        raise AssertionError(f"API did not start:\n{proc.tail()}") from None
    return proc, url


def start_worker(env: dict, tmp: Path, name: str, queues: str = "cpu", concurrency: int = 1) -> Proc:
    cmd = [
        PY,
        "-m",
        "worker",
        "worker",
        "--queues",
        queues,
        "--concurrency",
        str(concurrency),
        "--name",
        f"{name}-{uuid.uuid4().hex[:6]}@test",
        "--loglevel",
        "INFO",
    ]
    return Proc(cmd, env, tmp / f"worker-{name}.log")


def workers_online(url: str, token: str | None = None) -> int:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    checks = httpx.get(url + "/readyz", headers=headers, timeout=5).json()["checks"]
    return int(checks["workers"].split()[0]) if checks["workers"][0].isdigit() else 0


class RedisServer:
    """A private redis-server (no persistence) that tests may stop and restart: never the shared one."""

    def __init__(self, tmp: Path):
        self.port = free_port()
        self.tmp = tmp
        self.proc: Proc | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        cmd = [
            "redis-server",
            "--port",
            str(self.port),
            "--bind",
            "127.0.0.1",
            "--save",
            "",
            "--appendonly",
            "no",
            "--dir",
            str(self.tmp),
        ]
        self.proc = Proc(cmd, dict(os.environ), self.tmp / f"redis-{self.port}.log")
        import redis

        wait_until(lambda: redis.Redis(port=self.port, socket_timeout=1).ping(), 20, 0.1, "redis-server")

    def stop(self) -> None:
        if self.proc:
            self.proc.kill(signal.SIGKILL)
            self.proc.stop()
            self.proc = None


class Api:
    """A small synchronous helper over httpx for one user of a test server."""

    def __init__(self, url: str, token: str | None = None):
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=url, headers=headers, timeout=60)

    def upload(self, path: Path) -> dict:
        r = self.http.post(
            "/v1/meshes",
            params={"filename": Path(path).name},
            content=Path(path).read_bytes(),
            headers={"Content-Type": "application/octet-stream"},
        )
        assert r.status_code == 201, r.text
        return r.json()

    def submit(self, mesh_id: str, **params) -> dict:
        r = self.http.post("/v1/jobs", json={"mesh_id": mesh_id, **params})
        assert r.status_code == 202, r.text
        return r.json()

    def job(self, job_id: str) -> dict:
        r = self.http.get(f"/v1/jobs/{job_id}")
        assert r.status_code == 200, r.text
        return r.json()

    def wait(self, job_id: str, timeout: float = 120, statuses=("succeeded", "failed", "cancelled")) -> dict:
        return wait_until(
            lambda: (j := self.job(job_id))["status"] in statuses and j,
            timeout,
            0.2,
            f"job {job_id} to reach {statuses}",
        )

    def wait_running(self, job_id: str, timeout: float = 60, attempt: int = 1) -> dict:
        """Wait until the job runs its `attempt`-th attempt (the first by default)."""

        def running():
            j = self.job(job_id)
            assert j["status"] not in ("failed", "cancelled", "succeeded"), j
            return j["status"] == "running" and j["attempts"] >= attempt and j

        return wait_until(running, timeout, 0.05, f"job {job_id} to run")

    def close(self) -> None:
        self.http.close()


def child_pids(pid: int) -> list[int]:
    """Direct children of a process (from /proc; Linux)."""
    kids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                kids.append(int(entry.name))
    return kids


@contextlib.contextmanager
def embedded_server(tmp: Path, token: str, user: str = "tester"):
    """A live API with its embedded worker and one API key (`user`:`token`); yields the URL once a
    worker is online, stops the server after."""
    proc, url = start_api(service_env(tmp / "data", api_keys=f"{user}:{token}"), tmp, embedded_worker=True)
    try:
        wait_until(lambda: workers_online(url, token) >= 1, 60, 0.2, "the embedded worker")
        yield url
    finally:
        proc.stop()


def octave_cli() -> str:
    """The octave-cli executable; skips the test, saying how to install it, when there is none."""
    import pytest

    octave = shutil.which("octave-cli")
    if octave is None:
        pytest.skip(
            "octave-cli not found: install GNU Octave (apt-get install -y --no-install-recommends octave)"
        )
    return octave


def run_octave(script: Path, text: str, result: Path) -> dict:
    """Write `text` to `script`, run it with octave-cli in its folder and load the JSON it writes to
    `result` (the test fails with Octave's output when that file is missing)."""
    script.write_text(text)
    out = subprocess.run(
        [octave_cli(), "--no-gui", "--quiet", "--no-window-system", str(script)],
        cwd=script.parent,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.exists(), f"octave failed:\n{out.stdout}\n{out.stderr}"
    return json.loads(result.read_text())


def upload_raw(client, name: str, data: bytes, token: str):
    """POST /v1/meshes of a raw body named `name` through a TestClient (or any httpx-like client)."""
    return client.post(
        "/v1/meshes",
        params={"filename": name},
        content=data,
        headers={"Content-Type": "application/octet-stream", "Authorization": f"Bearer {token}"},
    )


@contextlib.contextmanager
def store_url(store: str):
    """The job store's database URL: None for "sqlite" (the default store), or for "postgresql" a
    fresh database, dropped afterwards (the test skipped when PostgreSQL is down)."""
    if store != "postgresql":
        yield None
        return
    import pytest

    psycopg = pytest.importorskip("psycopg")
    try:
        admin = psycopg.connect(PG_ADMIN, autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.skip(f"PostgreSQL is not reachable at 127.0.0.1:5432: {exc}")
    name = f"magnet_test_{uuid.uuid4().hex[:12]}"
    admin.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql://postgres@127.0.0.1:5432/{name}"
    finally:
        admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.close()


@contextlib.contextmanager
def app_on_store(tmp: Path, store: str, **settings):
    """The app in a TestClient on the job store `store` (store_url), with these Settings."""
    from fastapi.testclient import TestClient

    from jobqueue.settings import Settings
    from service.app import create_app

    with store_url(store) as url:
        with TestClient(create_app(Settings(data_dir=tmp / "data", database_url=url, **settings))) as client:
            yield client
            client.app.state.ctx.db.engine.dispose()
