"""Bearer API keys: each key is a user. Keys come from the job store (`magnet keys add|list|revoke`,
seen by the running API at once) and from MAGNET_API_KEYS / MAGNET_API_KEYS_FILE; only SHA-256
hashes are kept in memory and on disk (a keys file may hold `user:sha256:<hex>` entries). With no
key configured every caller is the user 'anonymous' (allowed only on a loopback address;
`magnet serve` refuses other binds without keys)."""

from __future__ import annotations

import re
from pathlib import Path

from fastapi import HTTPException, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from jobqueue.settings import Settings
from service.keys import any_stored, digest
from service.keys import user_of as stored_user

ANONYMOUS = "anonymous"
LOOPBACK_HOSTS = {"127.0.0.1", "::1", "localhost"}


HASHED = re.compile(r"sha256:([0-9a-fA-F]{64})")


def parse_keys(text: str, separator: str = ",") -> dict[str, str]:
    """'alice:tok1,bob:sha256:<hex>' (or one entry per line) -> {sha256 of the token: user}."""
    keys: dict[str, str] = {}
    for entry in text.replace("\n", separator).split(separator):
        entry = entry.strip()
        if not entry or entry.startswith("#"):
            continue
        user, sep, token = entry.partition(":")
        if not sep or not user.strip() or not token.strip():
            raise ValueError(f"API key entry must be 'user:token', got {entry[:20]!r}...")
        hashed = HASHED.fullmatch(token.strip())
        keys[hashed.group(1).lower() if hashed else digest(token.strip())] = user.strip()
    return keys


def load_keys(settings: Settings) -> dict[str, str]:
    """API keys {sha256: user} from MAGNET_API_KEYS and MAGNET_API_KEYS_FILE."""
    keys: dict[str, str] = {}
    if settings.api_keys:
        keys.update(parse_keys(settings.api_keys))
    if settings.api_keys_file:
        keys.update(parse_keys(Path(settings.api_keys_file).read_text()))
    return keys


def user_for_token(keys: dict[str, str], token: str | None) -> str | None:
    """The user owning `token` (looked up by its hash: no secret is compared); None when unknown."""
    return keys.get(digest(token)) if token else None


def bearer_token(request: Request) -> str | None:
    header = request.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    if scheme.lower() == "bearer" and token.strip():
        return token.strip()
    return None


def authenticate(request: Request, token: str | None = None) -> str:
    """The caller's user name; 401 when keys are configured and the token is missing or wrong."""
    keys: dict[str, str] = request.app.state.api_keys
    db = request.app.state.ctx.db
    presented = bearer_token(request) or token
    user = user_for_token(keys, presented) or (stored_user(db, presented) if presented else None)
    if user is None and not keys and not any_stored(db):
        return ANONYMOUS
    if user is None:
        raise HTTPException(
            401,
            "missing or invalid API key (send 'Authorization: Bearer <key>')",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return user


# documents the scheme (the Authorize button in /docs); authenticate() reads the header itself
bearer_scheme = HTTPBearer(
    auto_error=False,
    scheme_name="APIKey",
    description="`Authorization: Bearer <API key>`; not needed when the server runs without keys.",
)


def current_user(
    request: Request, _credentials: HTTPAuthorizationCredentials | None = Security(bearer_scheme)
) -> str:
    """FastAPI dependency: the authenticated user of this request."""
    return authenticate(request)
