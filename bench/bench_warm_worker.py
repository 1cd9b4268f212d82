"""First vs later neural jobs on one worker (not part of the tests): does a worker keep its networks
loaded between jobs, and what does MAGNET_PRELOAD_MODELS change for the first job?

One `magnet worker` (concurrency 1, so every job runs in the same pool process) on the Redis at
127.0.0.1:6379 and the API; SAGE-Base jobs (nref 5, different seeds, so no dedup) on the brain
mesh, one after the other. Run time = the job record's finished_at - started_at (queue wait not
counted). Compared in the same run: a worker without and with preloading.
Usage: python bench/bench_warm_worker.py [--jobs 4]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from service_fixtures import (  # noqa: E402
    BRAIN,
    SHARED_REDIS,
    Api,
    service_env,
    start_api,
    start_worker,
    wait_until,
    workers_online,
)


def seconds(job: dict) -> float:
    parse = lambda s: datetime.fromisoformat(s.replace("Z", "+00:00"))  # noqa: E731
    return (parse(job["finished_at"]) - parse(job["started_at"])).total_seconds()


def run(preload: bool, jobs: int, tmp: Path) -> list[float]:
    env = service_env(tmp / "data", broker_url=SHARED_REDIS, preload_models=str(preload).lower())
    api_proc, url = start_api(env, tmp, name=f"api-{preload}")
    worker = start_worker(env, tmp, f"w-{preload}")
    try:
        wait_until(lambda: workers_online(url) >= 1, 120, 0.5, "the worker")
        api = Api(url)
        mesh = api.upload(BRAIN)
        times = []
        for seed in range(jobs):
            job = api.submit(mesh["id"], model="sage-base", mode="nref", nref=5, options={"seed": seed})
            done = api.wait(job["id"], 600)
            assert done["status"] == "succeeded", done
            times.append(seconds(done))
        return times
    finally:
        worker.stop()
        api_proc.stop()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--jobs", type=int, default=4)
    args = parser.parse_args()
    rows = []
    for preload in (False, True):
        with tempfile.TemporaryDirectory() as tmp:
            rows.append((preload, run(preload, args.jobs, Path(tmp))))
    print("SAGE-Base nref 5 on the brain (14,372 cells), one worker, jobs in a row; run time in s")
    print(
        f"{'preload':8} {'job 1':>7} "
        + " ".join(f"{'job ' + str(i + 1):>7}" for i in range(1, args.jobs))
        + f" {'job 1 / median(rest)':>22}"
    )
    for preload, t in rows:
        rest = sorted(t[1:])[len(t[1:]) // 2]
        print(
            f"{str(preload):8} {t[0]:7.2f} " + " ".join(f"{x:7.2f}" for x in t[1:]) + f" {t[0] / rest:22.2f}"
        )


if __name__ == "__main__":
    main()
