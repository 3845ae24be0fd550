"""One simulated clock for a whole application (`pbo run APP.yaml --clock sim`): subsystems take turns.

Each subsystem of an application is its own `pbo run`, with its own supervisor as the lockstep
master of its plant and RTPUs (`clock.lockstep`). Left alone, each would advance at its own wall
speed, and a link between two of them (a triple buffer, a message queue) would be read at a tick
that depends on the scheduler. So the application's runner is the master of the subsystems' masters:

- it gives the turn to one subsystem at a time, through that subsystem's `go` and `done`
  semaphores (0600, named after the runner's run, so a later run removes them if this one died);
- the subsystem whose next tick comes first in simulated time goes next (ties: the order of the
  application file), so subsystems with different ticks interleave by time, the same way every run;
- a subsystem's supervisor takes the turn (`TurnGate.take`) before any lockstep activity, a tick
  or a step between ticks that serves a signal, and gives it back after one tick: whatever it does
  between ticks (spawning, turning on, stopping tasks, an `off` writing its last value to a link)
  happens inside its turn. Turn k of a subsystem thus ends with its tick at (k - 1) x its tick;
- when its run ends it keeps the turn through its shutdown and exits: the master sees the process
  end while it waits for `done` and drops it from the rotation.

The turn is abandoned (no longer waited for) once the subsystem is asked to stop or has failed: the
runner then stops every subsystem at once, and the run is no longer one that replays.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import posix_ipc

from pbo_runtime.clock.lockstep import remove_semaphores
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import shm

WAIT_SLICE = 0.05  # seconds between looks at the processes while waiting for a turn or its end


class TurnStalled(PboError):
    """A participant held the application's turn past the watchdog's limit: every subsystem waits for it."""


def turn_base(application: str, run_id: str, key: str) -> str:
    """The base name of subsystem `key`'s turn semaphores (`pbo run --turn` takes it)."""
    return shm.object_name(application, run_id, f"turn-{key}")


def turn_names(base: str) -> tuple[str, str]:
    """The (go, done) semaphore names of one subsystem's turn."""
    return f"{base}.go", f"{base}.done"


class TurnGate:
    """A subsystem's side: wait for the application's turn before lockstep activity, give it back after a tick."""

    def __init__(self, base: str, abandoned: Callable[[], bool] = lambda: False) -> None:
        go, done = turn_names(base)
        self._go = posix_ipc.Semaphore(go)
        self._done = posix_ipc.Semaphore(done)
        self.abandoned = abandoned  # True once the run stops early: then the turn is no longer waited for
        self.held = False
        self.open = False  # abandoned: every take returns at once from then on
        self.turns = 0

    def take(self, while_waiting: Callable[[], bool | None]) -> bool:
        """Hold the turn (waiting for it if needed); False if `while_waiting` returned True to stop waiting.

        `while_waiting` runs every slice while the other subsystems have the turn; it may raise.
        """
        if self.held or self.open:
            return True
        while True:
            if self.abandoned():
                self.open = True
                return True
            try:
                self._go.acquire(WAIT_SLICE)
                self.held = True
                self.turns += 1
                return True
            except (posix_ipc.BusyError, posix_ipc.SignalError):  # a signal: Ctrl-C only sets a flag
                if while_waiting():
                    return False

    def give(self) -> None:
        """After a tick: the turn goes back to the application's master."""
        if self.held and not self.open:
            self.held = False
            self._done.release()

    def close(self) -> None:
        for semaphore in (self._go, self._done):
            semaphore.close()


class ApplicationLockstep:
    """The runner's side: owns every subsystem's turn semaphores and gives the turn in order of simulated time."""

    def __init__(self, application: str, run_id: str, ticks: dict[str, float]) -> None:
        """`ticks`: each subsystem's tick in seconds, in the order of the application file."""
        self.order = {key: index for index, key in enumerate(ticks)}
        self.tick_ns = {key: round(tick * 1e9) for key, tick in ticks.items()}
        self.turns = {key: 0 for key in ticks}  # turns given so far: the next one ends with tick number `turns`
        self.rotation = list(ticks)  # the subsystems still running
        self.bases = {key: turn_base(application, run_id, key) for key in ticks}
        self.holding, self.held_since = "", 0.0  # who has the turn, and since when (wall clock)
        self._go: dict[str, posix_ipc.Semaphore] = {}
        self._done: dict[str, posix_ipc.Semaphore] = {}
        try:
            for key, base in self.bases.items():
                go, done = turn_names(base)
                self._go[key] = posix_ipc.Semaphore(go, posix_ipc.O_CREX, mode=0o600, initial_value=0)
                self._done[key] = posix_ipc.Semaphore(done, posix_ipc.O_CREX, mode=0o600, initial_value=0)
        except BaseException:
            self.close()
            raise

    def next_time(self, key: str) -> float:
        """The simulated time of the tick subsystem `key`'s next turn ends with."""
        return self.turns[key] * self.tick_ns[key] / 1e9

    def next_turn(self) -> str:
        """The subsystem whose next tick comes first in simulated time; ties in the file's order."""
        return min(self.rotation, key=lambda key: (self.turns[key] * self.tick_ns[key], self.order[key]))

    def give_turn(self, key: str, ended: Callable[[str], bool], while_waiting: Callable[[], None]) -> bool:
        """Give subsystem `key` one turn and wait until it gives it back (True) or its process ends (False).

        A subsystem whose process ended is dropped from the rotation. `while_waiting` runs every
        slice (it may raise: another subsystem failed, or a stop was asked for).
        """
        self.turns[key] += 1
        self.holding, self.held_since = key, time.monotonic()
        self._go[key].release()
        done = self._done[key]
        while True:
            try:
                done.acquire(WAIT_SLICE)
                self.holding = ""
                return True
            except (posix_ipc.BusyError, posix_ipc.SignalError):
                if ended(key):
                    self.rotation.remove(key)
                    self.holding = ""
                    return False
                while_waiting()

    def held_for(self) -> float:
        """Wall seconds the subsystem holding the turn has held it (0 when no one does)."""
        return time.monotonic() - self.held_since if self.holding else 0.0

    def close(self) -> None:
        remove_semaphores([*self._go.values(), *self._done.values()])
        self._go.clear()
        self._done.clear()
