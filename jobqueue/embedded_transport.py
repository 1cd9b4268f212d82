"""The embedded broker: kombu's SQLAlchemy transport on a SQLite file, tuned for one machine.

Two changes to kombu's transport: a short polling interval is accepted (kombu would hand it to
create_engine), and a message is deleted when delivered instead of kept forever as invisible.
Delivery is at-most-once from the broker's side; the reaper re-sends jobs whose worker died.

Wake-up: a consuming process binds a Unix datagram socket in `<broker file>.wake/` (in the temp
folder when that path is too long for a socket) and, between empty polls, waits on it instead of
sleeping; a publisher sends one byte to every socket there after its commit. A job then waits for
pick-up about a millisecond, not half a polling interval. Polling stays as the fallback: every
WOKEN_POLL_S with a socket, the configured interval without one (no AF_UNIX, no socket could be
bound). The Redis deployment does not use this file (same tasks, only the broker differs).
URL: magnetsql+sqlite:///path/to/broker.sqlite (registered as a kombu transport alias on import).
"""

from __future__ import annotations

import hashlib
import os
import socket
import tempfile
from json import dumps, loads
from pathlib import Path
from queue import Empty
from select import select as wait_readable
from time import monotonic

from kombu.transport import TRANSPORT_ALIASES
from kombu.transport import sqlalchemy as sqla
from kombu.utils.encoding import bytes_to_str
from sqlalchemy import create_engine, delete, event, insert, select, text
from sqlalchemy.exc import OperationalError

ALIAS = "magnetsql"
ENGINE_OPTIONS = ("connect_args", "pool_pre_ping", "pool_recycle")
SOCKET_PATH_MAX = 100  # sun_path is 108 bytes on Linux, 104 on macOS
WOKEN_POLL_S = 1.0  # the polling interval of a consumer that has a wake-up socket
SOCKET_NAME_MAX = 32  # "/<pid>-<8 hex>.sock"


def wake_dir(url: str) -> Path | None:
    """The folder of wake-up sockets of the SQLite broker at `url` (None: not a SQLite file): next
    to the broker file, or in the temporary folder, named after the broker's path, when that path
    is too long for a socket address."""
    prefix = "sqlite:///"
    if not url.startswith(prefix) or url[len(prefix) :] in ("", ":memory:"):
        return None
    broker = os.path.abspath(url[len(prefix) :])
    folder = broker + ".wake"
    if len(folder.encode()) + SOCKET_NAME_MAX > SOCKET_PATH_MAX:
        digest = hashlib.sha256(broker.encode()).hexdigest()[:16]
        folder = os.path.join(
            tempfile.gettempdir(), f"magnet-wake-{os.getuid() if hasattr(os, 'getuid') else 0}-{digest}"
        )
    return Path(folder)


def wake_consumers(folder: Path | None) -> None:
    """Tell every consumer waiting on `folder` that a message was committed (best effort: a consumer
    that misses it finds the message at its next poll). Sockets nobody listens on are removed."""
    if folder is None or not hasattr(socket, "AF_UNIX"):
        return
    try:
        names = [n for n in os.listdir(folder) if n.endswith(".sock")]
    except OSError:
        return
    if not names:
        return
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
        s.setblocking(False)
        for name in names:
            path = os.path.join(folder, name)
            try:
                s.sendto(b"1", path)
            except (ConnectionRefusedError, FileNotFoundError):
                try:
                    os.unlink(path)  # its process is gone
                except OSError:
                    pass
            except OSError:
                pass  # its buffer is full: it has wake-ups pending already


