"""Replies as JSON: numpy values as numbers and lists, non-finite floats as null, refusals as 4xx/5xx.

Every answer of the API is a JSON object with `"ok"`, as the supervisor's replies are: `{"ok": true,
...}`, or `{"ok": false, "error": "one line"}` with the HTTP status saying whose fault it was.
"""

from __future__ import annotations

import json
from typing import Any, Literal

from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict

from pbo_runtime.api.jsonable import jsonable

# What a refusal's status says: the request was wrong, the run's state refused it, there is no run,
# the run did not answer; a path outside the served tree, a body over the size limit.
BAD_REQUEST, REFUSED, NO_RUN, NO_ANSWER = 400, 409, 404, 503
FORBIDDEN, TOO_LARGE = 403, 413


class Refusal(BaseModel):
    """What every refusal answers: `ok` false and the reason in one line (some add keys, such as `bad_request`)."""

    model_config = ConfigDict(extra="allow")
    ok: Literal[False]
    error: str


class Answer(BaseModel):
    """What every JSON answer of a route that did what was asked holds: `ok` true, and the route's own keys."""

    model_config = ConfigDict(extra="allow")
    ok: Literal[True]


# Every status a route may refuse with, for the OpenAPI description (each route's own answers are in its summary).
REFUSALS: dict[int | str, dict[str, Any]] = {200: {"model": Answer, "description": "done: `ok` true and the route's keys"}}
REFUSALS |= {status: {"model": Refusal, "description": what} for status, what in (
    (BAD_REQUEST, "the request was wrong (a bad body or parameter, no such task, a file that does not check)"),
    (401, "no token, or a wrong one"),
    (FORBIDDEN, "a path that leaves the folder the server reads and writes"),
    (NO_RUN, "no run is the one meant, or no subsystem file"),
    (REFUSED, "the run's state refused it"),
    (TOO_LARGE, "the body is over the size limit"),
    (500, "a bug of the server, with a reference its terminal logged"),
    (NO_ANSWER, "the supervisor did not answer in time"),
)}


class Reply(JSONResponse):
    """A JSON response whose content may hold numpy values and non-finite floats."""

    def render(self, content: Any) -> bytes:
        text = json.dumps(jsonable(content), ensure_ascii=False, separators=(",", ":"))
        return text.encode("utf-8", "replace")  # a lone surrogate (YAML can write "\ud800") cannot be UTF-8: "?"


def refusal(status: int, error: str, **extra: Any) -> Reply:
    return Reply({"ok": False, "error": error, **extra}, status_code=status)


def supervisor_reply(reply: dict[str, Any]) -> Reply:
    """The supervisor's reply as it came: 200 when done, 400 when the request was wrong, 409 when the run refused."""
    if reply.get("ok"):
        return Reply(reply)
    return Reply(reply, status_code=BAD_REQUEST if reply.get("bad_request") else REFUSED)
