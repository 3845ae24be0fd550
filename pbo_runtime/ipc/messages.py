"""Signals to RTPUs and events back to job control: msgpack over POSIX message queues.

Queues carry signals and events only, never per-cycle data (docs/architecture.md). All are 0600.

Signals and events are typed: one frozen dataclass per kind, below, encoded and decoded here
only (`Queue.signal`/`try_signal` and `signal_from_wire` for signals; `Queue.report` and
`Queue.receive_event` for events). On the wire a signal is the msgpack list `[kind, *fields]`
and an event `[kind, source, *fields]` (source: the RTPU's name or "plant"), fields in
declaration order; trailing fields with a default may be left out. Events are sent on state
changes (a task's state, a switch, a stable episode's start and end), never per cycle.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, ClassVar, Union

import msgpack
import posix_ipc

from pbo_runtime.ipc import process
from pbo_runtime.ipc import shm
from pbo_runtime.errors import InternalError

MESSAGE_BYTES = 8192
READER_CHECK = 0.1  # seconds between checks that a queue's reader is alive, while a send waits on it


def _system_limit(name: str, default: int) -> int:
    try:
        with open(f"/proc/sys/fs/mqueue/{name}") as limit:
            return int(limit.read())
    except (OSError, ValueError):
        return default


# Linux refuses queues longer than fs.mqueue.msg_max (10 by default) even to root.
MAX_MESSAGES = min(64, _system_limit("msg_max", 10))
MESSAGE_BYTES = min(MESSAGE_BYTES, _system_limit("msgsize_max", MESSAGE_BYTES))


def signal_queue_name(subsystem: str, run_id: str, rtpu: str) -> str:
    return shm.object_name(subsystem, run_id, f"rtpu-{rtpu}")


def event_queue_name(subsystem: str, run_id: str) -> str:
    return shm.object_name(subsystem, run_id, "events")


def plant_registers_name(subsystem: str, run_id: str) -> str:
    return shm.object_name(subsystem, run_id, "plant")


def table_name(subsystem: str, run_id: str) -> str:
    return shm.object_name(subsystem, run_id, "table")


# --- signals: job control (and a link's relay) to an RTPU ------------------------------------


@dataclasses.dataclass(frozen=True, slots=True)
class Spawn:
    """Create the task and run its init (again, with a fresh instance, after a kill: a static switch)."""

    KIND: ClassVar[str] = "spawn"
    task: str


@dataclasses.dataclass(frozen=True, slots=True)
class TurnOn:
    """Turn the task on, its releases aligned from `at` (None: now); a critical task watches the
    writers of its inputs in configuration number `configuration` (None: it does not)."""

    KIND: ClassVar[str] = "on"
    task: str
    at: float | None = None
    configuration: int | None = None


@dataclasses.dataclass(frozen=True, slots=True)
class TurnOff:
    KIND: ClassVar[str] = "off"
    task: str


@dataclasses.dataclass(frozen=True, slots=True)
class Kill:
    KIND: ClassVar[str] = "kill"
    task: str


@dataclasses.dataclass(frozen=True, slots=True)
class Clear:
    """The operator's clear: the task's clear component decides whether it goes back to OFF."""

    KIND: ClassVar[str] = "clear"
    task: str


@dataclasses.dataclass(frozen=True, slots=True)
class OperatorEvent:
    """An event for an aperiodic task from the operator (`pbo event`): refused unless the task is ON."""

    KIND: ClassVar[str] = "event"
    task: str
    values: Any = None


@dataclasses.dataclass(frozen=True, slots=True)
class LinkMessage:
    """A message of another subsystem for the task serving its link (TR §5.1): kept until it is ON."""

    KIND: ClassVar[str] = "message"
    task: str
    payload: Any = None


@dataclasses.dataclass(frozen=True, slots=True)
class StopRtpu:
    """The run is over: every task off and killed, statistics reported, the executive ends."""

    KIND: ClassVar[str] = "stop"


@dataclasses.dataclass(frozen=True, slots=True)
class SendStats:
    KIND: ClassVar[str] = "stats"


@dataclasses.dataclass(frozen=True, slots=True)
class PlanPosted:
    """A wake-up: a plan is in the table's header (the plan itself never travels on a queue)."""

    KIND: ClassVar[str] = "plan"


@dataclasses.dataclass(frozen=True, slots=True)
class Watch:
    """A critical task that stays ON across a static switch watches the writers of its inputs in
    configuration number `configuration` from now (the executive answers with its state)."""

    KIND: ClassVar[str] = "watch"
    task: str
    configuration: int


TaskSignal = Union[Spawn, TurnOn, TurnOff, Kill, Clear, OperatorEvent, LinkMessage, Watch]  # the signals for one task
Signal = Union[Spawn, TurnOn, TurnOff, Kill, Clear, OperatorEvent, LinkMessage, Watch, StopRtpu, SendStats, PlanPosted]
SIGNAL_TYPES: dict[str, type[Signal]] = {cls.KIND: cls for cls in
                                         (Spawn, TurnOn, TurnOff, Kill, Clear, OperatorEvent, LinkMessage, Watch, StopRtpu,
                                          SendStats, PlanPosted)}