class Waker:
    """The consumer's end: a datagram socket to wait on between empty polls."""

    def __init__(self, folder: Path | None):
        self.sock = self.path = None
        if folder is None or not hasattr(socket, "AF_UNIX"):
            return
        path = str(folder / f"{os.getpid()}-{os.urandom(4).hex()}.sock")
        if len(path.encode()) > SOCKET_PATH_MAX:
            return
        try:
            folder.mkdir(mode=0o700, exist_ok=True)
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            sock.bind(path)
            sock.setblocking(False)
        except OSError:
            return
        self.sock, self.path, self.pid = sock, path, os.getpid()

    def wait(self, timeout: float) -> bool:
        """Return when woken (True) or after `timeout` seconds (False)."""
        if self.sock is None or self.pid != os.getpid():
            wait_readable([], [], [], timeout)
            return False
        readable, _, _ = wait_readable([self.sock], [], [], timeout)
        if readable:
            self.drain()
        return bool(readable)

    def drain(self) -> None:
        if self.sock is None or self.pid != os.getpid():
            return
        try:
            while self.sock.recv(64):
                pass
        except OSError:
            pass

    def close(self) -> None:
        if self.sock is not None and self.pid == os.getpid():
            self.sock.close()
            try:
                os.unlink(self.path)
            except OSError:
                pass
        self.sock = None


def _sqlite_pragmas(dbapi_connection, _record) -> None:
    """Write-ahead log, synced at checkpoints: a publish or a take costs no fsync of its own (with
    the default rollback journal each one cost several, tens of ms on a busy disk). A crash of the
    machine may lose the last messages; the reaper re-sends jobs that stay queued."""
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.close()


class Channel(sqla.Channel):
    def _engine_from_config(self):
        conninfo = self.connection.client
        options = {k: v for k, v in conninfo.transport_options.items() if k in ENGINE_OPTIONS}
        engine = create_engine(conninfo.hostname, **options)
        if engine.dialect.name == "sqlite":
            event.listen(engine, "connect", _sqlite_pragmas)
        return engine

    def _queue_id(self, queue: str) -> int:
        """The queue's row id, looked up once per channel (kombu's transport queries it by name on
        every publish and every poll; queue rows are never deleted)."""
        ids = self.__dict__.setdefault("_queue_ids", {})
        if queue not in ids:
            ids[queue] = self._get_or_create(queue).id
        return ids[queue]

    def _put(self, queue, payload, **kwargs):
        """One INSERT through SQLAlchemy Core (kombu's goes through the ORM's unit of work), then
        a wake-up for the consumers."""
        qid = self._queue_id(queue)
        try:
            self.session.execute(
                insert(self.message_cls.__table__).values(payload=dumps(payload), queue_id=qid)
            )
            self.session.commit()
        except OperationalError:
            self.session.rollback()  # the publish fails (and may be retried); nothing was stored
            raise
        wake_consumers(wake_dir(self.connection.client.hostname))

    def _get(self, queue):
        """Take the oldest visible message and delete it, in one write transaction."""
        qid = self._queue_id(queue)
        m = self.message_cls
        if self.session.bind.name == "sqlite":
            self.session.execute(text("BEGIN IMMEDIATE TRANSACTION"))
        try:
            row = self.session.execute(
                select(m.id, m.payload)
                .where(m.queue_id == qid, m.visible != False)  # noqa: E712
                .order_by(m.sent_at, m.id)
                .limit(1)
            ).first()
            if row is None:
                raise Empty()
            self.session.execute(delete(m.__table__).where(m.__table__.c.id == row.id))
            return loads(bytes_to_str(row.payload))
        finally:
            self.session.commit()


class Transport(sqla.Transport):
    Channel = Channel
    _waker: Waker | None = None

    def drain_events(self, connection, timeout=None):
        """kombu's loop, with the sleep between empty polls replaced by a wait on the wake-up socket."""
        if self._waker is None:
            self._waker = Waker(wake_dir(self.client.hostname))
        start = monotonic()
        interval = self.polling_interval or 0.05
        if self._waker.sock is not None:
            interval = max(interval, WOKEN_POLL_S)  # a publish wakes us: poll rarely, as a fallback
        if timeout:
            interval = min(interval, timeout)
        while True:
            self._waker.drain()  # a wake-up from before this poll is answered by the poll itself
            try:
                self.cycle.get(self._deliver, timeout=timeout)
                return
            except Empty:
                if timeout is not None and monotonic() - start >= timeout:
                    raise TimeoutError() from None
                self._waker.wait(interval)

    def close_connection(self, connection):
        if self._waker is not None:
            self._waker.close()
            self._waker = None
        super().close_connection(connection)


TRANSPORT_ALIASES[ALIAS] = f"{__name__}:Transport"
