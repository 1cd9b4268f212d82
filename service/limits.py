"""Request body size limit for every route, enforced on Content-Length and on the bytes actually
received (chunked uploads included), before any form parser spools the body to disk."""

from __future__ import annotations

import json

from starlette.exceptions import HTTPException

from service.wording import said_bytes


def too_large(file_limit: int) -> str:
    return f"request body too large: a mesh file may be at most {said_bytes(file_limit)}"


class BodyTooLarge(HTTPException):
    """Raised from receive(); an HTTPException so that body parsers pass it through as a 413."""

    def __init__(self, file_limit: int):
        super().__init__(413, too_large(file_limit))


class BodySizeLimit:
    """ASGI middleware: 413 for bodies over `max_bytes` (`form_max_bytes` for paths ending /form,
    whose base64 payload is a third larger than the file); the refusal says `file_limit`, the mesh
    file's limit that these bodies are sized for (MAGNET_MAX_UPLOAD_BYTES)."""

    def __init__(self, app, max_bytes: int, form_max_bytes: int, file_limit: int | None = None):
        self.app, self.max_bytes, self.form_max_bytes = app, max_bytes, form_max_bytes
        self.file_limit = max_bytes if file_limit is None else file_limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        limit = self.form_max_bytes if scope["path"].endswith("/form") else self.max_bytes
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = 0
                if declared > limit:
                    return await _reject(send, self.file_limit)
        received = 0
        started = False

        async def counting_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLarge(self.file_limit)
            return message

        async def tracking_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except BodyTooLarge:
            if not started:
                await _reject(send, self.file_limit)


async def _reject(send, file_limit: int) -> None:
    body = json.dumps({"detail": too_large(file_limit)}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": 413,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
