"""The embedded broker: kombu's SQLAlchemy transport on a SQLite file, tuned for one machine.

Two changes to kombu's transport: a short polling interval is accepted (kombu would hand it to
create_engine), and a message is deleted when delivered instead of kept forever as invisible.
Delivery is at-most-once from the broker's side; the reaper re-sends jobs whose worker died.
URL: magnetsql+sqlite:///path/to/broker.sqlite (registered as a kombu transport alias on import).
"""

from __future__ import annotations

from json import loads
from queue import Empty

from kombu.transport import TRANSPORT_ALIASES
from kombu.transport import sqlalchemy as sqla
from kombu.utils.encoding import bytes_to_str
from sqlalchemy import create_engine, event, text

ALIAS = "magnetsql"
ENGINE_OPTIONS = ("connect_args", "pool_pre_ping", "pool_recycle")


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

    def _get(self, queue):
        obj = self._get_or_create(queue)
        if self.session.bind.name == "sqlite":
            self.session.execute(text("BEGIN IMMEDIATE TRANSACTION"))
        try:
            msg = (
                self.session.query(self.message_cls)
                .filter(self.message_cls.queue_id == obj.id, self.message_cls.visible != False)  # noqa: E712
                .order_by(self.message_cls.sent_at, self.message_cls.id)
                .limit(1)
                .first()
            )
            if msg is None:
                raise Empty()
            payload = loads(bytes_to_str(msg.payload))
            self.session.delete(msg)
            return payload
        finally:
            self.session.commit()


class Transport(sqla.Transport):
    Channel = Channel


TRANSPORT_ALIASES[ALIAS] = f"{__name__}:Transport"
