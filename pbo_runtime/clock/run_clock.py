"""The clock a run is supervised on: real time, or the simulated clock's lockstep ticks.

The executive takes its clock as a parameter (`clocks.RealClock`, `clocks.SimClock`); the
supervisor does the same with a `RunClock`, so what differs between the two clocks is said
here once instead of in branches through the supervisor:

- `RealRunClock`: time is CLOCK_MONOTONIC; the children run on their own timers, RTPUs release
  staggered over the shortest period, a plan needs a wake-up on each RTPU's queue, and the
  supervisor waits for events between its own turns.
- `SimRunClock`: the supervisor is the clock master (`clock.lockstep`): time is the tick count,
  moved only by `run_for`, which lets the participants run the ticks among themselves until one
  of them sends an event; a signal is served in full when its RTPU is stepped, so its answer
  is already queued when `serve` returns; children run with a fixed string hash so a run
  replays bit for bit. A participant that dies is brought back between ticks: the ring is
  stopped where it stood, the tick the death happened in is finished for the live participants
  after it (`clock.lockstep`, `RingStop`), and its new process joins from the next tick. In an
  application on the simulated clock it takes the application's turn
  (`clock.application_lockstep`) before each tick or step, and gives it back after each tick.
  With `one_process` the participants are hosted in the supervisor's process and the ring is
  a loop of calls (`clock.local_ring`), the same turns in the same order. With a `pace` (`pbo run
  --pace`), simulated time runs no faster than that many seconds per wall second, for a person
  watching it: the master waits on the wall clock between turns of the ring, never within one,
  so the ticks and what they compute are the same as unpaced.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from pbo_runtime.clock.application_lockstep import TurnGate, TurnStalled
from pbo_runtime.clock.clocks import release_stagger
from pbo_runtime.clock.local_ring import LocalRing
from pbo_runtime.clock.lockstep import LockstepMaster, RingStop, ring_arguments, semaphore_names
from pbo_runtime.table.table import Header

TURN_STALL_SECONDS = 30.0  # wall seconds one participant may take over a tick while a whole application waits
PACE_TURN = 0.01  # paced: wall seconds between two looks at the wall clock (the ring runs the ticks they cover)
PACE_BEHIND = 0.1  # paced: wall seconds a run may fall behind its pace before it stops catching up (a slow machine)


class RunClock(Protocol):
    """What the supervisor asks of its clock."""

    name: str  # "real" or "sim", as `pbo run --clock` names it
    tick: float  # seconds per tick of the simulated clock; 0 on the real clock
    fifo_by_default: bool  # RTPUs ask for SCHED_FIFO unless told otherwise
    on_monotonic: bool  # its times are CLOCK_MONOTONIC seconds (lined up with a trace of the machine)
    watches_stalls: bool  # a task whose cycle count stops moving is reported (StallWatch)
    signals_served_when_sent: bool  # a signal's answer is queued when `serve` returns (no waiting for it)
    plans_need_a_wakeup: bool  # RTPUs must be woken to read a plan in the header
    one_process: bool  # the participants are hosted in the supervisor's process (`--one-process`)

    def now(self) -> float:
        """The run's time."""
    def semaphores(self, subsystem: str, run_id: str, roles: list[str]) -> list[str]:
        """The names of the semaphores this clock will make for these participants (for the manifest)."""
    def start(self, subsystem: str, run_id: str, roles: list[str], header: np.ndarray) -> float:
        """Start the clock for a run whose table has `header`; the release epoch."""
    def stagger(self, shortest_period: float, n_rtpus: int) -> float:
        """The offset between consecutive RTPUs' release grids."""
    def plant_arguments(self) -> list[str]:
        """What the plant is told about the clock on its command line."""
    def child_environment(self) -> dict[str, str] | None:
        """The children's environment (None: the supervisor's own)."""
    def run_for(self, timeout: float, wait_for_events: Callable[[float], None], while_stepping: Callable[[], None],
                while_ticking: Callable[[], None]) -> None:
        """Let the run go on for `timeout`: wait for events, or run the ticks that cover it (at least one).

        `while_stepping` runs after each tick that sent events (and after the last), `while_ticking`
        while the ticks run, which must take no event.
        """
    def serve(self, role: str, while_waiting: Callable[[], bool | None]) -> None:
        """Have participant `role` serve the signals queued for it now (a no-op where it serves them itself)."""
    def take_turn(self, while_waiting: Callable[[], None]) -> None:
        """In an application on the simulated clock: wait for the application's turn (no-op elsewhere)."""
    def announce_stop(self, announce: Callable[[], None]) -> None:
        """Tell the children the run is stopping before they are signalled (where they run on their own)."""
    def slow_participant(self, limit: float) -> tuple[str, float, float] | None:
        """Once per tick: (who, at what time, for how long) when one participant took over `limit` wall seconds."""
    def stop_ring(self, role: str, while_waiting: Callable[[], bool | None]) -> None:
        """Participant `role` died: stop the ticks where they stood (a no-op where there are none)."""
    def forget_turn(self, role: str) -> None:
        """A turn handed to the dead `role` is not for its new process (a no-op where there are none)."""
    def finish_tick(self, while_waiting: Callable[[], bool | None]) -> None:
        """Run the tick a death interrupted for the participants that had not run it (a no-op where there are none)."""
    def join(self, role: str, step: Callable[[bool], None], events_pending: Callable[[], bool]) -> None:
        """One process: participant `role`, hosted here, takes its turns through `step`; `events_pending`:
        job control's queue holds an event."""
    def close(self) -> None:
        """Remove what the clock made."""


