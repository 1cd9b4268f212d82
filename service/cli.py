"""`magnet serve`: the HTTP API, plus (by default) a job worker on the embedded broker, in one command.

Registered through the magnet.commands entry point, so models/cli/main.py never imports the service.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import subprocess
import sys
import threading
import time

from jobqueue.settings import Settings
from service.auth import LOOPBACK_HOSTS, load_keys

log = logging.getLogger("magnet.serve")


def register_serve(subparsers) -> argparse.ArgumentParser:
    """Add the `serve` sub-command to the `magnet` CLI."""
    p = subparsers.add_parser(
        "serve",
        help="run the HTTP API (and an embedded job worker)",
        description="Serve the MAGNET HTTP API (OpenAPI at /docs). By default also starts a job worker "
        "on the embedded SQLite broker: no external server needed. Configuration from MAGNET_* "
        "variables (MAGNET_DATA_DIR, MAGNET_BROKER_URL, MAGNET_DATABASE_URL, MAGNET_API_KEYS, "
        "MAGNET_API_KEYS_FILE, ...). Bound to a non-loopback address it refuses to start without API keys.",
    )
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--data-dir", default=None, help="overrides MAGNET_DATA_DIR (default ./var)")
    p.add_argument("--broker-url", default=None, help="overrides MAGNET_BROKER_URL")
    p.add_argument("--database-url", default=None, help="overrides MAGNET_DATABASE_URL")
    p.add_argument(
        "--api-keys-file", default=None, help="overrides MAGNET_API_KEYS_FILE ('user:token' lines)"
    )
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        help="jobs the embedded worker runs at the same time (default 1); 0 = no embedded worker",
    )
    p.add_argument(
        "--no-worker", action="store_true", help="API only (workers run elsewhere: `magnet worker`)"
    )
    p.add_argument("--log-level", default="info")
    p.set_defaults(func=run_serve)
    if "keys" not in subparsers.choices:  # `magnet keys` rides on the serve entry point
        register_keys(subparsers)
    return p


def check_bind(host: str, settings: Settings) -> None:
    """Refuse to serve on a non-loopback address without API keys."""
    if host not in LOOPBACK_HOSTS and not load_keys(settings) and not _stored_keys(settings):
        raise SystemExit(
            f"magnet serve: refusing to listen on {host} without API keys; set MAGNET_API_KEYS "
            "('user:token,...') or MAGNET_API_KEYS_FILE, add one with `magnet keys add USER`, or bind to "
            "127.0.0.1"
        )


def _stored_keys(settings: Settings) -> bool:
    from jobqueue.db import Database
    from service.keys import any_stored

    db = Database(settings.resolved_database_url)
    db.create_schema()
    return any_stored(db)


def register_keys(subparsers) -> argparse.ArgumentParser:
    """Add `magnet keys add|list|revoke` (API keys in the job store, hashed; no API restart needed)."""
    p = subparsers.add_parser(
        "keys",
        help="manage API keys (add USER | list | revoke ID_OR_USER)",
        description="API keys live in the job store (MAGNET_DATABASE_URL, default SQLite in MAGNET_DATA_DIR) "
        "as SHA-256 hashes: a running API sees a change at its next request. `add` prints the new key "
        "once; it cannot be shown again.",
    )
    p.add_argument("action", choices=("add", "list", "revoke"))
    p.add_argument("who", nargs="?", help="add: the user name; revoke: a key id or a user (all their keys)")
    p.add_argument("--note", default="", help="add: a note shown by `list` (e.g. where the key is used)")
    p.add_argument("--data-dir", default=None, help="overrides MAGNET_DATA_DIR")
    p.add_argument("--database-url", default=None, help="overrides MAGNET_DATABASE_URL")
    p.set_defaults(func=run_keys)
    return p


def run_keys(args: argparse.Namespace) -> int:
    from jobqueue.db import Database
    from service import keys

    for attr, var in (("data_dir", "MAGNET_DATA_DIR"), ("database_url", "MAGNET_DATABASE_URL")):
        if getattr(args, attr, None):
            os.environ[var] = str(getattr(args, attr))
    settings = Settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    db = Database(settings.resolved_database_url)
    db.create_schema()
    if args.action in ("add", "revoke") and not args.who:
        print(
            f"magnet keys {args.action}: say which {'user' if args.action == 'add' else 'key id or user'}",
            file=sys.stderr,
        )
        return 2
    if args.action == "add":
        try:
            key_id, token = keys.add_key(db, args.who, args.note)
        except ValueError as exc:
            print(f"magnet keys add: {exc}", file=sys.stderr)
            return 2
        print(f"key {key_id} for {args.who}: {token}")
        print("(shown once: only its hash is stored)", file=sys.stderr)
    elif args.action == "list":
        for k in keys.list_keys(db):
            state = f"revoked {k.revoked_at:%Y-%m-%d %H:%M}" if k.revoked_at else "active"
            print(f"{k.id}  {k.user:<20} {k.created_at:%Y-%m-%d %H:%M}  {state}  {k.note}".rstrip())
    else:
        n = keys.revoke(db, args.who)
        if not n:
            print(f"magnet keys revoke: no active key with id or user {args.who!r}", file=sys.stderr)
            return 2
        print(f"revoked {n} key(s)")
    return 0


class EmbeddedWorker:
    """A `magnet worker` child process, restarted if it dies, stopped with the server."""

    def __init__(self, concurrency: int, log_level: str):
        self.cmd = [
            sys.executable,
            "-m",
            "worker",
            "worker",
            "--queues",
            "cpu,gpu",
            "--concurrency",
            str(concurrency),
            "--loglevel",
            log_level.upper(),
        ]
        self.proc: subprocess.Popen | None = None
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._supervise, daemon=True, name="embedded-worker")

    def start(self) -> None:
        self.thread.start()

    def _supervise(self) -> None:
        from service.mesh_check import child_env

        backoff = 1.0
        while not self.stopping.is_set():
            started = time.monotonic()
            self.proc = subprocess.Popen(self.cmd, env=child_env(), preexec_fn=_die_with_parent)
            self.proc.wait()
            if self.stopping.is_set():
                break
            log.warning("embedded worker exited with %s; restarting", self.proc.returncode)
            backoff = 1.0 if time.monotonic() - started > 60 else min(backoff * 2, 30)
            self.stopping.wait(backoff)

    def stop(self) -> None:
        self.stopping.set()
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def _die_with_parent() -> None:
    """Linux: the worker gets SIGTERM if `magnet serve` dies without cleaning up (kill -9)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def run_serve(args: argparse.Namespace) -> int:
    for attr, var in (
        ("data_dir", "MAGNET_DATA_DIR"),
        ("broker_url", "MAGNET_BROKER_URL"),
        ("database_url", "MAGNET_DATABASE_URL"),
        ("api_keys_file", "MAGNET_API_KEYS_FILE"),
    ):
        if getattr(args, attr, None):
            os.environ[var] = str(getattr(args, attr))
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    settings = Settings()
    check_bind(args.host, settings)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    import uvicorn

    worker = None
    if not args.no_worker and args.workers > 0:
        worker = EmbeddedWorker(args.workers, args.log_level)
        worker.start()

        def stop(signum, _frame):  # uvicorn re-raises the signal after its graceful shutdown
            worker.stop()
            raise SystemExit(128 + signum)

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)
    try:
        uvicorn.run(
            "service.app:create_app",
            factory=True,
            host=args.host,
            port=args.port,
            log_level=args.log_level.lower(),
            timeout_keep_alive=30,
            timeout_graceful_shutdown=10,  # open event streams (GET /v1/jobs/{id}/events) end here
        )
    finally:
        if worker:
            worker.stop()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="magnet")
    register_serve(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)
