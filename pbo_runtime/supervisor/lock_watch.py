"""The supervisor's watch on the table lock: a holder past a bound is killed and the lock recovered.

Only RTPUs and job control's own writes take the table lock, each for microseconds; observers
read without it (`table.snapshot`). A holder that keeps it longer, dead, stopped (SIGSTOP) or
stuck, holds up every RTPU while the arm keeps its last command. Job control looks at the lock
record (`table.table`: whether the semaphore is taken, its holder's pid, the write sequence) at
every turn of its loop, at least every half bound, and every LOCK_LOOK_EVERY while the lock is
taken: a wedge is ended within one and a half bounds of its start. Every acquisition
signs the holder word and every write moves the sequence, so one (holder, sequence) seen taken
at every look is one holding, and `LockWatch` says when one has lasted `lock_hold_bound`: a few
periods of the fastest task, never under LOCK_HOLD_FLOOR. The bound is wall time on either
clock: the simulated clock does not advance while a participant holds the lock, since job
control waits for it.

What is then done (`LockGuard`): a live holder gets one last look, job control waiting
LOCK_LOOK_EVERY for the lock itself (a holder that only took it again and again is no wedge); a
dead holder's lock is released; a live one that is one of this run's processes is SIGKILLed and
its lock released once it is dead; any other process is never signalled. Each case is a
supervisor line and an entry of the run report's `lock_events`, and the run fails (exit 2). An
RTPU killed this way is then handled as any RTPU that died.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import posix_ipc

from pbo_runtime.ipc import shm
from pbo_runtime.objects.helper_threads import HELPER_FIFO_PRIORITY
from pbo_runtime.reports.run_records import LockEvent
from pbo_runtime.supervisor.children import Child
from pbo_runtime.supervisor.failures import RunFailure, StopRequested
from pbo_runtime.supervisor.fork_server import ForkedProcess
from pbo_runtime.supervisor.in_process import InProcessChild
from pbo_runtime.supervisor.run_report import STOP_TIMEOUT, RunResult
from pbo_runtime.table.table import StateTable

LOCK_HOLD_PERIODS = 5  # a holding past this many periods of the fastest task is a wedge ...
LOCK_HOLD_FLOOR = 0.05  # ... and never one under this (seconds): a VM steals milliseconds now and then
LOCK_LOOK_EVERY = 0.01  # seconds between looks while the lock is taken; also the last look's wait


def lock_hold_bound(shortest_period: float) -> float:
    """Wall seconds a holding of the table lock may last: LOCK_HOLD_PERIODS fastest periods, at least LOCK_HOLD_FLOOR."""
    return max(LOCK_HOLD_PERIODS * shortest_period, LOCK_HOLD_FLOOR)


@dataclass(frozen=True)
class LockSample:
    """One look at the lock record."""

    held: bool
    holder: int  # the pid that signed the last acquisition
    sequence: int  # the write sequence (odd while a writer writes)


@dataclass
class Holding:
    """One holding of the lock as the looks saw it, on the wall clock (time.monotonic)."""

    holder: int
    sequence: int
    since: float  # the first look that saw it
    last: float  # the latest look that saw it
    ended: bool = False  # reported and dealt with: a holder left alone is not reported again

    @property
    def seconds(self) -> float:
        return self.last - self.since


class LockWatch:
    """Follows the holdings of the lock from looks at its record; says when one has lasted `bound`."""

    def __init__(self, bound: float, sample: Callable[[], LockSample], clock: Callable[[], float] = time.monotonic) -> None:
        self.bound = bound
        self._sample = sample
        self._clock = clock
        self.holding: Holding | None = None

    def look(self) -> Holding | None:
        """Look once; the holding if it has lasted the bound (its holder is then for the caller to end)."""
        now = self._clock()
        sample = self._sample()
        if not sample.held:
            self.holding = None
            return None
        holding = self.holding
        if holding is None or (holding.holder, holding.sequence) != (sample.holder, sample.sequence):
            self.holding = Holding(sample.holder, sample.sequence, now, now)
            return None
        holding.last = now
        return holding if holding.seconds >= self.bound and not holding.ended else None

    def next_look_in(self, idle: float) -> float:
        """How long job control may wait before its next look: `idle` up to half the bound, or
        LOCK_LOOK_EVERY while the lock is taken (the arm runs on its last command meanwhile)."""
        return min(idle, LOCK_LOOK_EVERY if self.holding is not None else self.bound / 2)

    def forget(self) -> None:
        self.holding = None


@dataclass(frozen=True)
class LockVerdict:
    """What is done about a holding past the bound, decided from its holder alone."""

    action: str  # "released" (dead holder), "killed" (a live process of this run), "left" (any other)
    state: str  # the holder: "dead", "stopped" or "running"
    why_left: str = ""  # for "left": what the run's line says


def holder_alive(state: str) -> bool:
    """Whether a process in this /proc state (`shm.pid_state`; "" when gone) still holds what it took."""
    return bool(state) and state not in ("Z", "X")


def lock_verdict(pid: int, own_pid: int, state: str, ours: bool) -> LockVerdict:
    """What is done to the holder `pid` (in /proc `state`; `ours`: a child of this run) of a lock held
    past the bound: an unsigned lock or one of another process is left and the run stops, a dead
    holder's lock is released, a live child of the run is killed."""
    alive = holder_alive(state)
    how = "stopped" if state in ("T", "t") else "running" if alive else "dead"
    if pid in (0, own_pid):
        return LockVerdict("left", how, "it cannot be told who holds it; the run is stopped")
    if not alive:
        return LockVerdict("released", how)
    if ours:
        return LockVerdict("killed", how)
    return LockVerdict("left", how, "it is not a process of this run, so it was not signalled; the run is stopped")