def signal_to_wire(signal: Signal) -> list[Any]:
    """`[kind, *fields]`: what goes on an RTPU's signal queue."""
    return [signal.KIND, *(getattr(signal, name) for name in _FIELDS[type(signal)])]


def signal_from_wire(message: list[Any]) -> Signal | None:
    """The signal `[kind, *fields]` stands for; None for a kind no RTPU knows (the RTPU refuses it)."""
    cls = SIGNAL_TYPES.get(message[0]) if message and isinstance(message[0], str) else None
    if cls is None:
        return None
    try:
        return cls(*message[1:])
    except TypeError as exc:
        raise InternalError(f"a malformed '{message[0]}' signal came on a signal queue ({exc}): {message!r:.200}; "
                            "please report this") from None


# --- events: RTPUs and the plant to job control ----------------------------------------------


@dataclasses.dataclass(frozen=True, slots=True)
class Ready:
    """A child is up: an RTPU says what it runs under (cpu, scheduler, timer slack...), the plant nothing."""

    KIND: ClassVar[str] = "ready"
    realtime: dict[str, str] | None = None


@dataclasses.dataclass(frozen=True, slots=True)
class StateChanged:
    """A task's lifecycle state after a signal, a cycle or a switch; `error` the last error's message."""

    KIND: ClassVar[str] = "state"
    task: str
    state: str
    error: str = ""


@dataclasses.dataclass(frozen=True, slots=True)
class Switched:
    """An RTPU applied plan `sequence`: when, and which of its tasks went off and on."""

    KIND: ClassVar[str] = "switched"
    sequence: int
    configuration: str
    activation: float
    applied_at: float
    done_at: float
    off: list[str]
    on: list[str]


@dataclasses.dataclass(frozen=True, slots=True)
class Window:
    """A critical task's cycles lost and stale reads from switch `sequence` to the next one (or the stop)."""

    KIND: ClassVar[str] = "window"
    sequence: int
    task: str
    lost: int
    stale: int


@dataclasses.dataclass(frozen=True, slots=True)
class FirstCycle:
    """An entering task of plan `sequence` ran its first cycle, starting at `at`."""

    KIND: ClassVar[str] = "first_cycle"
    sequence: int
    task: str
    at: float


@dataclasses.dataclass(frozen=True, slots=True)
class Stable:
    """A critical task entered (`entering`) or left its locally stable behaviour at `at`; entering, why."""

    KIND: ClassVar[str] = "stable"
    task: str
    entering: bool
    at: float
    reason: str = ""  # what the operator reads
    cause: str = ""  # "illegal" (configuration), "stale" (an in-var past its freshness bound), "module" (it said so)


@dataclasses.dataclass(frozen=True, slots=True)
class Stats:
    """Per task (one task a message: an RTPU with dozens would overflow one), its run figures."""

    KIND: ClassVar[str] = "stats"
    tasks: dict[str, dict[str, Any]]


@dataclasses.dataclass(frozen=True, slots=True)
class PlantStats:
    """The plant's figures at its end: steps, late steps, how far behind it left SCHED_FIFO."""

    KIND: ClassVar[str] = "plant_stats"
    figures: dict[str, Any]


@dataclasses.dataclass(frozen=True, slots=True)
class PlantStalled:
    """The plant process did not run for `seconds` (stopped, or starved of CPU) and resumed at
    simulated time `sim_time` without integrating the backlog: the world stood still meanwhile."""

    KIND: ClassVar[str] = "plant_stalled"
    seconds: float
    sim_time: float


@dataclasses.dataclass(frozen=True, slots=True)
class Refused:
    """An RTPU refused a signal for `task` (job control's mistake, not a crash): why."""

    KIND: ClassVar[str] = "refused"
    task: str
    reason: str


@dataclasses.dataclass(frozen=True, slots=True)
class Crashed:
    """A child failed outside any task: the exception, and its traceback."""

    KIND: ClassVar[str] = "crashed"
    error: str
    trace: str = ""


Event = Union[Ready, StateChanged, Switched, Window, FirstCycle, Stable, Stats, PlantStats, PlantStalled, Refused, Crashed]
EVENT_TYPES: dict[str, type[Event]] = {cls.KIND: cls for cls in
                                       (Ready, StateChanged, Switched, Window, FirstCycle, Stable, Stats, PlantStats, PlantStalled,
                                        Refused, Crashed)}
_FIELDS: dict[type, tuple[str, ...]] = {cls: tuple(f.name for f in dataclasses.fields(cls))
                                        for cls in (*SIGNAL_TYPES.values(), *EVENT_TYPES.values())}


