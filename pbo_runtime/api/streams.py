"""Live streams over WebSocket: the status reply at a few Hz, chosen variables at up to 100 Hz.

    /api/streams/status?rate=2                     the status reply (as POST /api/verbs/status), 2 a second
    /api/streams/status?subsystem=NAME             the same of subsystem NAME's run, a subsystem of the
                                                   application file served (api.application)
    /api/streams/variables?names=q_m,tau_u&rate=50  {"time", "values": {name: value}, "sequences": {name: n}}

The variables are read from the run's table under its seqlock (`table.svar`), never under the
table lock: a client, however slow or stopped, cannot delay an RTPU. Each connection attaches
its own read-only view of the table and paces itself on absolute deadlines; a client that cannot
keep up gets fewer messages, never a queue. A request the stream cannot serve (a rate above its
limit, an unknown variable, no run) is answered with one `{"ok": false, "error": ...}` message
and the close code 1008; the end of the run with `{"ok": false, "ended": true, ...}` and 1000.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect, status
from starlette.concurrency import run_in_threadpool

from pbo_runtime.api.jsonable import jsonable
from pbo_runtime.api.link import LiveRunLink, NoRun, RunLink
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import shm
from pbo_runtime.supervisor.commands import STATUS_TIMEOUT
from pbo_runtime.table.snapshot import TableBusy
from pbo_runtime.table.svar import TableView

MAX_VARIABLE_RATE = 100.0  # Hz: a plot needs no more, and each message costs the machine the RTPUs run on
MAX_STATUS_RATE = 10.0  # Hz: each status is a request the supervisor serves between its ticks
DEFAULT_VARIABLE_RATE = 20.0
DEFAULT_STATUS_RATE = 2.0
ALIVE_EVERY = 1.0  # seconds between checks that the run still lives (a mapping outlives its run: values would freeze)


def parse_rate(text: str | None, default: float, limit: float) -> float:
    """The requested rate in Hz; ValueError saying what is allowed."""
    if text is None:
        return default
    try:
        rate = float(text)
    except ValueError:
        raise ValueError(f"rate must be a number of Hz, got: {text!r}") from None
    if not 0 < rate <= limit:  # also refuses NaN
        raise ValueError(f"rate must be > 0 and at most {limit:g} Hz, got: {text} Hz; ask for {limit:g} or less")
    return rate


async def refuse(websocket: WebSocket, error: str, code: int = status.WS_1008_POLICY_VIOLATION, **extra: Any) -> None:
    await websocket.send_json({"ok": False, "error": error, **extra})
    await websocket.close(code)


class Pacer:
    """Absolute deadlines `rate` times a second; a late tick moves the next deadline on instead of bursting."""

    def __init__(self, rate: float) -> None:
        self.period = 1.0 / rate
        self.next = time.monotonic()

    async def wait(self) -> None:
        self.next += self.period
        delay = self.next - time.monotonic()
        if delay > 0:
            await asyncio.sleep(delay)
        elif delay < -self.period:
            self.next = time.monotonic()  # fell behind by a whole period: skip, never catch up in a burst


def run_alive(view: TableView) -> bool:
    return (shm.SHM_DIR / view.name.lstrip("/")).exists() and shm.pid_alive(view.supervisor_pid)


async def accept_at_rate(websocket: WebSocket, default: float, limit: float) -> float | None:
    """Accept a stream and read its `?rate=`; None once a bad rate has been refused."""
    await websocket.accept()
    try:
        return parse_rate(websocket.query_params.get("rate"), default, limit)
    except ValueError as exc:
        await refuse(websocket, str(exc))
        return None


async def open_view(websocket: WebSocket) -> TableView | None:
    """A lock-free view of the run's table (the caller closes it); None once the refusal was sent."""
    link: RunLink = websocket.app.state.link
    try:
        return await run_in_threadpool(link.open_table)
    except PboError as exc:
        await refuse(websocket, str(exc))
        return None


async def ticks(websocket: WebSocket, view: TableView, rate: float) -> AsyncIterator[float]:
    """The time of each message, `rate` times a second, while the run lives; when it ends, the
    stream is closed saying so."""
    pacer = Pacer(rate)
    checked = time.monotonic()
    while True:
        now = time.monotonic()
        if now - checked >= ALIVE_EVERY:
            checked = now
            if not run_alive(view):
                await refuse(websocket, f"the run of '{view.subsystem}' has ended", status.WS_1000_NORMAL_CLOSURE, ended=True)
                return
        yield now
        await pacer.wait()


def router() -> APIRouter:
    routes = APIRouter(prefix="/api/streams")

    @routes.websocket("/status")
    async def status_stream(websocket: WebSocket) -> None:
        await websocket.accept()
        link: RunLink = websocket.app.state.link
        subsystem = websocket.query_params.get("subsystem")
        if subsystem is not None:  # one subsystem of the application file served: several runs read side by side
            names = websocket.app.state.application_subsystems
            if subsystem not in names:
                await refuse(websocket, f"no subsystem '{subsystem[:80]}' in the application file served "
                                        f"(subsystems: {', '.join(sorted(names)) or 'none'})")
                return
            link = LiveRunLink(subsystem)
        try:
            rate = parse_rate(websocket.query_params.get("rate"), DEFAULT_STATUS_RATE, MAX_STATUS_RATE)
        except ValueError as exc:
            await refuse(websocket, str(exc))
            return
        pacer = Pacer(rate)
        try:
            while True:
                try:
                    reply = await run_in_threadpool(link.request, "status", {}, STATUS_TIMEOUT)
                except NoRun as exc:
                    await refuse(websocket, str(exc), status.WS_1000_NORMAL_CLOSURE, ended=True)
                    return
                except PboError as exc:  # busy or stopping: say so, and keep asking
                    reply = {"ok": False, "error": str(exc)}
                await websocket.send_json(jsonable(reply))
                await pacer.wait()
        except WebSocketDisconnect:
            return

    @routes.websocket("/variables")
    async def variables_stream(websocket: WebSocket) -> None:
        rate = await accept_at_rate(websocket, DEFAULT_VARIABLE_RATE, MAX_VARIABLE_RATE)
        view = await open_view(websocket) if rate is not None else None
        if rate is None or view is None:
            return
        try:
            names = [n for n in (websocket.query_params.get("names") or "").split(",") if n] or view.variables()
            unknown = [n for n in names if n not in view.variables()]
            if unknown:
                await refuse(websocket, f"no variable {', '.join(map(repr, unknown))} in '{view.subsystem}' "
                                        f"(variables: {', '.join(view.variables())})")
                return
            await stream_variables(websocket, view, names, rate)
        except WebSocketDisconnect:
            return
        finally:
            view.close()

    return routes


async def stream_variables(websocket: WebSocket, view: TableView, names: list[str], rate: float) -> None:
    """Send the variables `rate` times a second until the client leaves or the run ends."""
    await websocket.send_json({"ok": True, "subsystem": view.subsystem, "run_id": view.run_id, "names": names, "rate": rate})
    async for now in ticks(websocket, view, rate):
        values: dict[str, Any] = {}
        sequences: dict[str, int] = {}
        try:
            for name in names:
                value, sequence, _when, _writer = view.read(name)  # lock-free: copies under the seqlock
                values[name] = value.tolist()
                sequences[name] = sequence
            message: dict[str, Any] = {"time": now, "values": values, "sequences": sequences}
        except TableBusy as exc:  # a writer stopped mid-write: say so, never wait on it
            message = {"time": now, "busy": str(exc)}
        await websocket.send_json(jsonable(message))
