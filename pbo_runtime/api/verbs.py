"""The operator's verbs as routes, made from the command table: `POST /api/verbs/NAME`.

One route per verb of `supervisor.commands.VERBS`, whatever the table holds: the JSON body is
the verb's request (its arguments' keys, as the CLI sends them on the control queue), the answer
the supervisor's reply dict, as `pbo VERB --format json` prints it. A refusal keeps the reply's
one-line `error`; its status says why (`api.replies`): 400 the request was wrong (no such task, a
value that is not a finite number), 409 the run's state refused it, 404 no run is the one meant,
503 the supervisor did not answer. A verb the supervisor does not serve (handler None: `svar`
reads the table itself) is served here by the same code the CLI runs (`LOCAL_VERBS`). A verb's
argument that names a file (`FILE_ARGUMENTS`: where `save` writes) is taken relative to the served
folder (`files.served_root`) and refused with 403 when it leaves it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, Request
from starlette.concurrency import run_in_threadpool

from pbo_runtime.api.files import NoFile, served_root, subsystem_file, within
from pbo_runtime.api.link import NoRun, RunLink
from pbo_runtime.api.replies import BAD_REQUEST, NO_ANSWER, NO_RUN, Reply, refusal, supervisor_reply
from pbo_runtime.errors import PboError
from pbo_runtime.supervisor.commands import STATUS_TIMEOUT, VERBS, Verb
from pbo_runtime.table.snapshot import TableBusy
from pbo_runtime.table.svar import svar_rows

WRITER_NAMES_TIMEOUT = 0.5  # svar names the writers from the status reply, but never waits long for it
FILE_ARGUMENTS = {"save": "file"}  # verb -> its argument that names a file the run writes: kept in the served folder


def request_schema(verb: Verb) -> dict[str, Any]:
    """The JSON Schema of the verb's request body, from its arguments (for the OpenAPI description)."""
    properties: dict[str, Any] = {}
    for argument in verb.arguments:
        key = argument.key if argument.key is not None else (argument.dest if verb.handler is None else None)
        if key is None or argument.name.startswith("-"):
            continue
        properties[key] = {"description": argument.help or key}
        if argument.nargs == "*":
            properties[key]["type"] = "array"
    return {"type": "object", "properties": properties}


async def read_body(request: Request) -> dict[str, Any]:
    """The request's JSON object ({} when there is no body); ValueError with what was wrong."""
    raw = await request.body()
    if not raw.strip():
        return {}
    try:
        body = json.loads(raw)
    except RecursionError:
        raise ValueError("the body is not JSON a request can take: nested too deeply") from None
    except ValueError as exc:
        raise ValueError(f"the body is not JSON: {exc}") from None
    if not isinstance(body, dict):
        raise ValueError(f"the body must be a JSON object of the verb's arguments, got: {type(body).__name__}")
    return body


def confine_file(request: Request, verb: Verb, arguments: dict[str, Any]) -> None:
    """The verb's file argument made the real path it names in the served folder; OutsideRoot when it leaves it."""
    key = FILE_ARGUMENTS.get(verb.name)
    given = arguments.get(key) if key is not None else None
    if key is None or not isinstance(given, str) or not given:
        return  # none given, or not text: the supervisor refuses it in its own words
    arguments[key] = within(served_root(subsystem_file(request)), given)


def call_supervisor(link: RunLink, verb: Verb, arguments: dict[str, Any]) -> Reply:
    """One verb served by the run's supervisor over its control queue."""
    try:
        return supervisor_reply(link.request(verb.name, arguments, verb.timeout))
    except NoRun as exc:
        return refusal(NO_RUN, str(exc))
    except PboError as exc:  # no control queue (starting, stopping), no answer in time, queue memory
        return refusal(NO_ANSWER, str(exc))


# --- verbs served here, as the CLI serves them ----------------------------------------------------


def svar(link: RunLink, arguments: dict[str, Any]) -> Reply:
    """`pbo svar --format json`: the rows `pbo svar` prints (value as text, sequence, age, writer), read lock-free."""
    names = arguments.pop("names", None) or []
    if arguments:
        return refusal(BAD_REQUEST, f"'svar' takes no argument {', '.join(map(repr, arguments))} (its arguments: names)",
                       bad_request=True)
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        return refusal(BAD_REQUEST, "names must be a list of variable names", bad_request=True)
    try:
        view = link.open_table()
    except NoRun as exc:
        return refusal(NO_RUN, str(exc))
    except PboError as exc:
        return refusal(NO_ANSWER, str(exc))
    try:
        unknown = [n for n in names if n not in view.variables()]
        if unknown:
            return refusal(BAD_REQUEST, f"no variable {', '.join(map(repr, unknown))} in '{view.subsystem}' "
                                        f"(variables: {', '.join(view.variables())})", bad_request=True)
        rows = svar_rows(view, names or None, writer_names(link))
        return Reply({"ok": True, "subsystem": view.subsystem, "run_id": view.run_id, "variables": rows})
    except TableBusy as exc:
        return refusal(NO_ANSWER, str(exc))
    finally:
        view.close()


def writer_names(link: RunLink) -> dict[int, str]:
    """Task index -> name, from the status reply; {} when the supervisor does not answer in time."""
    try:
        reply = link.request("status", {}, WRITER_NAMES_TIMEOUT)
    except PboError:
        return {}
    tasks = reply.get("tasks") if reply.get("ok") else None
    return {int(t.get("index", i)): str(t["task"]) for i, t in enumerate(tasks or []) if isinstance(t, dict) and "task" in t}


LOCAL_VERBS: dict[str, Callable[[RunLink, dict[str, Any]], Reply]] = {"svar": svar}


# --- the routes -------------------------------------------------------------------------------------


def verb_route(verb: Verb) -> Callable[[Request], Any]:
    async def route(request: Request) -> Reply:
        link: RunLink = request.app.state.link
        try:
            arguments = await read_body(request)
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)
        try:
            await run_in_threadpool(confine_file, request, verb, arguments)
        except NoFile as exc:
            return refusal(NO_RUN, f"refused: no folder to write in: {exc}")
        if verb.handler is None:
            return await run_in_threadpool(LOCAL_VERBS[verb.name], link, arguments)
        return await run_in_threadpool(call_supervisor, link, verb, arguments)  # waits on the control queue

    route.__name__ = f"verb_{verb.name}"
    return route


def router() -> APIRouter:
    """A route per verb of the command table, and the list of live runs."""
    routes = APIRouter(prefix="/api", tags=["verbs"])
    for verb in VERBS:
        routes.add_api_route(f"/verbs/{verb.name}", verb_route(verb), methods=["POST"], summary=verb.help,
                             description=f"`pbo {verb.name}`: {verb.help}. Reply besides `\"ok\": true`: {verb.result}.",
                             openapi_extra={"requestBody": {"required": False, "content": {
                                 "application/json": {"schema": request_schema(verb)}}}})

    @routes.get("/runs", summary="your live runs (pbo runs)")
    def runs(request: Request) -> Reply:
        return Reply({"ok": True, "runs": request.app.state.link.runs()})

    return routes


__all__ = ["LOCAL_VERBS", "STATUS_TIMEOUT", "router"]