def event_to_wire(source: str, event: Event) -> list[Any]:
    """`[kind, source, *fields]`: what goes on the event queue."""
    return [event.KIND, source, *(getattr(event, name) for name in _FIELDS[type(event)])]


def event_from_wire(message: list[Any]) -> tuple[str, Event]:
    """(source, event) from `[kind, source, *fields]`; anything else is our bug, named."""
    kind = message[0] if isinstance(message, list) and len(message) >= 2 else None
    cls = EVENT_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise InternalError(f"an event that is not one of {', '.join(EVENT_TYPES)} came on the event queue: "
                            f"{message!r:.200}; please report this")
    try:
        return str(message[1]), cls(*message[2:])
    except TypeError as exc:
        raise InternalError(f"a malformed '{kind}' event came on the event queue ({exc}): {message!r:.200}; "
                            "please report this") from None


class Queue:
    """One end of a message queue carrying msgpack-encoded lists (events: `report`, `receive_event`)."""

    def __init__(self, name: str, create: bool = False) -> None:
        self.name = name
        flags = posix_ipc.O_CREX if create else 0
        self._mq = posix_ipc.MessageQueue(name, flags, mode=0o600, max_messages=MAX_MESSAGES, max_message_size=MESSAGE_BYTES)
        self.owner = create

    def send(self, *message: Any, timeout: float | None = 1.0) -> None:
        raw = self._encode(message)
        while True:
            try:
                self._mq.send(raw, timeout=timeout)
                return
            except posix_ipc.SignalError:
                process.raise_if_stopping()
                continue  # interrupted by a signal whose handler only set a flag: send anyway

    def try_send(self, *message: Any, timeout: float = 0.5, reader_alive: Callable[[], bool] | None = None) -> bool:
        """Send, waiting at most `timeout`; False if the queue stayed full or is gone (a dead peer must not hang us).

        `reader_alive`, asked every READER_CHECK seconds of the wait, ends it as soon as the
        process that reads the queue is gone: a long wait is only worth it while someone drains.
        """
        raw = self._encode(message)
        deadline = time.monotonic() + timeout
        while True:
            left = max(deadline - time.monotonic(), 0.0)
            if reader_alive is not None and not reader_alive():
                left = 0.0  # nobody drains it: one try, no wait
            wait = left if reader_alive is None else min(left, READER_CHECK)
            try:
                self._mq.send(raw, timeout=wait)
                return True
            except posix_ipc.BusyError:
                if wait >= left:  # waited all that was left: the queue stayed full
                    return False
            except (posix_ipc.ExistentialError, posix_ipc.SignalError, OSError):
                return False

    def signal(self, signal: Signal, timeout: float | None = 1.0) -> None:
        """Send a signal to an RTPU (`send`: waits for room, at most `timeout`)."""
        self.send(*signal_to_wire(signal), timeout=timeout)

    def try_signal(self, signal: Signal, timeout: float = 0.5) -> bool:
        """Send a signal if there is room within `timeout` (`try_send`)."""
        return self.try_send(*signal_to_wire(signal), timeout=timeout)

    def report(self, source: str, event: Event, timeout: float = 0.5,
               reader_alive: Callable[[], bool] | None = None) -> bool:
        """Send one event from `source` (`try_send`: a dead or stuck job control never hangs the sender)."""
        return self.try_send(*event_to_wire(source, event), timeout=timeout, reader_alive=reader_alive)

    def receive_event(self, timeout: float | None) -> tuple[str, Event] | None:
        """The next event as (source, event), or None if none came within `timeout` (see `receive`)."""
        message = self.receive(timeout)
        return None if message is None else event_from_wire(message)

    def _encode(self, message: tuple[Any, ...]) -> bytes:
        """The message as msgpack; one too long for the queue is our bug, named, never a bare ValueError."""
        raw = msgpack.packb(list(message))
        if len(raw) > self._mq.max_message_size:
            raise InternalError(f"a '{message[0]}' message of {len(raw)} B does not fit queue {self.name} "
                                f"(at most {self._mq.max_message_size} B); please report this")
        return raw

    def receive(self, timeout: float | None) -> list[Any] | None:
        """The next message, or None if none came within `timeout` seconds (0: do not wait).

        A stop requested while the process was not waiting is raised here (`process.stop_only_at_waits`).
        """
        process.raise_if_stopping()
        try:
            raw, _priority = self._mq.receive(timeout=max(timeout, 0.0) if timeout is not None else None)
        except posix_ipc.BusyError:
            return None
        except posix_ipc.SignalError:
            # The signal's handler has run. In the supervisor it set a flag and we return; in
            # a child it raised Stop, which posix_ipc replaced by SignalError: raise it again.
            process.raise_if_stopping()
            return None
        return msgpack.unpackb(raw)

    def close(self) -> None:
        try:
            self._mq.close()
        except posix_ipc.ExistentialError:
            pass
        if self.owner:
            shm.unlink_quietly("mq", self.name)
