"""How the supervisor hears from its children: signals sent to a task's RTPU and the typed events
that come back (`ipc.messages`), waiting for a child to start or a task to change state, on the
real clock by waiting for events, on the simulated clock by stepping the RTPU that serves them."""

from __future__ import annotations

import time
from typing import Any, Callable

import posix_ipc

from pbo_runtime.clock.run_clock import RunClock
from pbo_runtime.config.model import Subsystem
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import messages
from pbo_runtime.supervisor.failures import RunFailure, StopRequested
from pbo_runtime.supervisor.job_control import JobControl
from pbo_runtime.ipc.task_statistics import TaskStatistics
from pbo_runtime.supervisor.run_report import RunResult

START_TIMEOUT = 60.0  # seconds for a child to import numpy, pinocchio and mujoco on a busy machine
SIGNAL_TIMEOUT = 10.0
STABLE_EPISODES_TOLD = 5  # holds for late inputs per critical task told as they happen; the summary counts them all
SIM_STALL_SECONDS = 2.0  # wall seconds one participant may take over one tick of the simulated clock before it is reported


class EventHandling:
    """The Supervisor's part that sends signals and absorbs events."""

    subsystem: Subsystem
    clock: RunClock
    signals: dict[str, messages.Queue]
    events: messages.Queue | None
    result: RunResult
    job_control: JobControl
    task_states: dict[str, str]
    task_errors: dict[str, str]
    say: Callable[[str], None]
    _stop_requested: str
    _stable: dict[str, tuple[float, str, str]]  # task -> (since, reason, cause) of its open stable episode
    started_at: float | None
    _stats: dict[str, TaskStatistics]
    _refused: dict[str, str]
    _check_children: Callable[[], None]
    child_watch: Any  # supervisor.child_watch.ChildWatch while the run is up, else None
    _count_errors: Callable[[], None]
    every_task: dict[str, Any]  # every task the run has had (live changes add some), by name
    staged: Callable[[str, int, str], None]
    _startup_mark: Callable[..., None]

    def _signal(self, signal: messages.TaskSignal) -> None:
        task = signal.task
        rtpu = self.every_task[task].rtpu
        self._refused.pop(task, None)
        self.signals[rtpu].signal(signal, timeout=SIGNAL_TIMEOUT)
        self.clock.serve(rtpu, self._while_stepping)

    def signal_and_wait(self, signal: messages.TaskSignal, states: set[str]) -> str:
        self._signal(signal)
        return self._await_state(signal.task, states)

    def _while_stepping(self) -> None:
        """Between ticks, and while a participant serves its signals: `_while_ticking`, and keep the
        event queue drained."""
        self._while_ticking()
        assert self.events is not None
        while (received := self.events.receive_event(0)) is not None:
            self._absorb(*received)

    def _while_ticking(self) -> None:
        """While the participants run ticks: fail if a child died, stop if asked, and say so once if
        a tick takes seconds (a cycle there has not returned). No event is taken: the participants
        hand the turn back after a tick that sent one, and it is taken then."""
        self._check_children()
        if self._stop_requested:
            raise StopRequested(self._stop_requested)  # a tick that never ends must not hold Ctrl-C
        slow = self.clock.slow_participant(SIM_STALL_SECONDS)
        if slow is not None:
            stepping, at, waited = slow
            self.say(f"{stepping} has not finished the tick at {at:.3f} s for {waited:.1f} s of wall "
                     "time: a cycle there has not returned (Ctrl-C stops the run)")

    def _await_ready(self, roles: set[str]) -> None:
        waiting = set(roles)
        deadline = time.monotonic() + START_TIMEOUT
        while waiting:
            source, event = self._next_event(deadline, f"waiting for {', '.join(sorted(waiting))} to start")
            if isinstance(event, messages.Ready):
                waiting.discard(source)
                self._startup_mark(source)  # the start-up's time line: when each child was ready
                if isinstance(event.realtime, dict):
                    self.result.realtime[source] = event.realtime

    def _served_state(self, task: str, states: set[str], failure: type[PboError]) -> str:
        """Sim clock: the signal was served in full when `_signal` returned; its events are all queued."""
        self._while_stepping()
        if task in self._refused:
            raise failure(f"task '{task}': {self._refused[task]}")
        state = self.task_states[task]
        if state not in states:
            raise failure(f"task '{task}' is {state} after the signal, not {' or '.join(sorted(states))}")
        return state

    def _await_state(self, task: str, states: set[str]) -> str:
        if self.clock.signals_served_when_sent:
            return self._served_state(task, states, RunFailure)
        deadline = time.monotonic() + SIGNAL_TIMEOUT
        while True:
            self._next_event(deadline, f"waiting for task '{task}' to reach {' or '.join(sorted(states))}")
            if self.task_states[task] in states:
                return self.task_states[task]

    def _await_change(self, task: str, before: str | None, states: set[str]) -> str:
        """The task's state after a signal: one of `states`; a clear that fails reports ERROR again."""
        if self.clock.signals_served_when_sent:
            return self._served_state(task, states, PboError)
        deadline = time.monotonic() + SIGNAL_TIMEOUT
        while True:
            _, event = self._next_event(deadline, f"waiting for task '{task}'")
            if isinstance(event, messages.Refused) and event.task == task:
                raise PboError(f"task '{task}': {event.reason}")
            if isinstance(event, messages.StateChanged) and event.task == task and self.task_states[task] in states:
                return self.task_states[task]

    def _next_event(self, deadline: float, doing: str) -> tuple[str, messages.Event]:
        assert self.events is not None
        while True:
            self._check_children()
            if self._stop_requested:
                raise RunFailure(f"stopped by {self._stop_requested} while {doing}")
            received = self.events.receive_event(0.05)
            if received is not None:
                self._absorb(*received)
                return received
            if time.monotonic() > deadline:
                raise RunFailure(f"timed out {doing}")

    def _absorb(self, source: str, event: messages.Event) -> None:
        if isinstance(event, messages.StateChanged):
            task, state, message = event.task, event.state, event.error
            previous = self.task_states.get(task)
            self.task_states[task] = state
            if message:
                self.task_errors[task] = message
            if event.output_failed and message:
                said = f"task '{task}' on {source} "
                if not any(fault.startswith(said) for fault in self.result.faults):  # its first failure says it
                    self.result.faults.append(f"{said}could not write its output: {message}")
            if state == "ERROR" and previous != "ERROR":
                self.say(f"task '{task}' on {source} is in ERROR: {message} (operator intervention required: pbo clear {task})")
            if (state == "ERROR") != (previous == "ERROR"):
                self._count_errors()
        elif isinstance(event, messages.Switched):
            self.job_control.switched(source, event.sequence, event.applied_at, event.done_at, event.off, event.on,
                                      event.read_at)
        elif isinstance(event, messages.Window):
            self.job_control.window(event.sequence, event.task, event.lost, event.stale)
        elif isinstance(event, messages.FirstCycle):
            self.job_control.first_cycle(event.sequence, event.task, event.at)
        elif isinstance(event, messages.Stable):
            task, at = event.task, event.at
            if event.entering:
                self._stable[task] = (at, event.reason, event.cause)
                if self._told(task, event.cause):
                    self.say(self._stable_news(task, event.reason))
            elif task in self._stable:
                cause = self._stable[task][2]
                told = self._told(task, cause)
                self._end_stable_episode(task, at)
                began = self.result.stable_episodes[-1]["from"]
                if told:
                    self.say(f"{self._kind_of(task)} '{task}' is back to its cycle after {(at - began) * 1e3:.1f} ms"
                             + ("" if self._told(task, cause) else "; its further holds for late inputs are counted in "
                                                                   "the summary, not told"))
            self._count_errors()
        elif isinstance(event, messages.Stats):
            self._stats[event.task] = event.statistics
        elif isinstance(event, messages.PlantStats):
            self.result.plant = event.figures
        elif isinstance(event, messages.PlantStalled):
            stall = (f"the plant did not run for {event.seconds:.3f} s (its process was stopped or starved) and resumed at "
                     f"simulated time {event.sim_time:.3f} s without integrating the backlog")
            if self.started_at is not None:  # (while the children start, they starve it of CPU, and no task drives it yet)
                self.result.faults.append(stall)
            self.say(stall)
        elif isinstance(event, messages.Refused):
            self._refused[event.task] = event.reason
            self.say(f"{source} refused a signal for '{event.task}': {event.reason}")
        elif isinstance(event, messages.Staged):
            self.staged(source, event.sequence, event.error)
        elif isinstance(event, messages.ChildExited):
            if self.child_watch is not None:  # (closed once the run stops: children then end as asked)
                self._check_children()  # a death handled now, not at the next look
        elif isinstance(event, messages.Crashed):
            raise RunFailure(f"{source} crashed: {event.error}" + (f"\n{event.trace}" if event.trace else ""))

    def _kind_of(self, task: str) -> str:
        subsystem = getattr(self, "subsystem", None)  # (a handler tested without one: every task is critical)
        spec = subsystem.tasks.get(task) if subsystem is not None else None
        return "task" if spec is not None and not spec.critical else "critical task"

    def _stable_news(self, task: str, reason: str) -> str:
        if self._kind_of(task) == "task":  # not critical: it says its inputs are stale, and the critical tasks hold
            return f"task '{task}' has no fresh input (its cycle returned STABLE): the critical tasks hold until it has"
        return f"critical task '{task}' runs its locally stable behaviour: {reason or 'the configuration is illegal'}"

    def _told(self, task: str, cause: str) -> bool:
        """Whether a stable episode of `task` for `cause` is told as it happens: always when the
        configuration is illegal (the operator acts on it), the first few holds for late inputs."""
        return cause == "illegal" or sum(1 for e in self.result.stable_episodes
                                         if e["task"] == task and e["cause"] != "illegal") < STABLE_EPISODES_TOLD

    def _end_stable_episode(self, task: str, at: float | None) -> None:
        """Into the report; `at` None: the task was still stable when the run stopped."""
        began, reason, cause = self._stable.pop(task)
        self.result.stable_episodes.append({"task": task, "from": began, "to": at,
                                            "seconds": None if at is None else at - began,
                                            "reason": reason, "cause": cause})

    def _take_one_event(self, timeout: float) -> None:
        assert self.events is not None
        received = self.events.receive_event(timeout)
        if received is not None:
            self._absorb(*received)

    def _drain_events(self, timeout: float) -> None:
        if self.events is None:
            return
        while True:
            try:
                received = self.events.receive_event(timeout)
            except posix_ipc.Error:
                return
            if received is None:
                return
            try:
                self._absorb(*received)
            except RunFailure as exc:
                if not self.result.failure:
                    self.result.failure = str(exc)
                    self.result.stopped_by = "failure"
            timeout = 0.0
