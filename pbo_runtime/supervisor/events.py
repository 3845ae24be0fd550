"""How the supervisor hears from its children: signals sent to a task's RTPU and the typed events
that come back (`ipc.messages`), waiting for a child to start or a task to change state, on the
real clock by waiting for events, on the simulated clock by stepping the RTPU that serves them."""

from __future__ import annotations

import time
from typing import Callable

import posix_ipc

from pbo_runtime.clock.run_clock import RunClock
from pbo_runtime.config.model import Subsystem, TaskSpec
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import messages
from pbo_runtime.supervisor.event_ledger import EventLedger
from pbo_runtime.supervisor.failures import RunFailure, StopRequested
from pbo_runtime.supervisor.job_control import JobControl
from pbo_runtime.supervisor.run_report import RunResult

START_TIMEOUT = 60.0  # seconds for a child to import numpy, pinocchio and mujoco on a busy machine
SIGNAL_TIMEOUT = 10.0
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
    ledger: EventLedger  # what the events change
    _refused: dict[str, str]
    _check_children: Callable[[], None]
    every_task: dict[str, TaskSpec]  # every task the run has had (live changes add some), by name
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
            self.ledger.absorb(*received)

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
                self.ledger.absorb(*received)
                return received
            if time.monotonic() > deadline:
                raise RunFailure(f"timed out {doing}")

    def _end_stable_episode(self, task: str, at: float | None) -> None:
        self.ledger.end_stable_episode(task, at)

    def _take_one_event(self, timeout: float) -> None:
        assert self.events is not None
        received = self.events.receive_event(timeout)
        if received is not None:
            self.ledger.absorb(*received)

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
                self.ledger.absorb(*received)
            except RunFailure as exc:
                if not self.result.failure:
                    self.result.failure = str(exc)
                    self.result.stopped_by = "failure"
            timeout = 0.0
