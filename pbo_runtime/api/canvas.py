"""The engineer level's routes (Onika §4.3): the job canvas checked as a file, and saved as a job.

    GET  /api/canvas          what a canvas starts from: the file's RTPUs, devices, configurations
                              and their tasks (values as YAML text)
    POST /api/canvas/check    {"tasks": [...], "configuration": NAME}: the canvas composed onto the
                              file's base, checked by pbo check's checker; each diagnostic with the
                              task, modifier and pin it belongs to, each task's pins, and which
                              lexicon modules could be placed next (the placement query)
    POST /api/canvas/job      {"name": JOB, "tasks": [...], "configuration": NAME, "object":
                              "inferred"|"none"}: save the canvas as a job in the file pbo hmi was
                              given (or the run's own), if the file then checks clean

A task is `{"name", "module", "fields": {rtpu, period, ...: YAML text}, "params": {modifier: YAML
text}, "ports": {port: variable}, "on": bool}`. The logic is `edit.canvas` and
`edit.canvas_job`; the file written is never a path from the request, and nothing outside its
folder is read (`files.in_tree`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, Request
from pydantic import BaseModel

from pbo_runtime.api.files import NoFile, OutsideRoot, in_tree, subsystem_file
from pbo_runtime.api.replies import BAD_REQUEST, NO_RUN, REFUSED, Reply, refusal
from pbo_runtime.config.root import OUTSIDE_ROOT
from pbo_runtime.edit.canvas import CANVAS_CONFIGURATION, CanvasError, check_canvas, file_canvas, tasks_from_json
from pbo_runtime.edit.canvas_job import JobRefused, save_job
from pbo_runtime.edit.live import NAME


class CanvasRequest(BaseModel):
    """The canvas: its tasks, and the configuration it stands for (the file's it was loaded from, or a new one)."""

    tasks: list[Any]
    configuration: str | None = None


class JobRequest(CanvasRequest):
    """Save as job: its name, and whether its object is inferred by the job model or none."""

    name: str
    object: str = "inferred"


def configuration_name(given: str | None) -> str:
    if given is None or not given:
        return CANVAS_CONFIGURATION
    if not NAME.match(given):
        raise CanvasError(f"a configuration's name is an identifier, got: {given!r}")
    return given


def answer(request: Request, reply: Callable[[str], dict[str, Any]]) -> Reply:
    """`reply(file)` for the file the HMI edits, or the refusal: 404 no file, 400 a wrong canvas, 409 a job refused."""
    try:
        file = subsystem_file(request)
        with in_tree(file):
            answered = reply(file)
        outside = [d for d in answered.get("diagnostics", ()) if d.get("code") == OUTSIDE_ROOT]
        if outside:
            raise OutsideRoot(f"refused: error[{OUTSIDE_ROOT}]: {outside[0].get('message')}")  # 403 (api.app)
        return Reply({"ok": True, **answered})
    except NoFile as exc:
        return refusal(NO_RUN, str(exc))
    except CanvasError as exc:
        return refusal(BAD_REQUEST, str(exc), bad_request=True)
    except JobRefused as exc:
        return refusal(REFUSED, str(exc))


def router() -> APIRouter:
    routes = APIRouter(prefix="/api/canvas", tags=["canvas"])

    @routes.get("", summary="what the job canvas starts from: the file's configurations and their tasks")
    def get_canvas(request: Request) -> Reply:
        return answer(request, file_canvas)

    @routes.post("/check", summary="check the job canvas composed onto the file's base (pbo check), with placement")
    def post_check(request: Request, body: CanvasRequest) -> Reply:
        return answer(request, lambda file: {"file": file, **check_canvas(file, tasks_from_json(body.tasks),
                                                                          configuration_name(body.configuration))})

    @routes.post("/job", summary="save the job canvas as a job in the subsystem file (action, or action requiring an object)")
    def post_job(request: Request, body: JobRequest) -> Reply:
        return answer(request, lambda file: save_job(file, body.name, tasks_from_json(body.tasks), body.configuration or None,
                                                     body.object))

    return routes
