"""The simulated clock's master when every participant runs in the supervisor's process (`--one-process`).

The ring of `clock.lockstep`, with calls instead of semaphores: within a tick the plant, then
each RTPU by index, takes its turn (its `step(new_tick)`), in the order the processes take
theirs; the ring stops after a tick that queued an event for job control, or at the last tick
asked for, as the participants' own hand-overs do. The header's words (time, tick, turn) move
exactly as they do there, so what a task reads of the clock is the same.

A participant cannot die without the process: there is no ring to recover (`recover` reports a
stop with nothing left to run), and an RTPU hosted here is never restarted.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from pbo_runtime.clock.lockstep import RingStop, RingTime
from pbo_runtime.table.table import Flag, Header

_SIM_TIME_NS, _SIM_TICK, _SIM_TURN = int(Header.SIM_TIME_NS), int(Header.SIM_TICK), int(Header.SIM_TURN)

Step = Callable[[bool], None]  # a participant's turn: True on a new tick, False to serve its signals only


class LocalRing(RingTime):
    """`LockstepMaster`'s interface over participants hosted in this process (`join`)."""

    def __init__(self, roles: list[str], tick: float, header: np.ndarray) -> None:
        self.roles = list(roles)
        self.tick_ns = round(tick * 1e9)
        self.tick = self.tick_ns / 1e9
        self.header = header
        self._words = header.data  # the same words as plain ints: no numpy scalar per write
        self.ticks = 0
        self.stepping, self.step_started = "", 0.0
        self._steps: list[Step | None] = [None] * len(self.roles)
        self.events_pending: Callable[[], bool] = lambda: False  # job control's queue holds an event
        header[Header.SIM_TIME_NS] = 0
        header[Header.SIM_TICK] = 0
        header[Header.SIM_TICK_NS] = self.tick_ns
        header[Header.SIM_RING_END] = 0
        header[Header.FLAGS] = int(header[Header.FLAGS]) | Flag.SIM_CLOCK

    def join(self, role: str, step: Step, events_pending: Callable[[], bool]) -> None:
        """Participant `role` takes its turns through `step` from now on; `events_pending` says whether
        job control's queue (where the participants report) holds an event."""
        self._steps[self.roles.index(role)] = step
        self.events_pending = events_pending

    def advance(self, while_waiting: Callable[[], bool | None], ticks: int = 1) -> int:
        """Run up to `ticks` ticks, every participant in order in each; sooner after a tick that queued an event."""
        steps = [(place, step) for place, step in enumerate(self._steps) if step is not None]
        words, tick_ns, pending = self._words, self.tick_ns, self.events_pending
        first = tick = self.ticks + 1
        last = self.ticks + max(ticks, 1)
        self.stepping, self.step_started = self.roles[0], time.monotonic()
        try:
            while True:
                words[_SIM_TIME_NS] = (tick - 1) * tick_ns
                words[_SIM_TICK] = tick
                for place, step in steps:
                    words[_SIM_TURN] = place
                    step(True)
                if tick >= last or pending():
                    break
                tick += 1
        finally:
            self.ticks = tick
        return tick - first + 1

    def step(self, role: str, while_waiting: Callable[[], bool | None]) -> bool:
        """Give `role` a turn with no new tick (its signals only)."""
        place = self.roles.index(role)
        step = self._steps[place]
        self._words[_SIM_TURN] = place
        self.stepping, self.step_started = role, time.monotonic()
        if step is not None:
            step(False)
        return True

    def running(self) -> str:
        place = int(self.header[Header.SIM_TURN])
        return self.roles[place] if 0 <= place < len(self.roles) else self.stepping

    def recover(self, dead: str, while_waiting: Callable[[], bool | None]) -> RingStop:
        return RingStop(int(self.header[Header.SIM_TICK]), (), False)

    def forget(self, role: str) -> None:
        pass

    def finish_tick(self, stop: RingStop, while_waiting: Callable[[], bool | None]) -> None:
        pass

    def close(self) -> None:
        self._steps = [None] * len(self.roles)
