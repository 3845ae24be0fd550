"""The routes of an application file's workspace: its `run:` as stages of `parallel` steps, saved and run.

    GET  /api/application          the file's subsystems (each with its job dictionary) and its stages
                                   (edit.stages_workspace), and the state of the run the HMI started
    POST /api/application/stages   {"stages": [{"arms": {subsystem: row}}, ...]}: each arm's row checked
                                   against its subsystem, `run:` written back only if the file then checks
    POST /api/application/run      {"clock": "real" | "sim"}: `pbo run APP.yaml` started (api.application_run)
    GET  /api/application/run      that run's state: running, exit status, its last lines
    POST /api/application/stop     that run stopped, as Ctrl-C stops it

Served only when `pbo hmi` was given an application file (404 otherwise). The file written and run
is that one, never a path from a request, and loads stay in its folder. Each subsystem's run is
watched with the status stream of its own name (`/api/streams/status?subsystem=NAME`, api.streams),
which takes only the names of the subsystems this file has.
"""

from __future__ import annotations

import os
import threading
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from pydantic import BaseModel
from starlette.concurrency import run_in_threadpool

from pbo_runtime.api.application_run import CLOCKS, ApplicationRun, RunRefused
from pbo_runtime.api.files import in_tree, served_root
from pbo_runtime.api.replies import BAD_REQUEST, NO_RUN, REFUSED, Reply, refusal
from pbo_runtime.config.application import Application, check_application
from pbo_runtime.config.file_kind import is_application_file
from pbo_runtime.edit.stages_workspace import checked_stages, save_stages, stages_workspace
from pbo_runtime.edit.workspace import RowRefused
from pbo_runtime.edit.write_back import WriteRefused

_writing = threading.Lock()  # one save at a time: each reads the file, changes it, and writes it back


class NotAnApplication(Exception):
    """`pbo hmi` was given no application file."""


class StagesBody(BaseModel):
    stages: list[Any]


class RunBody(BaseModel):
    clock: str = "real"


def application_file(app: FastAPI) -> str:
    file: str | None = app.state.file
    if not file or not is_application_file(file):
        raise NotAnApplication("pbo hmi was given no application file: start it as pbo hmi APP.yaml to edit and run "
                               "an application's stages")
    return file


def checked(app: FastAPI, file: str) -> Application:
    """The application of `file`, read within its folder; ValueError naming the first error. Its subsystems' names
    are kept for the status streams."""
    with in_tree(file):
        result = check_application(file)
    if result.application is None:
        first = result.errors[0].format().splitlines()[0] if result.errors else "it does not load"
        raise ValueError(f"{file} has {len(result.errors)} error(s), the first: {first}; run pbo check {file}")
    app.state.application_subsystems = {sub.name for sub in result.application.subsystems.values()}
    return result.application


def runner(app: FastAPI, file: str) -> ApplicationRun:
    if app.state.application_run is None:
        app.state.application_run = ApplicationRun(file, served_root(file))
    run: ApplicationRun = app.state.application_run
    return run


def workspace_reply(app: FastAPI, file: str) -> dict[str, Any]:
    return {"ok": True, **stages_workspace(checked(app, file)), "run": runner(app, file).state()}


def write_stages(app: FastAPI, file: str, body: StagesBody) -> dict[str, Any]:
    with _writing:
        stages = checked_stages(checked(app, file), body.stages)
        with in_tree(file):
            result = save_stages(file, stages)
    warnings = [w.format().splitlines()[0] for w in result.warnings]
    return {**workspace_reply(app, file), "warnings": warnings,
            "message": f"run: saved to {os.path.basename(file)}, {len(stages)} stage(s); pbo check finds no error"}


def router() -> APIRouter:
    routes = APIRouter(prefix="/api/application", tags=["application"])

    @routes.get("", summary="an application file's subsystems, their job dictionaries, its stages and the run started here")
    async def get_application(request: Request) -> Reply:
        try:
            file = application_file(request.app)
            return Reply(await run_in_threadpool(workspace_reply, request.app, file))
        except NotAnApplication as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.post("/stages", summary="write the workspace's stages as the file's run:, checked like pbo check first")
    async def post_stages(request: Request, body: StagesBody) -> Reply:
        try:
            return Reply(await run_in_threadpool(write_stages, request.app, application_file(request.app), body))
        except NotAnApplication as exc:
            return refusal(NO_RUN, str(exc))
        except (RowRefused, WriteRefused, ValueError) as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.post("/run", summary="run the application file as pbo run APP.yaml does (one supervisor per subsystem)")
    async def post_run(request: Request, body: RunBody) -> Reply:
        if body.clock not in CLOCKS:
            return refusal(BAD_REQUEST, f"not started: clock must be one of {', '.join(CLOCKS)}, got {body.clock!r}",
                           bad_request=True)
        try:
            file = application_file(request.app)
            await run_in_threadpool(checked, request.app, file)  # a file that does not check is not started
            state = runner(request.app, file).start(body.clock)
        except NotAnApplication as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, f"not started: {exc}", bad_request=True)
        except RunRefused as exc:
            return refusal(REFUSED, f"not started: {exc}")
        return Reply({"ok": True, "message": f"pbo run {os.path.basename(file)} --clock {body.clock} started "
                                             f"(pid {state['pid']}): one supervisor per subsystem", "run": state})

    @routes.get("/run", summary="the state of the run started here: running, its exit status, its last lines")
    def get_run(request: Request) -> Reply:
        try:
            return Reply({"ok": True, "run": runner(request.app, application_file(request.app)).state()})
        except NotAnApplication as exc:
            return refusal(NO_RUN, str(exc))

    @routes.post("/stop", summary="stop the run started here, as Ctrl-C does")
    async def post_stop(request: Request) -> Reply:
        try:
            run = runner(request.app, application_file(request.app))
        except NotAnApplication as exc:
            return refusal(NO_RUN, str(exc))
        if not await run_in_threadpool(run.stop):
            return refusal(REFUSED, "no run started here is running")
        return Reply({"ok": True, "message": "the application stopped", "run": run.state()})

    return routes
