"""Bearer API keys: each key is a user. With no key configured every caller is the user 'anonymous'
(allowed only on a loopback address; `magnet serve` refuses other binds without keys)."""

from __future__ import annotations

import hmac
from pathlib import Path

from fastapi import HTTPException, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from jobqueue.settings import Settings

ANONYMOUS = "anonymous"
LOOPBACK_HOSTS = {"127.0.0.1", "::1", "localhost"}


def parse_keys(text: str, separator: str = ",") -> dict[str, str]:
    """'alice:tok1,bob:tok2' (or one entry per line) -> {token: user}."""
    keys: dict[str, str] = {}
    for entry in text.replace("\n", separator).split(separator):
        entry = entry.strip()
        if not entry or entry.startswith("#"):
            continue
        user, sep, token = entry.partition(":")
        if not sep or not user.strip() or not token.strip():
            raise ValueError(f"API key entry must be 'user:token', got {entry[:20]!r}...")
        keys[token.strip()] = user.strip()
    return keys


def load_keys(settings: Settings) -> dict[str, str]:
    """All configured API keys {token: user} from MAGNET_API_KEYS and MAGNET_API_KEYS_FILE."""
    keys: dict[str, str] = {}
    if settings.api_keys:
        keys.update(parse_keys(settings.api_keys))
    if settings.api_keys_file:
        keys.update(parse_keys(Path(settings.api_keys_file).read_text()))
    return keys


def user_for_token(keys: dict[str, str], token: str | None) -> str | None:
    """The user owning `token`, compared in constant time; None when unknown."""
    found = None
    for known, user in keys.items():
        if token is not None and hmac.compare_digest(known.encode(), token.encode()):
            found = user
    return found


def bearer_token(request: Request) -> str | None:
    header = request.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    if scheme.lower() == "bearer" and token.strip():
        return token.strip()
    return None


def authenticate(request: Request, token: str | None = None) -> str:
    """The caller's user name; 401 when keys are configured and the token is missing or wrong."""
    keys: dict[str, str] = request.app.state.api_keys
    if not keys:
        return ANONYMOUS
    user = user_for_token(keys, bearer_token(request) or token)
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
