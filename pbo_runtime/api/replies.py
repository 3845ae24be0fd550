"""Replies as JSON: numpy values as numbers and lists, non-finite floats as null, refusals as 4xx/5xx.

Every answer of the API is a JSON object with `"ok"`, as the supervisor's replies are: `{"ok": true,
...}`, or `{"ok": false, "error": "one line"}` with the HTTP status saying whose fault it was.
"""

from __future__ import annotations

import json
from typing import Any

from fastapi.responses import JSONResponse

from pbo_runtime.api.jsonable import jsonable

# What a refusal's status says: the request was wrong, the run's state refused it, there is no run,
# the run did not answer.
BAD_REQUEST, REFUSED, NO_RUN, NO_ANSWER = 400, 409, 404, 503


class Reply(JSONResponse):
    """A JSON response whose content may hold numpy values and non-finite floats."""

    def render(self, content: Any) -> bytes:
        return json.dumps(jsonable(content), ensure_ascii=False, separators=(",", ":")).encode("utf-8")


def refusal(status: int, error: str, **extra: Any) -> Reply:
    return Reply({"ok": False, "error": error, **extra}, status_code=status)


def supervisor_reply(reply: dict[str, Any]) -> Reply:
    """The supervisor's reply as it came: 200 when done, 400 when the request was wrong, 409 when the run refused."""
    if reply.get("ok"):
        return Reply(reply)
    return Reply(reply, status_code=BAD_REQUEST if reply.get("bad_request") else REFUSED)
