"""`magnet worker`: a Celery worker for the MAGNET queues (registered through the magnet.commands
entry point, so models/cli/main.py never imports Celery)."""

from __future__ import annotations

import argparse
import os
import socket

from jobqueue.settings import Settings


def register_worker(subparsers) -> argparse.ArgumentParser:
    """Add the `worker` sub-command to the `magnet` CLI."""
    p = subparsers.add_parser(
        "worker",
        help="run a job worker (MAGNET_BROKER_URL=redis://... for a Redis deployment)",
        description="Run a Celery worker for MAGNET jobs. Configuration from MAGNET_* variables: "
        "MAGNET_BROKER_URL (default: embedded SQLite broker in MAGNET_DATA_DIR), MAGNET_DATABASE_URL, "
        "MAGNET_DATA_DIR (shared with the API).",
    )
    p.add_argument(
        "--queues",
        "-Q",
        default="cpu",
        help="comma-separated queues to consume: cpu, gpu (default: cpu). A GPU worker: -Q gpu,cpu -c 1",
    )
    p.add_argument(
        "--concurrency",
        "-c",
        type=int,
        default=1,
        help="jobs run at the same time (default 1; one per GPU on a GPU worker)",
    )
    p.add_argument("--name", "-n", default=None, help="worker node name (default magnet-<pid>@<host>)")
    p.add_argument("--data-dir", default=None, help="overrides MAGNET_DATA_DIR")
    p.add_argument("--broker-url", default=None, help="overrides MAGNET_BROKER_URL")
    p.add_argument("--database-url", default=None, help="overrides MAGNET_DATABASE_URL")
    p.add_argument(
        "--preload-models",
        action="store_true",
        help="load the neural networks when the worker starts, not at its first neural job "
        "(MAGNET_PRELOAD_MODELS=true); they stay loaded between jobs either way",
    )
    p.add_argument("--loglevel", "-l", default="INFO")
    p.set_defaults(func=run_worker)
    return p


def apply_overrides(args: argparse.Namespace) -> None:
    """Command-line overrides become MAGNET_* variables, so child processes see them too."""
    for attr, var in (
        ("data_dir", "MAGNET_DATA_DIR"),
        ("broker_url", "MAGNET_BROKER_URL"),
        ("database_url", "MAGNET_DATABASE_URL"),
    ):
        value = getattr(args, attr, None)
        if value:
            os.environ[var] = str(value)
    if getattr(args, "preload_models", False):
        os.environ["MAGNET_PRELOAD_MODELS"] = "true"


def run_worker(args: argparse.Namespace) -> int:
    apply_overrides(args)
    from worker.app import make_worker_app

    settings = Settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    app = make_worker_app(settings)
    name = args.name or f"magnet-{os.getpid()}@{socket.gethostname()}"
    print(banner(name, args.queues, args.concurrency), flush=True)
    argv = [
        "--quiet",  # no Celery banner: its queue lines ("cpu exchange=cpu(direct) key=cpu") say nothing to a user
        "worker",
        "--queues",
        args.queues,
        "--concurrency",
        str(args.concurrency),
        "--pool",
        "prefork",
        "--hostname",
        name,
        "--loglevel",
        args.loglevel,
        "--without-mingle",
        "--without-gossip",
        "--without-heartbeat",
    ]
    app.worker_main(argv)
    return 0


QUEUE_WORDS = {"cpu": "CPU jobs (every model)", "gpu": "GPU jobs (the neural models, sage-*, rl-*)"}


def banner(name: str, queues: str, concurrency: int) -> str:
    """The worker's start line in plain words (instead of Celery's banner)."""
    names = [q.strip() for q in queues.split(",") if q.strip()]
    what = ", ".join(f"{q}: {QUEUE_WORDS.get(q, 'jobs sent to this queue')}" for q in names)
    return f"magnet worker {name}: takes {what}; {concurrency} job(s) at a time"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="magnet")
    register_worker(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)
