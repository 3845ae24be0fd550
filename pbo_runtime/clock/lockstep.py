"""The simulated clock's barrier (`pbo run --clock sim`): every process advances in lockstep ticks.

The supervisor is the clock master. The participants (the plant first, then the RTPUs by
index) form a ring: within a tick each runs in turn, never two at once, and hands the turn
straight to the next through that one's `go` semaphore. Running them in turn is what makes a
run replay bit for bit: no two processes ever race for the table in the same tick, so what a
task reads depends only on the tick order, never on the scheduler. The plant steps exactly once
per tick; an RTPU first serves the signals queued for it, then runs every task released at or
before the tick's time.

The master starts a turn of the ring with the time of its first tick in the table's header and
the number of the last tick it may run (`Header.SIM_RING_END`). The participant that ends a
tick begins the next one itself (the next time in the header, then the first participant's
`go`) until that last tick, or until a participant queued an event for job control during the
tick, and then hands the turn back through the master's `done` semaphore. Job control so takes
every event after the very tick it was sent in, as if it had released each tick itself, while
the ticks between events cost one hand-over per participant and nothing in the supervisor.
`advance(ticks=1)` gives the master each tick.

A participant can also be stepped with no new tick (the tick counter unchanged): it then only
serves its signals and hands the turn back to the master. Job control uses that to spawn tasks,
turn them on and stop them between ticks, so a signal takes effect at a known simulated instant.

A participant that dies (an RTPU whose restart policy brings it back) stops the ring in some
tick N: the turn is stuck at it, or came back to the master from the one before it.
`LockstepMaster.recover` brings the ring to a known stop and says where tick N stands
(`RingStop`): who has not run it yet. `finish_tick` then runs tick N for those, each as its own
turn, so no other participant loses a tick; the dead one's tick N is lost. A participant started
for the dead one counts the ticks before it joined as seen: it runs from tick N + 1 on, and the
steps between (spawning its tasks) are steps, not ticks.

Semaphores are created 0600 and named after the run, so the table's manifest lists them and a
later run removes them if this one died.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
import posix_ipc

from pbo_runtime.errors import PboError
from pbo_runtime.ipc import process, shm
from pbo_runtime.table.table import Flag, Header

WAIT_SLICE = 0.05  # seconds between checks for dead children while the participants run their ticks
# Header words, as plain ints for the memoryview reads on the per-tick path
_SIM_TIME_NS, _SIM_TICK, _SIM_TICK_NS = int(Header.SIM_TIME_NS), int(Header.SIM_TICK), int(Header.SIM_TICK_NS)
_SIM_RING_END, _SIM_TURN = int(Header.SIM_RING_END), int(Header.SIM_TURN)


def go_name(subsystem: str, run_id: str, role: str) -> str:
    """The semaphore that gives participant `role` ('plant' or an RTPU's name) its turn."""
    return f"{shm.object_name(subsystem, run_id, f'tick-{role}')}.go"


def done_name(subsystem: str, run_id: str) -> str:
    """The semaphore that hands the turn back to the master."""
    return f"{shm.object_name(subsystem, run_id, 'tick')}.done"


def semaphore_names(subsystem: str, run_id: str, roles: list[str]) -> list[str]:
    """Every semaphore of the barrier: each participant's `go`, then the master's `done`."""
    return [go_name(subsystem, run_id, role) for role in roles] + [done_name(subsystem, run_id)]


@dataclass(frozen=True)
class RingStop:
    """Where the ring stood when a participant died: tick `tick`, and who has yet to run it."""

    tick: int  # the tick running when it stopped (0: none had begun)
    unfinished: tuple[str, ...]  # the live participants after the stop, in ring order: tick `tick` is still theirs
    stuck_at_dead: bool  # the turn was with the dead one (it died holding it, or was handed it): it never came back


class RingStuck(PboError):
    """A live participant never handed the turn back while the ring was brought to a stop."""


class RingTime:
    """What a ring's master reads of the simulated clock in the table's header."""

    header: np.ndarray

    @property
    def now(self) -> float:
        """The simulated time of the tick running or run last (0 before the first)."""
        return int(self.header[Header.SIM_TIME_NS]) / 1e9

    @property
    def tick_running(self) -> int:
        """The number of the tick running or run last (1 for the first)."""
        return int(self.header[Header.SIM_TICK])


class LockstepMaster(RingTime):
    """The supervisor's side: owns the semaphores, the tick counter and the time in the header."""

    def __init__(self, subsystem: str, run_id: str, roles: list[str], tick: float, header: np.ndarray) -> None:
        self.roles = list(roles)
        self.tick_ns = round(tick * 1e9)
        self.tick = self.tick_ns / 1e9
        self.header = header
        self.ticks = 0
        self.stepping, self.step_started = "", 0.0  # the participant released last, and when (wall clock)
        self._go: dict[str, posix_ipc.Semaphore] = {}
        self._done: posix_ipc.Semaphore | None = None
        self._turn_out = False  # a turn was released and not handed back yet (a wait that was given up)
        self._turn_ticks = False  # the turn out runs ticks (`advance`), not a step between ticks
        try:
            for role in self.roles:
                self._go[role] = posix_ipc.Semaphore(go_name(subsystem, run_id, role), posix_ipc.O_CREX, mode=0o600,
                                                     initial_value=0)
            self._done = posix_ipc.Semaphore(done_name(subsystem, run_id), posix_ipc.O_CREX, mode=0o600, initial_value=0)
        except BaseException:
            self.close()
            raise
        header[Header.SIM_TIME_NS] = 0
        header[Header.SIM_TICK] = 0
        header[Header.SIM_TICK_NS] = self.tick_ns
        header[Header.SIM_RING_END] = 0
        # before the run's participants exist: no one else writes the flags yet
        header[Header.FLAGS] = int(header[Header.FLAGS]) | Flag.SIM_CLOCK

    def advance(self, while_waiting: Callable[[], bool | None], ticks: int = 1) -> int:
        """Run up to `ticks` ticks, every participant in order in each; the number of ticks run.

        It stops sooner after a tick in which a participant queued an event, so job control
        takes it before the next tick. `while_waiting` runs every WAIT_SLICE meanwhile: it must
        not take events (the ring is still running). It may raise; returning True gives up.
        """
        header = self.header
        first = self.ticks + 1
        header[Header.SIM_RING_END] = self.ticks + max(ticks, 1)
        header[Header.SIM_TIME_NS] = self.ticks * self.tick_ns
        header[Header.SIM_TICK] = first
        try:
            self._turn(self.roles[0], while_waiting, ticks=True)
        finally:
            header[Header.SIM_RING_END] = 0  # a turn given up: the ring stops at its next hand-over
            self.ticks = int(header[Header.SIM_TICK])
        return self.ticks - first + 1

    def step(self, role: str, while_waiting: Callable[[], bool | None]) -> bool:
        """Release one participant with no new tick and wait until it is done (True); `while_waiting`
        runs every slice and may raise (a participant died) or return True to stop waiting (False)."""
        return self._turn(role, while_waiting)

    def recover(self, dead: str, while_waiting: Callable[[], bool | None]) -> RingStop:
        """Bring the ring to a stop after participant `dead` died, and say where the tick stands.

        The turn either comes back through `done` from a live participant (the ring's end is
        cleared, so the next hand-over gives it back), or is stuck at the dead one: its place in
        the header's turn word with `done` never released, whether it died holding the turn or
        a live one handed it over before the end was cleared. The dead one's `go` is drained
        (`forget`, again once its new process is launched: a hand-over may land just after),
        and no turn is out any more. `while_waiting` runs every WAIT_SLICE meanwhile; it may
        raise, or return True to give up (RingStuck).
        """
        header, done = self.header, self._done
        assert done is not None
        place = self.roles.index(dead)
        header[Header.SIM_RING_END] = 0  # a participant ending its turn from now on gives it back to the master
        came_back = True
        if self._turn_out:
            while not _acquired(done, 0.0):
                if int(header[Header.SIM_TURN]) == place:
                    came_back = False
                    break
                if _acquired(done, WAIT_SLICE):
                    break
                if while_waiting():
                    raise RingStuck(f"{self.running()} did not hand the turn back after {dead} died")
        self.forget(dead)
        self._turn_out = False
        tick = int(header[Header.SIM_TICK])
        self.ticks = tick
        unfinished: tuple[str, ...] = ()
        if self._turn_ticks:
            last = place if not came_back else int(header[Header.SIM_TURN])  # the last one to have had tick N
            unfinished = tuple(role for role in self.roles[last + 1:] if role != dead)
        self._turn_ticks = False
        return RingStop(tick, unfinished, not came_back)

    def forget(self, role: str) -> None:
        """Drain `role`'s `go`: a turn handed to a dead participant is not its new process's."""
        while _acquired(self._go[role], 0.0):
            pass

    def finish_tick(self, stop: RingStop, while_waiting: Callable[[], bool | None]) -> None:
        """Run tick `stop.tick` for the participants that had not run it, one turn each, in ring order.

        Each sees a tick it has not run (the header's tick is past its last), runs it in full, and
        gives the turn back (the ring's end is cleared): the time and the tick stay those of tick N.
        """
        self.header[Header.SIM_RING_END] = 0
        for role in stop.unfinished:
            self._turn(role, while_waiting, ticks=True)

    def _turn(self, role: str, while_waiting: Callable[[], bool | None], ticks: bool = False) -> bool:
        done = self._done
        assert done is not None
        if self._turn_out and not self._wait(done, while_waiting):  # the last turn first: one participant at a time
            self._turn_out = False  # given up on: the participant holding it is dead or stuck
        self.header[Header.SIM_TURN] = self.roles.index(role)  # whose turn it is, before it wakes (a stopped one is named)
        self._turn_ticks = ticks
        self._go[role].release()
        self._turn_out = True
        self.stepping, self.step_started = role, time.monotonic()  # for a watchdog in `while_waiting`
        if self._wait(done, while_waiting):
            self._turn_out = False
            return True
        return False

    @staticmethod
    def _wait(done: posix_ipc.Semaphore, while_waiting: Callable[[], bool | None]) -> bool:
        while True:
            try:
                done.acquire(WAIT_SLICE)
                return True
            except (posix_ipc.BusyError, posix_ipc.SignalError):  # a signal: Ctrl-C only sets a flag
                if while_waiting():
                    return False

    def running(self) -> str:
        """The participant whose turn it is (or was last)."""
        place = int(self.header[Header.SIM_TURN])
        return self.roles[place] if 0 <= place < len(self.roles) else self.stepping

    def close(self) -> None:
        remove_semaphores([*self._go.values(), *([self._done] if self._done is not None else [])])
        self._go.clear()
        self._done = None


class LockstepParticipant:
    """A plant's or an RTPU's side: wait for `go`, do the tick's work, hand the turn on (`done`).

    `ring` lists the participants in the order they run in a tick (`role` among them);
    `events_pending` says whether an event waits in job control's queue: the participant that
    ends a tick then hands the turn back to the master instead of beginning the next tick.
    """

    def __init__(self, subsystem: str, run_id: str, role: str, header: np.ndarray, ring: list[str],
                 events_pending: Callable[[], bool] = lambda: False, before_step: Callable[[], None] | None = None) -> None:
        place = ring.index(role)
        self._go = posix_ipc.Semaphore(go_name(subsystem, run_id, role))
        self._next = posix_ipc.Semaphore(go_name(subsystem, run_id, ring[(place + 1) % len(ring)]))
        self._done = posix_ipc.Semaphore(done_name(subsystem, run_id))
        self._place = place
        self._ends_tick = place == len(ring) - 1
        self._events_pending = events_pending
        self.header = header
        self._words = header.data  # the same words as plain ints: no numpy scalar per read
        # A participant started mid-run (for one that died) has no part in the ticks before it joined,
        # nor in a turn handed to the dead one (the master drains it too, but a hand-over may land late).
        self.last_tick = int(header[Header.SIM_TICK])
        while _acquired(self._go, 0.0):
            pass
        self.before_step = before_step  # run once released, before the step's work (an RTPU's link relays)
        self._new_tick = False

    def wait(self) -> bool:
        """Block until released; True if a new tick began (False: serve signals only)."""
        while True:
            process.raise_if_stopping()  # a stop that came while this process was not waiting
            try:
                self._go.acquire(1.0)
                break
            except (posix_ipc.BusyError, posix_ipc.SignalError):
                process.raise_if_stopping()  # a supervisor that died sent us its death signal (PDEATHSIG): Stop ends the wait
        if self.before_step is not None:
            self.before_step()
        words = self._words
        words[_SIM_TURN] = self._place
        tick = words[_SIM_TICK]
        self._new_tick = tick != self.last_tick
        if self._new_tick:
            self.last_tick = tick
        return self._new_tick

    def done(self) -> None:
        """Hand the turn on: to the next participant, to the first one for the next tick, or back to the master."""
        words = self._words
        end = words[_SIM_RING_END]
        if self._new_tick and end:
            if not self._ends_tick:
                words[_SIM_TURN] = self._place + 1  # the turn is the next one's before it wakes: a stopped one is named
                self._next.release()
                return
            tick = words[_SIM_TICK]
            if tick < end and not self._events_pending():
                words[_SIM_TIME_NS] = tick * words[_SIM_TICK_NS]
                words[_SIM_TICK] = tick + 1
                words[_SIM_TURN] = 0
                self._next.release()
                return
        self._done.release()

    def close(self) -> None:
        for semaphore in (self._go, self._next, self._done):
            semaphore.close()


def _acquired(semaphore: posix_ipc.Semaphore, timeout: float) -> bool:
    try:
        semaphore.acquire(timeout)
        return True
    except (posix_ipc.BusyError, posix_ipc.SignalError):
        return False


def remove_semaphores(semaphores: Iterable[posix_ipc.Semaphore]) -> None:
    """Unlink and close the semaphores a clock master made (one another process unlinked is passed over)."""
    for semaphore in semaphores:
        with contextlib.suppress(posix_ipc.ExistentialError):
            semaphore.unlink()
        semaphore.close()


def ring_arguments(ring: list[str]) -> list[str]:
    """What a participant is told on its command line about the ring (`--ring plant,rtpu0,...`)."""
    return ["--ring", ",".join(ring)]