class RealRunClock:
    """Wall time: CLOCK_MONOTONIC, shared by every process of the machine."""

    name = "real"
    tick = 0.0
    fifo_by_default = True  # under SCHED_OTHER the machine's threads hold a CPU for milliseconds
    on_monotonic = True
    watches_stalls = True
    signals_served_when_sent = False
    plans_need_a_wakeup = True
    one_process = False

    def now(self) -> float:
        return time.monotonic()

    def semaphores(self, subsystem: str, run_id: str, roles: list[str]) -> list[str]:
        return []

    def start(self, subsystem: str, run_id: str, roles: list[str], header: np.ndarray) -> float:
        epoch = time.monotonic()
        header[Header.RELEASE_EPOCH_NS] = int(epoch * 1e9)  # for whoever lines up with the releases from outside (bench.realtime)
        return epoch

    def stagger(self, shortest_period: float, n_rtpus: int) -> float:
        return release_stagger(shortest_period, n_rtpus)

    def plant_arguments(self) -> list[str]:
        return []

    def child_environment(self) -> dict[str, str] | None:
        return None

    def run_for(self, timeout: float, wait_for_events: Callable[[float], None], while_stepping: Callable[[], None],
                while_ticking: Callable[[], None]) -> None:
        wait_for_events(timeout)

    def serve(self, role: str, while_waiting: Callable[[], bool | None]) -> None:
        pass  # an RTPU serves its queue between its own releases

    def take_turn(self, while_waiting: Callable[[], None]) -> None:
        pass

    def announce_stop(self, announce: Callable[[], None]) -> None:
        announce()

    def slow_participant(self, limit: float) -> tuple[str, float, float] | None:
        return None

    def stop_ring(self, role: str, while_waiting: Callable[[], bool | None]) -> None:
        pass

    def forget_turn(self, role: str) -> None:
        pass

    def finish_tick(self, while_waiting: Callable[[], bool | None]) -> None:
        pass

    def join(self, role: str, step: Callable[[bool], None], events_pending: Callable[[], bool]) -> None:
        raise NotImplementedError("one process is for the simulated clock only")

    def close(self) -> None:
        pass


