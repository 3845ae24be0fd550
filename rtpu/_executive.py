"""The RTPU executive: one thread that releases ON tasks on absolute deadlines (DESIGN §3).

It waits for the earliest release with a timed receive on its signal queue, so signals and
timers share one wait; then runs the ready tasks, critical first, then earliest deadline
(maximum-urgency-first). Release times advance by the period from the previous release, so
the rate does not drift. Per task it keeps cycles, execution time, release jitter and overruns
in the table's status block, and samples for percentiles in preallocated rings.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Protocol

import numpy as np

from pbo_runtime._lifecycle import Task
from pbo_runtime._module import Status
from pbo_runtime._table import Status as W
from pbo_runtime._table import TaskState

RING = 1 << 16  # samples kept per task for percentiles (65 s at 1 kHz)


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep_until(self, deadline: float) -> None: ...


class SignalSource(Protocol):
    def receive(self, timeout: float | None) -> list[Any] | None: ...


class Scheduled:
    """A task's place in the executive: its next release and its timing record."""

    __slots__ = ("task", "period", "critical", "priority", "release", "overruns", "missed", "jitter", "exec_time", "samples",
                 "jitter_max", "exec_max", "status")

    def __init__(self, task: Task) -> None:
        self.task = task
        self.period = task.spec.period
        self.critical = task.spec.critical
        self.priority = task.spec.priority
        self.release = math.inf
        self.overruns = 0
        self.missed = 0
        self.jitter = np.zeros(RING)
        self.exec_time = np.zeros(RING)
        self.samples = 0
        self.jitter_max = 0.0
        self.exec_max = 0.0
        self.status = task.status

    def statistics(self) -> dict[str, float]:
        n = min(self.samples, RING)
        jitter = self.jitter[:n]
        exec_time = self.exec_time[:n]
        pct = (lambda a, q: float(np.percentile(a, q)) if n else 0.0)
        return {
            "cycles": self.task.cycles,
            "overruns": self.overruns,
            "missed": self.missed,
            "errors": self.task.errors,
            "jitter_p50": pct(jitter, 50), "jitter_p99": pct(jitter, 99), "jitter_max": self.jitter_max,
            "exec_p50": pct(exec_time, 50), "exec_p99": pct(exec_time, 99), "exec_max": self.exec_max,
            "bytes_in": self.task.local.bytes_in,
            "bytes_out": self.task.local.bytes_out,
            "bytes_per_cycle": self.task.local.bytes_in + self.task.local.bytes_out,
            "bytes_moved_per_cycle": self.task.local.bytes_moved,
        }


