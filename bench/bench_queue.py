"""Queue overhead and throughput of the MAGNET service (not part of the tests).

- latency: submit-to-result of a tiny job (METIS on a triangulated 8x8 square, 128 cells) through
  the HTTP API + Celery worker, p50/p95, against the same work done in-process (models.api.run_job);
  for the Redis broker and the embedded SQLite broker;
- throughput: jobs per minute with 1 and 2 workers (Redis), 40 tiny jobs submitted at once.

Real processes (uvicorn, `magnet worker`, Redis at 127.0.0.1:6379), as in the tests.
Usage: python bench/bench_queue.py [--jobs 30] [--batch 40]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from service_fixtures import (  # noqa: E402
    SHARED_REDIS,
    Api,
    service_env,
    square_mesh,
    start_api,
    start_worker,
    wait_until,
    workers_online,
)

FIRST: dict[str, float] = {}  # submit-to-result of the first job after start-up, per broker
PARTS: dict[str, list[tuple[float, ...]]] = {}  # per broker: where each job's time went (see parts())


def _ts(stamp: str) -> float:
    return datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()


def parts(t_submit: float, t_accepted: float, t_seen: float, job: dict) -> tuple[float, ...]:
    """A job's time in segments, from the client's wall clock and the job record's timestamps (same
    machine, same clock): POST answered; created -> started (broker + pick-up + claim); started ->
    finished (the task: library + result publishing); finished -> seen by the client."""
    created, started, finished = _ts(job["created_at"]), _ts(job["started_at"]), _ts(job["finished_at"])
    return (
        t_accepted - t_submit,
        created - t_submit,
        started - created,
        finished - started,
        t_seen - finished,
    )


def pct(values: list[float], q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(round(q * (len(values) - 1))))]


def in_process(mesh: Path, n: int, tmp: Path) -> list[float]:
    from models import api

    api.run_job(mesh, tmp / "warm", {"model": "metis", "k": 4})  # imports, caches
    times = []
    for i in range(n):
        t = time.perf_counter()
        api.run_job(mesh, tmp / f"run{i}", {"model": "metis", "k": 4, "options": {"seed": i + 1}})
        times.append(time.perf_counter() - t)
    return times


def wait_done(api: Api, job_id: str, poll: float = 0.01) -> dict:
    while True:
        job = api.job(job_id)
        if job["status"] in ("succeeded", "failed", "cancelled"):
            assert job["status"] == "succeeded", job
            return job
        time.sleep(poll)


def through_queue(broker: str | None, mesh: Path, n: int, tmp: Path, seed0: int) -> list[float]:
    env = service_env(tmp / f"data-{broker or 'embedded'}", broker_url=broker)
    api_proc, url = start_api(env, tmp, name=f"api-{broker is None}")
    worker = start_worker(env, tmp, f"bench-{broker is None}")
    try:
        wait_until(lambda: workers_online(url) >= 1, 60, 0.2, "worker")
        api = Api(url)
        mesh_id = api.upload(mesh)["id"]
        t = time.perf_counter()
        wait_done(api, api.submit(mesh_id, k=4)["id"])  # the first job after start-up: counted too
        times = [time.perf_counter() - t]
        FIRST[broker or "embedded"] = times[0]
        split = PARTS.setdefault(broker or "embedded", [])
        for i in range(n - 1):
            t, w0 = time.perf_counter(), time.time()
            job = api.submit(mesh_id, k=4, options={"seed": seed0 + i})
            w1 = time.time()
            done = wait_done(api, job["id"])
            times.append(time.perf_counter() - t)
            split.append(parts(w0, w1, time.time(), done))
        return times
    finally:
        worker.stop()
        api_proc.stop()


def throughput(workers: int, mesh: Path, batch: int, tmp: Path) -> float:
    env = service_env(tmp / f"data-tp{workers}", broker_url=SHARED_REDIS)
    api_proc, url = start_api(env, tmp, name=f"api-tp{workers}")
    procs = [start_worker(env, tmp, f"tp{workers}-{i}") for i in range(workers)]
    try:
        wait_until(lambda: workers_online(url) >= workers, 60, 0.2, "workers")
        api = Api(url)
        mesh_id = api.upload(mesh)["id"]
        for j in [api.submit(mesh_id, k=4, options={"seed": 10_000 + i}) for i in range(workers)]:
            wait_done(api, j["id"])  # warm every pool child
        t = time.perf_counter()
        jobs = [api.submit(mesh_id, k=4, options={"seed": 20_000 + i}) for i in range(batch)]
        for j in jobs:
            wait_done(api, j["id"], poll=0.05)
        return batch / (time.perf_counter() - t) * 60
    finally:
        for p in procs:
            p.stop()
        api_proc.stop()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--jobs", type=int, default=30, help="sequential jobs per latency measurement")
    parser.add_argument("--batch", type=int, default=40, help="jobs submitted at once for throughput")
    parser.add_argument("--embedded-only", action="store_true", help="latency of the embedded queue only")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="magnet-bench-"))
    mesh = square_mesh(tmp / "tiny.vtu", 8)
    rows = []
    local = in_process(mesh, args.jobs, tmp)
    rows.append(("in-process run_job", local))
    if not args.embedded_only:
        rows.append(("HTTP + Celery, Redis", through_queue(SHARED_REDIS, mesh, args.jobs, tmp, 100)))
    rows.append(("HTTP + Celery, embedded SQLite", through_queue(None, mesh, args.jobs, tmp, 1000)))
    base = statistics.median(local)
    print(f"\nsubmit-to-result of a tiny job ({args.jobs} sequential jobs, 128 triangles, METIS k=4)")
    print(f"{'path':34} {'p50 s':>8} {'p90 s':>8} {'p95 s':>8} {'overhead p50 s':>15} {'p90 s':>8}")
    base90 = pct(local, 0.90)
    for name, t in rows:
        print(
            f"{name:34} {statistics.median(t):8.3f} {pct(t, 0.90):8.3f} {pct(t, 0.95):8.3f}"
            f" {statistics.median(t) - base:15.3f} {pct(t, 0.90) - base90:8.3f}"
        )
    print(
        "(the queue rows include the first job after start-up: "
        + ", ".join(f"{k} {v:.3f} s" for k, v in FIRST.items())
        + ")"
    )
    print("\nwhere a queued job's time goes, medians in ms (jobs after the first; record timestamps)")
    print(f"{'broker':10} {'POST':>7} {'->record':>9} {'->started':>10} {'task':>7} {'->seen':>7}")
    for name, rows_ in PARTS.items():
        med = [statistics.median(c) * 1000 for c in zip(*rows_, strict=True)]
        print(
            f"{name[:10]:10} " + " ".join(f"{v:{w}.1f}" for v, w in zip(med, (7, 9, 10, 7, 7), strict=True))
        )
    if args.embedded_only:
        return
    one = throughput(1, mesh, args.batch, tmp)
    two = throughput(2, mesh, args.batch, tmp)
    print(f"\nthroughput, {args.batch} tiny jobs submitted at once (Redis)")
    print(f"{'workers':>8} {'jobs/min':>10}")
    print(f"{1:>8} {one:10.0f}\n{2:>8} {two:10.0f}")


if __name__ == "__main__":
    main()
