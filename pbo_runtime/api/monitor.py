"""The monitor's routes: what the file says the monitor needs, the bus load now, the arm's joint frames live.

    GET /api/monitor/layout         tasks (module, RTPU, parameters tunable live and their values),
                                    configurations and variables (shapes) of the subsystem file
    GET /api/monitor/bus            the running configuration's bus load, predicted from the file
                                    beside measured from the run's task rates now (analysis.bus)
    WS  /api/streams/arm?rate=20    the arm's joint frame origins, base to tool, from q_m by forward
         [&q=q_m]                   kinematics of the table's ARM and EE (reports.arm): {"time", "q", "frames": [[x, y, z], ...]}

The file is the one `pbo hmi FILE` was given or the run's own (`api.files.subsystem_file`). The arm
stream reads q_m lock-free from the table, as the variables stream does, at most 50 times a second.
"""

from __future__ import annotations

import functools
import os
from typing import Any

from fastapi import APIRouter, Request, WebSocket, WebSocketDisconnect
from starlette.concurrency import run_in_threadpool

from pbo_runtime.analysis import bus
from pbo_runtime.api.files import NoFile, loaded, subsystem_file
from pbo_runtime.api.jsonable import jsonable
from pbo_runtime.api.link import NoRun, RunLink
from pbo_runtime.api.replies import BAD_REQUEST, NO_ANSWER, NO_RUN, Reply, refusal
from pbo_runtime.api.streams import accept_at_rate, open_view, refuse, ticks
from pbo_runtime.config import bus_model
from pbo_runtime.config.model import Subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.reports.arm import ArmFrames
from pbo_runtime.reports.monitor import monitor_layout
from pbo_runtime.supervisor.commands import STATUS_TIMEOUT
from pbo_runtime.table.snapshot import TableBusy

MAX_ARM_RATE = 50.0  # Hz: a drawing of the arm needs no more than the screen's rate
DEFAULT_ARM_RATE = 20.0


@functools.lru_cache(maxsize=8)
def _checked(file: str, modified: int, what: str) -> Subsystem:
    return loaded(file, what)  # type: ignore[no-any-return]


def checked(file: str, what: str) -> Subsystem:
    """The file's checked subsystem, checked again only when the file changed (the bus is asked every few seconds)."""
    try:
        modified = os.stat(file).st_mtime_ns
    except OSError as exc:
        raise ValueError(f"cannot {what}: {file}: {exc.strerror}") from None
    return _checked(file, modified, what)


def arm_in(view: Any, name: str) -> ArmFrames:
    """The arm whose constants (ARM, EE) the robot interface published in the run's table."""
    missing = [const for const in ("ARM", "EE") if const not in view.variables()]
    if missing:
        raise ValueError(f"'{view.subsystem}' has no {' nor '.join(missing)} in its table: a robot interface "
                         "(robot_torque, robot_position) publishes them")
    arm, _sequence, _when, _writer = view.read("ARM")
    ee, _sequence, _when, _writer = view.read("EE")
    if not arm.any():
        raise ValueError(f"the robot interface of '{view.subsystem}' has not published ARM yet (its task has not "
                         "started); try again in a moment")
    return ArmFrames(arm, ee, name)


def router() -> APIRouter:
    routes = APIRouter(tags=["monitor"])

    @routes.get(
        "/api/monitor/layout", summary="the file's tasks (tunable parameters), configurations and variables, for the monitor"
    )
    def get_layout(request: Request) -> Reply:
        try:
            file = subsystem_file(request)
            return Reply({"ok": True, "file": file, **monitor_layout(checked(file, "show the monitor"))})
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:
            return refusal(BAD_REQUEST, str(exc), bad_request=True)

    @routes.get("/api/monitor/bus", summary="the running configuration's bus load: predicted from the file beside measured now")
    def get_bus(request: Request) -> Reply:
        link: RunLink = request.app.state.link
        try:
            reply = link.request("status", {}, STATUS_TIMEOUT)
        except NoRun as exc:
            return refusal(NO_RUN, str(exc))
        except PboError as exc:
            return refusal(NO_ANSWER, str(exc))
        if not reply.get("ok"):
            return refusal(NO_ANSWER, str(reply.get("error") or "the run did not give its status"))
        try:
            file = str(request.app.state.file or reply.get("file") or "")
            if not file:
                raise NoFile(
                    "no subsystem file: pbo hmi was given none and the run did not say its own; start it as pbo hmi FILE"
                )
            subsystem = checked(file, "report the bus")
            measured = bus.measured_live(subsystem, reply)
            predicted = bus_model.predict(subsystem, measured.configuration)
        except NoFile as exc:
            return refusal(NO_RUN, str(exc))
        except ValueError as exc:  # BusModelError included: a configuration the file does not have
            return refusal(BAD_REQUEST, str(exc), bad_request=True)
        return Reply({"ok": True, "file": file, "configuration": measured.configuration, **bus.as_json(predicted, measured)})

    @routes.websocket("/api/streams/arm")
    async def arm_stream(websocket: WebSocket) -> None:
        rate = await accept_at_rate(websocket, DEFAULT_ARM_RATE, MAX_ARM_RATE)
        view = await open_view(websocket) if rate is not None else None
        if rate is None or view is None:
            return
        link: RunLink = websocket.app.state.link
        joints = websocket.query_params.get("q") or "q_m"
        try:
            try:
                file = websocket.app.state.file or await run_in_threadpool(_run_file, link)
                subsystem = await run_in_threadpool(checked, file, "draw the arm")
                name = subsystem.plant.model if subsystem.plant is not None else subsystem.name
                frames = await run_in_threadpool(arm_in, view, name)
            except (PboError, ValueError, OSError) as exc:
                await refuse(websocket, f"no arm to draw: {exc}")
                return
            if joints not in view.variables():
                await refuse(websocket, f"no variable '{joints}' in '{view.subsystem}' to draw the arm from "
                                        f"(variables: {', '.join(view.variables())}); give ?q=NAME")
                return
            await stream_arm(websocket, view, frames, joints, rate)
        except WebSocketDisconnect:
            return
        finally:
            view.close()

    return routes


def _run_file(link: RunLink) -> str:
    reply = link.request("status", {}, STATUS_TIMEOUT)
    if not reply.get("ok") or not reply.get("file"):
        raise PboError("the run did not say its file; start pbo hmi FILE")
    return str(reply["file"])


async def stream_arm(websocket: WebSocket, view: Any, frames: ArmFrames, joints: str, rate: float) -> None:
    """Send the arm's joint frames `rate` times a second until the client leaves or the run ends."""
    await websocket.send_json({"ok": True, "subsystem": view.subsystem, "arm": frames.name, "joints": joints,
                               "rate": rate, "ndof": frames.ndof})
    async for now in ticks(websocket, view, rate):
        try:
            q, _sequence, _when, _writer = view.read(joints)
            message: dict[str, Any] = {"time": now, "q": q.tolist(), "frames": frames.positions(q).tolist()}
        except TableBusy as exc:
            message = {"time": now, "busy": str(exc)}
        except ValueError as exc:  # q_m's size is not the arm's joints
            await refuse(websocket, f"cannot draw the arm: {exc}")
            return
        await websocket.send_json(jsonable(message))