class Executive:
    """Runs the tasks of one RTPU. `handle` deals with one signal; `run_once` is one wait + cycles."""

    def __init__(self, clock: Clock, signals: SignalSource, report: Callable[..., None], epoch: float = 0.0) -> None:
        self.clock = clock
        self.signals = signals
        self.report = report  # report(kind, *fields): events to job control
        self.epoch = epoch  # releases are aligned to epoch + k * period
        self.tasks: dict[str, Scheduled] = {}
        self.on: list[Scheduled] = []
        self.running = True
        self.idle_wait = 0.05

    # --- the loop ---------------------------------------------------------------------------

    def run(self) -> None:
        while self.running:
            self.run_once()

    def run_once(self) -> None:
        clock = self.clock
        next_release = math.inf
        for s in self.on:
            if s.release < next_release:
                next_release = s.release
        wait = next_release - clock.now() if self.on else self.idle_wait
        spin = getattr(clock, "spin", 0.0)
        message = self.signals.receive(wait - spin if wait > spin else 0)
        if message is not None:
            self.handle(message)
            return
        if not self.on:
            return
        clock.sleep_until(next_release)
        self._run_ready()

    def _run_ready(self) -> None:
        """Run every released task once, most urgent first (maximum-urgency-first); no allocation.

        Urgency: critical before not; then the earlier deadline (release + period); then the
        higher user priority.
        """
        clock = self.clock
        on = self.on
        while True:
            now = clock.now()
            best = None
            for s in on:
                if s.release > now:
                    continue
                if best is None or s.critical > best.critical:
                    best = s
                elif s.critical == best.critical:
                    deadline, best_deadline = s.release + s.period, best.release + best.period
                    if deadline < best_deadline or (deadline == best_deadline and s.priority > best.priority):
                        best = s
            if best is None:
                return
            self._cycle(best, now)

    def _cycle(self, s: Scheduled, start: float) -> None:
        release = s.release
        status = s.status
        jitter = start - release
        status[W.JITTER_LAST] = jitter
        if jitter > s.jitter_max:
            s.jitter_max = jitter
            status[W.JITTER_MAX] = jitter
        result = s.task.run_cycle(release)
        end = self.clock.now()
        took = end - start
        k = s.samples & (RING - 1)
        s.jitter[k] = jitter
        s.exec_time[k] = took
        s.samples += 1
        status[W.EXEC_LAST] = took
        if took > s.exec_max:
            s.exec_max = took
            status[W.EXEC_MAX] = took
        following = release + s.period
        if end > following:
            # The deadline passed: count the overrun and skip the releases already gone,
            # keeping the phase (next = release + k * period, never end + period).
            s.overruns += 1
            skipped = int((end - release) // s.period)
            s.missed += skipped - 1 if skipped > 1 else 0
            status[W.OVERRUNS] = s.overruns
            following = release + skipped * s.period
            if following <= end:
                following += s.period
        s.release = following
        if result != Status.CONTINUE:
            self._leave_on(s)
            self._report_state(s.task)

    # --- signals ----------------------------------------------------------------------------

    def add(self, task: Task) -> None:
        self.tasks[task.name] = Scheduled(task)

    def handle(self, message: list[Any]) -> None:
        op = message[0]
        if op == "stop":
            self.stop()
            return
        if op == "stats":
            self.report("stats", {name: s.statistics() for name, s in self.tasks.items()})
            return
        name = message[1]
        s = self.tasks.get(name)
        if s is None:
            self.report("refused", name, f"no task '{name}' on this RTPU")
            return
        task = s.task
        try:
            if op == "spawn":
                task.spawn(self.clock.now())
            elif op == "on":
                at = message[2] if len(message) > 2 and message[2] is not None else self.clock.now()
                s.release = self._first_release(s, at)
                if task.turn_on(self.clock.now()):
                    self.on.append(s)
            elif op == "off":
                self._leave_on(s)
                task.turn_off()
            elif op == "kill":
                self._leave_on(s)
                task.kill()
            elif op == "clear":
                task.clear()
            else:
                self.report("refused", name, f"unknown signal '{op}'")
                return
        except Exception as exc:  # a refused signal is job control's mistake, not a crash
            self.report("refused", name, f"{op}: {exc}")
            return
        self._report_state(task)

    def stop(self) -> None:
        """Turn everything off and kill it (kill runs off first), then report statistics."""
        for s in list(self.tasks.values()):
            if s.task.state in (TaskState.ON, TaskState.OFF, TaskState.ERROR):
                self._leave_on(s)
                try:
                    s.task.kill()
                except Exception as exc:
                    self.report("refused", s.task.name, f"kill: {exc}")
                self._report_state(s.task)
        self.report("stats", {name: s.statistics() for name, s in self.tasks.items()})
        self.running = False

    def _first_release(self, s: Scheduled, at: float) -> float:
        periods = math.ceil((at - self.epoch) / s.period - 1e-9)
        return self.epoch + max(periods, 0) * s.period

    def _leave_on(self, s: Scheduled) -> None:
        if s in self.on:
            self.on.remove(s)

    def _report_state(self, task: Task) -> None:
        self.report("state", task.name, task.state.name, task.last_error)
