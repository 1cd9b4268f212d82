"""Errors readable by GNU Octave: its webread/webwrite drop the body of any 4xx/5xx answer
("HTTP response code said error"). A request with header `X-Magnet-Errors: body` or query parameter
`errors=body` gets error answers as 200 with the JSON body {"detail": ..., "status": <real status>};
the Matlab wrapper checks for `detail`. (Octave 7 can send only one header, which the wrapper spends
on the API key, hence the query parameter.) Every other client sees ordinary status codes."""

from __future__ import annotations

import json
from urllib.parse import parse_qsl

HEADER = b"x-magnet-errors"


def wants_errors_in_body(scope) -> bool:
    if dict(scope.get("headers", [])).get(HEADER) == b"body":
        return True
    query = scope.get("query_string", b"")
    return b"errors=body" in query and ("errors", "body") in parse_qsl(query.decode("latin-1"))


class ErrorsInBody:
    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or not wants_errors_in_body(scope):
            return await self.app(scope, receive, send)
        held: dict = {}

        async def rewriting_send(message):
            if message["type"] == "http.response.start" and message["status"] >= 400:
                held["start"], held["body"] = message, b""
                return
            if "start" not in held:
                return await send(message)
            held["body"] += message.get("body", b"")
            if message.get("more_body"):
                return
            try:
                payload = json.loads(held["body"] or b"{}")
            except ValueError:
                payload = {"detail": held["body"].decode(errors="replace")}
            if not isinstance(payload, dict):
                payload = {"detail": payload}
            payload["status"] = held["start"]["status"]
            body = json.dumps(payload).encode()
            headers = [
                (k, v)
                for k, v in held["start"].get("headers", [])
                if k not in (b"content-length", b"content-type")
            ]
            headers += [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
            await send({"type": "http.response.start", "status": 200, "headers": headers})
            await send({"type": "http.response.body", "body": body})

        await self.app(scope, receive, rewriting_send)