class SimRunClock:
    """Simulated time in lockstep ticks, the supervisor as clock master (`clock.lockstep`)."""

    name = "sim"
    fifo_by_default = False  # it waits on ticks, not on time
    on_monotonic = False
    watches_stalls = False  # a stuck participant is reported per tick instead (slow_participant)
    signals_served_when_sent = True
    plans_need_a_wakeup = False  # the simulated clock's RTPUs read the header every tick anyway

    def __init__(self, tick: float, gate: TurnGate | None = None, one_process: bool = False, pace: float | None = None,
                 stall_limit: float = TURN_STALL_SECONDS) -> None:
        self.tick = tick
        # `--pace`: at most this many simulated seconds per wall second (None: as fast as the machine allows)
        self.pace = pace
        self._paced_from: tuple[float, float] | None = None  # (wall, simulated) seconds the pace is counted from
        # `--one-process`: the participants are hosted in this process and take their turns by calls
        # (`clock.local_ring`), in the order the processes would take them
        self.one_process = one_process
        self.lockstep: LockstepMaster | LocalRing | None = None
        self.roles: list[str] = []
        # The most ticks the participants run among themselves before job control looks (None: as
        # many as `run_for` covers; they stop sooner after a tick that sent an event). 1 gives job
        # control every tick, for a master that must interleave ticks with others'.
        self.ticks_per_turn: int | None = None
        self._slow_tick = -1  # the tick last reported as slow
        self.gate = gate  # in an application: the application's turn, taken before any lockstep activity
        self.stall_limit = stall_limit  # in an application: wall seconds one participant may hold every subsystem
        if gate is not None:
            self.ticks_per_turn = 1  # the application interleaves its subsystems tick by tick
        self._watched: tuple[float, int, str] = (0.0, 0, "")  # (turn released at, tick, participant) last looked at
        self._watched_since = 0.0
        self.ring_stop: RingStop | None = None  # where a death stopped the ring, until its tick is finished

    def now(self) -> float:
        return self.lockstep.now if self.lockstep is not None else 0.0

    def semaphores(self, subsystem: str, run_id: str, roles: list[str]) -> list[str]:
        return [] if self.one_process else semaphore_names(subsystem, run_id, roles)

    def start(self, subsystem: str, run_id: str, roles: list[str], header: np.ndarray) -> float:
        self.roles = list(roles)
        self.lockstep = (LocalRing(roles, self.tick, header) if self.one_process
                         else LockstepMaster(subsystem, run_id, roles, self.tick, header))
        return self.now()

    def stagger(self, shortest_period: float, n_rtpus: int) -> float:
        return 0.0  # RTPUs run in turn within a tick: they cannot collide on the lock

    def plant_arguments(self) -> list[str]:
        return ["--clock", "sim", *ring_arguments(self.roles)]

    def child_environment(self) -> dict[str, str] | None:
        return {**os.environ, "PYTHONHASHSEED": "0"}  # a replayed run must not depend on string hashing

    def run_for(self, timeout: float, wait_for_events: Callable[[float], None], while_stepping: Callable[[], None],
                while_ticking: Callable[[], None]) -> None:
        assert self.lockstep is not None
        gate = self.gate
        left = max(1, math.floor(timeout / self.tick + 1e-9))
        limit = self.ticks_per_turn or left
        if self.pace is not None:
            limit = min(limit, max(1, round(PACE_TURN * self.pace / self.tick)))
        while left > 0:
            if self.pace is not None:
                self._keep_pace()  # before the application's turn: another subsystem may use the wait
            if gate is not None:
                gate.take(while_stepping)
            left -= self.lockstep.advance(while_ticking, min(left, limit))
            if gate is not None:
                gate.give()  # one tick a turn: the application's next turn may be another subsystem's
            while_stepping()

    def _keep_pace(self) -> None:
        """Wait until the wall clock has caught up with simulated time at the pace; a run that fell
        behind it (a machine slower than the pace) counts its pace from now rather than rushing."""
        assert self.pace is not None
        wall, simulated = time.monotonic(), self.now()
        if self._paced_from is None:
            self._paced_from = (wall, simulated)  # the first tick: start-up is not paced
            return
        ahead = self._paced_from[0] + (simulated - self._paced_from[1]) / self.pace - wall
        if ahead > 0:
            time.sleep(ahead)
        elif ahead < -PACE_BEHIND:
            self._paced_from = (wall, simulated)

    def serve(self, role: str, while_waiting: Callable[[], bool | None]) -> None:
        if self.lockstep is not None:
            if self.gate is not None and not self.gate.take(while_waiting):
                return  # told to stop waiting for the turn (the participant died, or a stop's deadline passed)
            self.lockstep.step(role, while_waiting)  # served now, between ticks: at a known instant

    def take_turn(self, while_waiting: Callable[[], None]) -> None:
        if self.gate is not None:
            self.gate.take(while_waiting)

    def announce_stop(self, announce: Callable[[], None]) -> None:
        pass  # the stop signal is served in step

    def slow_participant(self, limit: float) -> tuple[str, float, float] | None:
        lockstep, gate = self.lockstep, self.gate
        if lockstep is None or (gate is not None and not gate.held):
            return None  # waiting for the application's turn: none of ours is stepping
        # The participants pass ticks among themselves: a participant's tick is timed from the
        # turn's release or from the first look that saw it running, whichever is later.
        now, tick, running = time.monotonic(), lockstep.tick_running, lockstep.running()
        watched = (lockstep.step_started, tick, running)
        if watched != self._watched:
            same_turn = self._watched[0] == lockstep.step_started
            self._watched = watched
            self._watched_since = now if same_turn else lockstep.step_started
        waited = now - self._watched_since
        if gate is not None and waited > self.stall_limit:
            raise TurnStalled(f"{running} has not finished the tick at {lockstep.now:.3f} s after {waited:.1f} s "
                              "of wall time, and every subsystem of the application waits for it: a cycle there has "
                              "not returned")
        if waited > limit and self._slow_tick != tick:
            self._slow_tick = tick
            return running, lockstep.now, waited
        return None

    def stop_ring(self, role: str, while_waiting: Callable[[], bool | None]) -> None:
        if self.lockstep is None:
            return
        stop = self.lockstep.recover(role, while_waiting)  # (RingStuck, a PboError, fails the run)
        if self.ring_stop is None or stop.unfinished:  # a new process that died at once keeps the first stop's tick
            self.ring_stop = stop

    def forget_turn(self, role: str) -> None:
        if self.lockstep is not None:
            self.lockstep.forget(role)

    def finish_tick(self, while_waiting: Callable[[], bool | None]) -> None:
        stop, self.ring_stop = self.ring_stop, None
        if stop is not None and self.lockstep is not None:
            self.lockstep.finish_tick(stop, while_waiting)

    def join(self, role: str, step: Callable[[bool], None], events_pending: Callable[[], bool]) -> None:
        assert isinstance(self.lockstep, LocalRing), "a participant joins the ring only in one process"
        self.lockstep.join(role, step, events_pending)

    def close(self) -> None:
        if self.lockstep is not None:
            self.lockstep.close()
        if self.gate is not None:
            self.gate.close()  # the turn is not given back: the master sees this process end