class LockGuard:
    """Job control's guard of the table lock: its own writes wait through it, never for good, and a
    holding past the bound is ended (`lock_verdict`) with RunFailure. Made with the run's table."""

    def __init__(self, table: StateTable, shortest_period: float, result: RunResult, children: list[Child],
                 say: Callable[[str], None], run_time: Callable[[], float], check_children: Callable[[], None],
                 stop_requested: Callable[[], str], serving: Callable[[], bool], fifo: bool = False) -> None:
        self.table = table
        self.result = result
        self.children = children  # the run's children (the list the supervisor keeps up to date)
        self.say = say
        self.run_time = run_time  # seconds since the configuration came on (0 before)
        self.check_children = check_children  # looks at the lock too: a wedge is ended rather than waited out
        self.stop_requested = stop_requested  # why the run is asked to stop ("" while it is not)
        self.serving = serving  # whether an operator's command is being served (`ControlService`)
        table.lock_wait = self.take_table_lock
        if fifo:  # the RTPUs run SCHED_FIFO: job control holds the lock above every ordinary process
            table.lock_ceiling = HELPER_FIFO_PRIORITY
        self.watch = LockWatch(lock_hold_bound(shortest_period),
                               lambda: LockSample(table.lock_held, table.lock_holder, table.lock_sequence))

    def take_table_lock(self) -> None:
        """Job control's wait for the lock: never for good, and a Ctrl-C or a dead child ends it."""
        self.table.acquire_watching(LOCK_LOOK_EVERY, self.while_waiting_for_the_lock)

    def while_waiting_for_the_lock(self) -> None:
        self.check_children()
        stop = self.stop_requested()
        if stop:
            if self.serving():  # a PboError is what an operator's command answers with; the next turn of the loop stops
                raise RunFailure(f"stopped by {stop} while waiting for the table lock")
            raise StopRequested(stop)

    def look(self) -> None:
        """One look (every turn of job control's loop); ends a holding past the bound with RunFailure."""
        holding = self.watch.look()
        if holding is not None:
            self._end_holding(holding)

    def look_while_stopping(self) -> None:
        """The same while the run stops: a wedge must not hold up the children's stop; the first failure is kept."""
        try:
            self.look()
        except RunFailure as exc:
            if not self.result.failure:
                self.result.failure = str(exc)
                self.result.stopped_by = "failure"

    def _end_holding(self, holding: Holding) -> None:
        pid = holding.holder
        child = next((c for c in self.children if c.process.pid == pid), None)
        state = shm.pid_state(pid) if pid not in (0, os.getpid()) else ""
        if holder_alive(state) and self._lock_comes_free():
            self.watch.forget()  # it was taken again and again, not held: no wedge
            return
        verdict = lock_verdict(pid, os.getpid(), state, child is not None)
        how, action, done = verdict.state, verdict.action, verdict.why_left
        who = _describe(child, pid)
        released = False
        if action == "released":
            released = self.table.recover_lock_from(pid)
            action, done = ("released", "the lock was released") if released else ("left", "it could not be released")
        elif action == "killed":
            assert child is not None
            _kill(child.process)
            # reaped, and it held the lock up to the last look: only a taker that has not signed yet
            # could be mistaken for it, a window of microseconds; the arm waits meanwhile
            released = self.table.recover_lock_from(pid, settle=LOCK_LOOK_EVERY)
            done = "it was killed (SIGKILL) and the lock released" if released else "it was killed (SIGKILL)"
        if released:
            self.result.lock_recoveries += 1
        held_ms = holding.seconds * 1e3
        self.result.lock_events.append(LockEvent(pid, who, child.role if child is not None else "", how, held_ms,
                                                 self.watch.bound * 1e3, action, self.run_time()))
        holding.ended = True
        if action != "left":
            self.watch.forget()  # the lock is free again
        message = (f"the table lock was held for {held_ms:.0f} ms (bound {self.watch.bound * 1e3:.0f} ms) by {who}, "
                   f"{how}: {done}"
                   + (f"; it hosted tasks: {', '.join(child.tasks)}" if child is not None and child.tasks else ""))
        self.say(message)
        if not self.result.failure:  # the run fails even where the raise is answered to a command instead
            self.result.failure, self.result.stopped_by = message, "failure"
        raise RunFailure(message)

    def _lock_comes_free(self) -> bool:
        """The last look: can job control take the lock within LOCK_LOOK_EVERY? (released at once)"""
        try:
            self.table.lock.acquire(LOCK_LOOK_EVERY)
        except (posix_ipc.BusyError, posix_ipc.SignalError):
            return False
        self.table.lock.release()
        return True


def _describe(child: Child | None, pid: int) -> str:
    if pid == 0 or pid == os.getpid():
        return "a process that did not sign the lock"
    if child is None:
        return f"pid {pid}, not a process of this run"
    return f"the plant (pid {pid})" if child.role == "plant" else f"RTPU '{child.role}' (pid {pid})"


def _kill(process: subprocess.Popen[Any] | ForkedProcess | InProcessChild) -> None:
    """SIGKILL (it ends a stopped process too) and reap, so the lock's holder is dead when it is recovered."""
    try:
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=STOP_TIMEOUT)
    except (OSError, subprocess.TimeoutExpired):
        pass
