"""The API's outer wall: limits on what a request may send, and the last resort for a bug.

An ASGI middleware around the whole app (`api.app`). Before any route runs, a body larger than
`MAX_BODY_BYTES` is refused with 413 (by its Content-Length when it gives one, else while it is
read), and a JSON body nested deeper than `MAX_JSON_DEPTH` with 400: every route then parses a
body small and flat enough to be harmless. An exception no route caught (a bug) is logged as one
line with a reference, and answered 500 `{"ok": false, "error": "... reference ..."}`: never a
traceback in the terminal, and a client can quote the reference.
"""

from __future__ import annotations

import json
import logging
import uuid
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from pbo_runtime.api.replies import BAD_REQUEST, TOO_LARGE, refusal

MAX_BODY_BYTES = 1 << 20  # a request carries a subsystem file at most, or a verb's arguments
MAX_JSON_DEPTH = 32  # a verb's arguments, a canvas, a workspace's row or an object's value nest a few levels
# parsed by the YAML loader, which has its limits
TEXT_TYPES = ("text/plain", "application/yaml", "application/x-yaml", "text/yaml")

log = logging.getLogger("pbo_runtime.api")


class BodyRefused(Exception):
    """The request's body is over a limit: the status and the one-line reason."""

    def __init__(self, status: int, error: str) -> None:
        super().__init__(error)
        self.status = status
        self.error = error


def json_depth(value: Any, limit: int) -> int:
    """How deeply lists and objects nest in `value` (a scalar is 0), counted without recursion and
    at most to `limit` + 1."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (list, dict)):
            deepest = max(deepest, depth)
            if deepest > limit:
                break
            stack.extend((child, depth + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest


def check_json(raw: bytes, content_type: str) -> None:
    """BodyRefused when a body that is JSON nests deeper than MAX_JSON_DEPTH; text that is not
    JSON is the route's to refuse, in its own words."""
    if not raw.strip() or content_type.split(";", 1)[0].strip().lower() in TEXT_TYPES:
        return
    try:
        body = json.loads(raw)
    except RecursionError:
        body = None
    except ValueError:
        return
    else:
        if json_depth(body, MAX_JSON_DEPTH) <= MAX_JSON_DEPTH:
            return
    raise BodyRefused(BAD_REQUEST, f"the JSON body nests deeper than {MAX_JSON_DEPTH} levels of lists and objects; "
                                   "no request needs that many")


async def read_body(scope: Scope, receive: Receive) -> bytes:
    """The whole body, refused (BodyRefused, 413) as soon as it is over MAX_BODY_BYTES."""
    too_large = f"the body is over {MAX_BODY_BYTES:,} bytes, the most a request may send"
    headers = dict(scope.get("headers") or [])
    declared = headers.get(b"content-length", b"").strip()
    if declared.isdigit() and int(declared) > MAX_BODY_BYTES:
        raise BodyRefused(TOO_LARGE, too_large)
    chunks: list[bytes] = []
    size = 0
    while True:
        message = await receive()
        if message["type"] != "http.request":
            break  # the client left: the route sees the empty body, and the server the disconnect
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > MAX_BODY_BYTES:
            raise BodyRefused(TOO_LARGE, too_large)
        chunks.append(chunk)
        if not message.get("more_body", False):
            break
    return b"".join(chunks)


def one_line(text: str, limit: int = 300) -> str:
    flat = " ".join(text.split())
    return flat if len(flat) <= limit else flat[: limit - 3] + "..."


class Guard:
    """The middleware: limits on the body, and one logged line instead of a traceback for a bug."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        started = False

        async def tracked(message: Message) -> None:
            nonlocal started
            if message["type"] in ("http.response.start", "websocket.accept", "websocket.close"):
                started = True
            await send(message)

        try:
            if scope["type"] == "http":
                receive = await self.checked_body(scope, receive)
            await self.app(scope, receive, tracked)
        except BodyRefused as exc:
            await refusal(exc.status, exc.error)(scope, receive, send)
        except Exception as exc:  # a bug: said in one line, answered 500 if nothing was sent yet
            reference = uuid.uuid4().hex[:12]
            log.error("pbo hmi: internal error %s on %s %s: %s", reference, scope.get("method", "WEBSOCKET"),
                      one_line(scope.get("path", ""), 120), one_line(repr(exc)))
            if not started and scope["type"] == "http":
                await refusal(500, f"internal error {reference} (a bug of pbo hmi; its terminal has the same "
                                   "reference): please report it with the request")(scope, receive, send)
            elif not started:
                await send({"type": "websocket.close", "code": 1011, "reason": f"internal error {reference}"})

    @staticmethod
    async def checked_body(scope: Scope, receive: Receive) -> Receive:
        """A `receive` that replays the body, read and checked against the limits first."""
        raw = await read_body(scope, receive)
        content_type = dict(scope.get("headers") or []).get(b"content-type", b"").decode("latin-1")
        check_json(raw, content_type)
        sent = False

        async def replay() -> Message:
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": raw, "more_body": False}
            return await receive()

        return replay
