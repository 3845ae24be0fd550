"""The user level's routes (Onika §4.4): save an application or an object's value, run an application.

    POST /api/workspace/applications  {"name": str, "row": [{"name", "object"}, ...], "replace": bool}
                                      the workspace's row written to the file under applications:
                                      (a row with gaps too: an incomplete application, reusable)
    POST /api/workspace/objects       {"name": str, "value": number or nested list}
                                      a named object's value, checked against its type, written
    POST /api/workspace/run           {"name": str, "row": [...]}: the row run on the attached run
                                      (`pbo app NAME --steps`, checked first by the run), its named
                                      objects given as their values in the file now

Every save is checked like `pbo check` before it replaces the file, and answers with the new job
dictionary. The file written is the one `pbo hmi FILE` was given, or the run's own
(`files.subsystem_file`), never a path from the request, and nothing outside its folder is read.
Refusals: 400 (the row or value is wrong, or the file would not check clean), 409 (the run refused),
404 (no file, or no run).
"""

from __future__ import annotations

import threading
from typing import Any

from fastapi import APIRouter, Request
from pydantic import BaseModel
from starlette.concurrency import run_in_threadpool

from pbo_runtime.api.files import NoFile, in_tree, loaded, subsystem_file
from pbo_runtime.api.link import NoRun, RunLink
from pbo_runtime.api.replies import BAD_REQUEST, NO_ANSWER, NO_RUN, Reply, refusal, supervisor_reply
from pbo_runtime.config.loader import CheckResult
from pbo_runtime.edit.job_dictionary import job_dictionary
from pbo_runtime.edit.workspace import RowRefused, check_name, checked_row, file_steps, run_steps
from pbo_runtime.edit.workspace_file import SaveRefused, save_application, save_object
from pbo_runtime.errors import PboError
from pbo_runtime.supervisor.commands import COMMANDS

_writing = threading.Lock()  # one save at a time: each reads the file, changes it, and writes it back


class ApplicationBody(BaseModel):
    name: str
    row: list[Any]
    replace: bool = False


class ObjectBody(BaseModel):
    name: str
    value: Any


class RunBody(BaseModel):
    name: str = "workspace"
    row: list[Any]


def saved_reply(file: str, result: CheckResult, message: str) -> dict[str, Any]:
    """What a save answers: where, the warnings the file has now, and the job dictionary as it is now."""
    assert result.subsystem is not None, "a save replaces the file only when it checks clean"
    return {"ok": True, "file": file, "message": message, "warnings": [w.format().splitlines()[0] for w in result.warnings],
            "dictionary": job_dictionary(result.subsystem)}


def write_application(file: str, body: ApplicationBody) -> dict[str, Any]:
    name = check_name(body.name)
    with _writing, in_tree(file):
        steps = checked_row(loaded(file, "save an application"), body.row, run=False)
        result = save_application(file, name, file_steps(steps), body.replace)
    application = result.subsystem.applications[name] if result.subsystem else None
    what = "complete" if application is None or application.complete else \
        f"incomplete ({len(application.gaps)} gap(s)): it is an icon of the dictionary now, not runnable"
    return saved_reply(file, result, f"application '{name}' saved to {file}, {what}")


def write_object(file: str, body: ObjectBody) -> dict[str, Any]:
    with _writing, in_tree(file):
        result = save_object(file, loaded(file, "save an object"), body.name, body.value)
    return saved_reply(file, result, f"object '{body.name}' saved to {file}")


def run_row(link: RunLink, file: str, body: RunBody) -> Reply:
    name = check_name(body.name)
    subsystem = loaded(file, "run an application")
    steps = run_steps(subsystem, checked_row(subsystem, body.row, run=True))
    verb = COMMANDS["app"]
    try:
        return supervisor_reply(link.request(verb.name, {"application": name, "steps": steps}, verb.timeout))
    except NoRun as exc:
        return refusal(NO_RUN, f"no run is attached to run it on: {exc}")
    except PboError as exc:  # no control queue (starting, stopping), no answer in time
        return refusal(NO_ANSWER, str(exc))


def router() -> APIRouter:
    routes = APIRouter(prefix="/api/workspace", tags=["workspace"])

    @routes.post("/applications", summary="save the workspace's row as an application of the file (gaps allowed)")
    async def post_application(request: Request, body: ApplicationBody) -> Reply:
        try:
            return Reply(await run_in_threadpool(write_application, subsystem_file(request), body))
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except (RowRefused, SaveRefused, ValueError) as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.post("/objects", summary="save a named object's value to the file, checked against its type")
    async def post_object(request: Request, body: ObjectBody) -> Reply:
        try:
            return Reply(await run_in_threadpool(write_object, subsystem_file(request), body))
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except (SaveRefused, ValueError) as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.post("/run", summary="run the workspace's row on the attached run (pbo app NAME --steps), checked first")
    async def post_run(request: Request, body: RunBody) -> Reply:
        try:
            return await run_in_threadpool(run_row, request.app.state.link, subsystem_file(request), body)
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except (RowRefused, ValueError) as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    return routes
