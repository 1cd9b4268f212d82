"""API keys kept as SHA-256 hashes, never in plain text: in the job store (managed with
`magnet keys add|list|revoke`, seen by a running API at its next request) and, as before, from
MAGNET_API_KEYS / MAGNET_API_KEYS_FILE (whose entries may be `user:sha256:<hex>` hashes).

A key is 32 random bytes (URL-safe text): a plain SHA-256 of it is as hard to invert as the key is
to guess, so no slow password hash is needed, and a lookup by hash compares no secret.
"""

from __future__ import annotations

import hashlib
import secrets

from sqlalchemy import select, update

from jobqueue.db import ApiKey, Database, new_id, utcnow

PREFIX = "mk_"


def digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def add_key(db: Database, user: str, note: str = "") -> tuple[str, str]:
    """A new key for `user`: (key id, the key itself, shown this once)."""
    if not user or ":" in user or any(ord(c) < 32 for c in user) or len(user) > 200:
        raise ValueError("user names are 1-200 printable characters without ':'")
    token = PREFIX + secrets.token_urlsafe(32)
    key_id = new_id()[:12]
    with db.session() as s:
        s.add(ApiKey(id=key_id, user=user, sha256=digest(token), note=note[:200], created_at=utcnow()))
        s.commit()
    return key_id, token


def list_keys(db: Database) -> list[ApiKey]:
    with db.session() as s:
        return list(s.scalars(select(ApiKey).order_by(ApiKey.user, ApiKey.created_at)))


def revoke(db: Database, id_or_user: str) -> int:
    """Revoke the key with this id, or every key of this user; returns how many were revoked."""
    with db.session() as s:
        n = s.execute(
            update(ApiKey)
            .where((ApiKey.id == id_or_user) | (ApiKey.user == id_or_user), ApiKey.revoked_at.is_(None))
            .values(revoked_at=utcnow())
        ).rowcount
        s.commit()
    return n


def user_of(db: Database, token: str) -> str | None:
    """The user of an active stored key, or None."""
    with db.session() as s:
        return s.scalar(
            select(ApiKey.user).where(ApiKey.sha256 == digest(token), ApiKey.revoked_at.is_(None))
        )


def any_stored(db: Database) -> bool:
    """Keys are in use once one was ever added: revoking every key locks everyone out, it does not
    reopen the server to anonymous callers."""
    with db.session() as s:
        return s.scalar(select(ApiKey.id).limit(1)) is not None
