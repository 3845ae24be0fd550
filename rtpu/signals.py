"""Signals: what an executive does with each message job control (or a link's relay) sends it.

Signals and timers share one wait: the executive waits for the earliest release with a timed
receive on its signal queue. A signal changes a task's state (spawn, on, off, kill, clear), stages
a live change, asks for statistics or stops the RTPU; an event releases an aperiodic task. A
refused signal is job control's mistake, reported, never a crash. A spawn's slow steps (an import,
an init, the timing rings written) let the cycles due meanwhile run between them on the real clock.
"""

from __future__ import annotations

import contextlib
import gc
import math
from typing import TYPE_CHECKING, Any, Protocol

from pbo_runtime.ipc import messages
from pbo_runtime.ipc.messages import Refused
from pbo_runtime.objects import waits
from pbo_runtime.table.table import TaskState

if TYPE_CHECKING:
    from rtpu._executive import Executive, Scheduled

EVENTS_QUEUED = 16  # events an aperiodic task holds while it waits out its min inter-arrival time


class SignalSource(Protocol):
    def receive(self, timeout: float | None) -> list[Any] | None: ...


def handle_signal(executive: Executive, message: list[Any]) -> None:
    """One signal as it came off the queue (`[kind, *fields]`, decoded by `messages.signal_from_wire`)."""
    executive.report_background_failures()
    signal = messages.signal_from_wire(message)
    if isinstance(signal, messages.StopRtpu):
        executive.stop()
        return
    if isinstance(signal, messages.SendStats):
        executive.report_statistics()
        return
    if isinstance(signal, messages.PlanPosted):  # a wake-up: the plan itself is in the table's header
        return
    if isinstance(signal, messages.LiveUpdate):
        executive.plans.stage(signal.sequence, executive.tasks, executive.factories,
                              hand_off=executive.off_the_cycle if executive.cycles_between_steps else None)
        return
    name = signal.task if signal is not None else message[1]
    if not isinstance(signal, (messages.OperatorEvent, messages.LinkMessage)):
        executive.changes += 1  # a task spawned, turned on or off, killed or cleared: a plan read before is read again
    s = executive.tasks.get(name)
    if s is None and isinstance(signal, messages.Spawn) and name in executive.factories:  # spawned live
        with cycling_meanwhile(executive):
            s = executive.tasks[name] = make(executive, name)
    if s is None:
        executive.report(Refused(name, f"no task '{name}' on this RTPU"))
        return
    try:
        if not _change_state(executive, s, signal):
            executive.report(Refused(name, f"unknown signal '{message[0]}'"))
            return
    except Exception as exc:  # a refused signal is job control's mistake, not a crash
        executive.report(Refused(name, f"{message[0]}: {exc}"))
        return
    if not isinstance(signal, (messages.OperatorEvent, messages.LinkMessage)):
        executive.report_state(executive.tasks[name].task)


def _change_state(executive: Executive, s: Scheduled, signal: Any) -> bool:
    """Carry out a signal to task `s`; False for a signal no task takes."""
    clock = executive.clock
    task = s.task
    if isinstance(signal, messages.Spawn):
        spawn(executive, s)
    elif isinstance(signal, messages.TurnOn):
        if executive.before_first_on is not None:
            first, executive.before_first_on = executive.before_first_on, None
            first()
        at = signal.at if signal.at is not None else clock.now()
        executive.turn_on(s, at)
        if signal.configuration is not None:
            executive.watch(s, int(signal.configuration), at)
    elif isinstance(signal, messages.Watch):
        executive.watch(s, int(signal.configuration), clock.now())
    elif isinstance(signal, messages.TurnOff):
        executive.leave_on(s)
        task.turn_off(clock.now())
    elif isinstance(signal, messages.Kill):
        executive.leave_on(s)
        task.kill(clock.now())
    elif isinstance(signal, messages.Clear):
        task.clear()
    elif isinstance(signal, messages.OperatorEvent):
        event(executive, s, signal.values)
    elif isinstance(signal, messages.LinkMessage):  # from a link's relay (TaskContext.serve_link): no reply to anyone
        event(executive, s, signal.payload, quiet=True)
    else:
        return False
    return True


def spawn(executive: Executive, s: Scheduled) -> None:
    """Spawn task `s` (a new instance if it was killed: TR 4.4, static), running the cycles due meanwhile."""
    name = s.task.name
    with cycling_meanwhile(executive):  # an init's waits (a device starting) run the due cycles
        if s.task.state == TaskState.KILLED and name in executive.factories:
            s = executive.tasks[name] = make(executive, name)
        s.task.spawn(executive.clock.now())
    cycles_due(executive)
    # What the process built up to here (imports, the task and its module) lives as long as the
    # task: freezing it keeps it out of every later collection, which then walks only what the run
    # allocates, so a collection mid-run stays short.
    gc.freeze()


def make(executive: Executive, name: str) -> Scheduled:
    """A new instance of task `name` (its module imported if it was not yet), and its place here.

    Each step may take a millisecond or more (an import, an init, the timing rings written):
    the cycles that came due meanwhile run between the steps (`cycles_due`), not after them all."""
    from rtpu._executive import Scheduled

    task = executive.factories[name]()
    cycles_due(executive)
    made = Scheduled(task, between=lambda: cycles_due(executive))
    cycles_due(executive)
    return made


def cycles_due(executive: Executive) -> None:
    """On the real clock, between two steps of a signal's slow work (a spawn): run the cycles
    released meanwhile, after a plan whose boundary came meanwhile, as the loop would. (The
    simulated clock runs cycles on its ticks only.)"""
    if not executive.cycles_between_steps:
        return
    applied = executive.plan_if_due()
    executive.run_ready()
    if applied:
        executive.plans.send_held_reports()


def cycling_meanwhile(executive: Executive) -> contextlib.AbstractContextManager[None]:
    """On the real clock, a spawn's waits (`waits.sleep_while_cycling`) run the cycles due
    meanwhile; on the simulated clock they are plain waits (time stands still)."""
    if not executive.cycles_between_steps:
        return contextlib.nullcontext()

    def sleep_cycling(seconds: float) -> None:
        """Wait `seconds` and run each cycle that comes due meanwhile, at its release."""
        clock = executive.clock
        end = clock.now() + seconds
        while True:
            cycles_due(executive)
            if clock.now() >= end:
                return
            following = min((s.release for s in executive.on), default=math.inf)
            clock.sleep_until(min(end, following))

    return waits.cycles_meanwhile(sleep_cycling)


def event(executive: Executive, s: Scheduled, payload: Any, quiet: bool = False) -> None:
    """An event for an aperiodic task: released now, or after its minimum inter-arrival time.

    `quiet`: a message from another subsystem (TR §5.1). While its server is not ON yet it
    waits in the server's queue (released when it turns on), since the other subsystem may
    start first; an operator's event is refused instead, for the operator to read.
    """
    if not s.aperiodic:
        executive.report(Refused(s.task.name, "event: the task is periodic"))
        return
    on = s.task.state == TaskState.ON
    if not on and not quiet:
        executive.report(Refused(s.task.name, f"event: the task is {s.task.state.name}, not ON"))
        return
    if len(s.events) == s.events.maxlen:
        s.dropped_events += 1
    s.events.append(payload)
    if on and s.release == math.inf:
        s.release = max(executive.clock.now(), s.last_release + s.period)
