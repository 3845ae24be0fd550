"""The simulated clock's barrier (`pbo run --clock sim`): every process advances in lockstep ticks.

The supervisor is the clock master. For each tick it writes the tick's time into the table's
header, then releases the participants one at a time, in a fixed order (the plant first, then
the RTPUs by index), each through its own `go` semaphore, and waits on that participant's `done`
semaphore before releasing the next. Running them in turn, never together, is what makes a run
replay bit for bit: no two processes ever race for the table in the same tick, so what a task
reads depends only on the tick order, never on the scheduler. The plant steps exactly once per
tick; an RTPU first serves the signals queued for it, then runs every task released at or
before the tick's time.

A participant can also be stepped with no new tick (the tick counter unchanged): it then only
serves its signals. Job control uses that to spawn tasks, turn them on and stop them between
ticks, so a signal takes effect at a known simulated instant.

Semaphores are created 0600 and named after the run, so the table's manifest lists them and a
later run removes them if this one died.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
import posix_ipc

from pbo_runtime.ipc import process
from pbo_runtime.ipc import shm
from pbo_runtime.table.table import Flag, Header

WAIT_SLICE = 0.05  # seconds between checks for dead children while a participant runs its tick


def semaphore_names(subsystem: str, run_id: str, role: str) -> tuple[str, str]:
    """The (go, done) semaphore names of one participant ('plant' or an RTPU's name)."""
    base = shm.object_name(subsystem, run_id, f"tick-{role}")
    return f"{base}.go", f"{base}.done"


class LockstepMaster:
    """The supervisor's side: owns the semaphores, the tick counter and the time in the header."""

    def __init__(self, subsystem: str, run_id: str, roles: list[str], tick: float, header: np.ndarray) -> None:
        self.roles = list(roles)
        self.tick_ns = int(round(tick * 1e9))
        self.tick = self.tick_ns / 1e9
        self.header = header
        self.ticks = 0
        self.stepping, self.step_started = "", 0.0  # the participant released last, and when (wall clock)
        self._go: dict[str, posix_ipc.Semaphore] = {}
        self._done: dict[str, posix_ipc.Semaphore] = {}
        try:
            for role in self.roles:
                go, done = semaphore_names(subsystem, run_id, role)
                self._go[role] = posix_ipc.Semaphore(go, posix_ipc.O_CREX, mode=0o600, initial_value=0)
                self._done[role] = posix_ipc.Semaphore(done, posix_ipc.O_CREX, mode=0o600, initial_value=0)
        except BaseException:
            self.close()
            raise
        header[Header.SIM_TIME_NS] = 0
        header[Header.SIM_TICK] = 0
        # before the run's participants exist: no one else writes the flags yet
        header[Header.FLAGS] = int(header[Header.FLAGS]) | Flag.SIM_CLOCK

    @property
    def now(self) -> float:
        """The simulated time of the last tick released (0 before the first)."""
        return int(self.header[Header.SIM_TIME_NS]) / 1e9

    def advance(self, while_waiting: Callable[[], None]) -> None:
        """One tick: the next time in the header, then every participant in order, each to its end."""
        self.header[Header.SIM_TIME_NS] = self.ticks * self.tick_ns
        self.ticks += 1
        self.header[Header.SIM_TICK] = self.ticks
        for role in self.roles:
            self.step(role, while_waiting)

    def step(self, role: str, while_waiting: Callable[[], bool | None]) -> bool:
        """Release one participant and wait until it is done (True); `while_waiting` runs every slice.

        `while_waiting` may raise (a participant died) or return True to stop waiting (False).
        """
        self._go[role].release()
        done = self._done[role]
        self.stepping, self.step_started = role, time.monotonic()  # for a watchdog in `while_waiting`
        while True:
            try:
                done.acquire(WAIT_SLICE)
                return True
            except (posix_ipc.BusyError, posix_ipc.SignalError):  # a signal: Ctrl-C only sets a flag
                if while_waiting():
                    return False

    def close(self) -> None:
        for semaphore in (*self._go.values(), *self._done.values()):
            try:
                semaphore.unlink()
            except posix_ipc.ExistentialError:
                pass
            semaphore.close()
        self._go.clear()
        self._done.clear()


class LockstepParticipant:
    """A plant's or an RTPU's side: wait for `go`, do the tick's work, post `done`."""

    def __init__(self, subsystem: str, run_id: str, role: str, header: np.ndarray,
                 before_step: Callable[[], None] | None = None) -> None:
        go, done = semaphore_names(subsystem, run_id, role)
        self._go = posix_ipc.Semaphore(go)
        self._done = posix_ipc.Semaphore(done)
        self.header = header
        self.last_tick = 0
        self.before_step = before_step  # run once released, before the step's work (an RTPU's link relays)

    def wait(self) -> bool:
        """Block until released; True if a new tick began (False: serve signals only)."""
        while True:
            try:
                self._go.acquire(1.0)
                break
            except (posix_ipc.BusyError, posix_ipc.SignalError):
                process.raise_if_stopping()  # a supervisor that died sent us SIGTERM (PDEATHSIG): Stop ends the wait
        if self.before_step is not None:
            self.before_step()
        tick = int(self.header[Header.SIM_TICK])
        if tick != self.last_tick:
            self.last_tick = tick
            return True
        return False

    def done(self) -> None:
        self._done.release()

    def close(self) -> None:
        for semaphore in (self._go, self._done):
            semaphore.close()

