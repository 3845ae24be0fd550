"""How the supervisor hears from its children: signals sent to a task's RTPU and the typed events
that come back (`ipc.messages`), waiting for a child to start or a task to change state, on the
real clock by waiting for events, on the simulated clock by stepping the RTPU that serves them.

When a wait ends is decided by the pure functions below (`state_served`, `change_seen`), from
the event and the ledger's state: tested without processes."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

import posix_ipc

from pbo_runtime.clock.run_clock import RunClock
from pbo_runtime.config.model import TaskSpec
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import messages
from pbo_runtime.supervisor.event_ledger import EventLedger
from pbo_runtime.supervisor.failures import RunFailure, StopRequested
from pbo_runtime.supervisor.run_report import RtpuSettings, RunResult

START_TIMEOUT = 60.0  # seconds for a child to import numpy, pinocchio and mujoco on a busy machine
SIGNAL_TIMEOUT = 10.0
SIM_STALL_SECONDS = 2.0  # wall seconds one participant may take over one tick of the simulated clock before it is reported


def state_served(task: str, states: set[str], refused: Mapping[str, str], task_states: Mapping[str, str],
                 failure: type[PboError]) -> str:
    """Sim clock: the task's state once its signal was served in full; `failure` if refused or not in `states`."""
    if task in refused:
        raise failure(f"task '{task}': {refused[task]}")
    state = task_states[task]
    if state not in states:
        raise failure(f"task '{task}' is {state} after the signal, not {' or '.join(sorted(states))}")
    return state


def change_seen(task: str, states: set[str], event: messages.Event, state: str) -> bool:
    """Real clock: whether `event` ends the wait for `task` to change into one of `states` (`state`:
    the task's state once the event was absorbed); PboError if it refused the signal."""
    if isinstance(event, messages.Refused) and event.task == task:
        raise PboError(f"task '{task}': {event.reason}")
    return isinstance(event, messages.StateChanged) and event.task == task and state in states


class EventHandling:
    """The supervisor's part that sends signals to the tasks and takes its children's events.

    `queue` gives the event queue once the run made it; `check_children` raises if a child died;
    `stop_requested` says why the run is asked to stop ("" while it is not); `mark` notes when a
    child was ready (the start-up's time line).
    """

    def __init__(self, clock: RunClock, ledger: EventLedger, result: RunResult, signals: dict[str, messages.Queue],
                 every_task: dict[str, TaskSpec], queue: Callable[[], messages.Queue | None],
                 check_children: Callable[[], None], stop_requested: Callable[[], str],
                 mark: Callable[[str], None], say: Callable[[str], None]) -> None:
        self.clock = clock
        self.ledger = ledger
        self.result = result
        self.signals = signals
        self.every_task = every_task  # every task the run has had (live changes add some), by name
        self.queue = queue
        self.check_children = check_children
        self.stop_requested = stop_requested
        self.mark = mark
        self.say = say

    def _events(self) -> messages.Queue:
        events = self.queue()
        assert events is not None
        return events

    def signal(self, signal: messages.TaskSignal) -> None:
        task = signal.task
        rtpu = self.every_task[task].rtpu
        self.ledger.refused.pop(task, None)
        self.signals[rtpu].signal(signal, timeout=SIGNAL_TIMEOUT)
        self.clock.serve(rtpu, self.while_stepping)

    def signal_and_wait(self, signal: messages.TaskSignal, states: set[str]) -> str:
        self.signal(signal)
        return self.await_state(signal.task, states)

    def spawn_and_wait(self, task: str) -> str:
        """Spawn `task`; OFF once its init ran, KILLED if it failed. A state kept from a task of the
        same name killed before is forgotten first: it must not answer for the new one."""
        self.ledger.task_states[task] = "NOT_CREATED"
        return self.signal_and_wait(messages.Spawn(task), {"OFF", "KILLED"})

    def while_stepping(self) -> None:
        """Between ticks, and while a participant serves its signals: `while_ticking`, and keep the
        event queue drained."""
        self.while_ticking()
        events = self._events()
        while (received := events.receive_event(0)) is not None:
            self.ledger.absorb(*received)

    def while_ticking(self) -> None:
        """While the participants run ticks: fail if a child died, stop if asked, and say so once if
        a tick takes seconds (a cycle there has not returned). No event is taken: the participants
        hand the turn back after a tick that sent one, and it is taken then."""
        self.check_children()
        stopping = self.stop_requested()
        if stopping:
            raise StopRequested(stopping)  # a tick that never ends must not hold Ctrl-C
        slow = self.clock.slow_participant(SIM_STALL_SECONDS)
        if slow is not None:
            stepping, at, waited = slow
            self.say(f"{stepping} has not finished the tick at {at:.3f} s for {waited:.1f} s of wall "
                     "time: a cycle there has not returned (Ctrl-C stops the run)")

    def await_ready(self, roles: set[str]) -> None:
        waiting = set(roles)
        deadline = time.monotonic() + START_TIMEOUT
        while waiting:
            source, event = self.next_event(deadline, f"waiting for {', '.join(sorted(waiting))} to start")
            if isinstance(event, messages.Ready):
                waiting.discard(source)
                self.mark(source)  # the start-up's time line: when each child was ready
                if isinstance(event.realtime, dict):
                    self.result.realtime[source] = RtpuSettings.from_json(event.realtime)

    def _served_state(self, task: str, states: set[str], failure: type[PboError]) -> str:
        """Sim clock: the signal was served in full when `signal` returned; its events are all queued."""
        self.while_stepping()
        return state_served(task, states, self.ledger.refused, self.ledger.task_states, failure)

    def await_state(self, task: str, states: set[str]) -> str:
        if self.clock.signals_served_when_sent:
            return self._served_state(task, states, RunFailure)
        task_states = self.ledger.task_states
        deadline = time.monotonic() + SIGNAL_TIMEOUT
        while True:
            self.next_event(deadline, f"waiting for task '{task}' to reach {' or '.join(sorted(states))}")
            if task_states[task] in states:
                return task_states[task]

    def await_change(self, task: str, states: set[str]) -> str:
        """The task's state after a signal: one of `states`; a clear that fails reports ERROR again."""
        if self.clock.signals_served_when_sent:
            return self._served_state(task, states, PboError)
        task_states = self.ledger.task_states
        deadline = time.monotonic() + SIGNAL_TIMEOUT
        while True:
            _, event = self.next_event(deadline, f"waiting for task '{task}'")
            if change_seen(task, states, event, task_states[task]):
                return task_states[task]

    def next_event(self, deadline: float, doing: str) -> tuple[str, messages.Event]:
        events = self._events()
        while True:
            self.check_children()
            stopping = self.stop_requested()
            if stopping:
                raise RunFailure(f"stopped by {stopping} while {doing}")
            received = events.receive_event(0.05)
            if received is not None:
                self.ledger.absorb(*received)
                return received
            if time.monotonic() > deadline:
                raise RunFailure(f"timed out {doing}")

    def take_one_event(self, timeout: float) -> None:
        received = self._events().receive_event(timeout)
        if received is not None:
            self.ledger.absorb(*received)

    def drain(self, timeout: float) -> None:
        """Absorb what the children sent, waiting up to `timeout` for the first; a failure an event tells is the run's."""
        events = self.queue()
        if events is None:
            return
        while True:
            try:
                received = events.receive_event(timeout)
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
