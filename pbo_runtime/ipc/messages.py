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

import contextlib
import dataclasses
import time
from collections.abc import Callable
from typing import Any, ClassVar

import msgpack
import posix_ipc

from pbo_runtime.errors import InternalError
from pbo_runtime.ipc import process, shm
from pbo_runtime.ipc.limits import QueueSize, queue_system_limit
from pbo_runtime.ipc.task_statistics import TaskStatistics

READER_CHECK = 0.1  # seconds between checks that a queue's reader is alive, while a send waits on it

# Linux refuses queues longer than fs.mqueue.msg_max (10 by default) or with longer messages than
# msgsize_max (8192) to a process without CAP_SYS_RESOURCE.
MAX_MESSAGES = min(64, queue_system_limit("msg_max", 10))
MESSAGE_BYTES = min(8192, queue_system_limit("msgsize_max", 8192))

# Each queue of a run is sized for what it carries: every byte of depth x message size counts
# against the per-user RLIMIT_MSGQUEUE (docs/architecture.md has the figures per run).
QUEUE_DEPTH = min(10, MAX_MESSAGES)  # signals come one at a time, events in bursts the supervisor drains
SIGNAL_BYTES = 128  # spawn, on, off, kill, clear, stop, stats, plan: a kind, a task's name, two numbers
EVENT_BYTES = 2048  # a task's statistics (about 600 B), a state change with its error (cut to fit)
CUT_STRINGS_TO = (1000, 300, 80)  # an event too long for its queue has its long strings cut, in these steps


def signal_queue_size(name: str, task_names: list[str], payload_bytes: int = 0) -> QueueSize:
    """An RTPU's signal queue: small signals, and room for a payload of `payload_bytes` where it hosts
    an aperiodic task (an operator's event, a link's message); at most MESSAGE_BYTES."""
    longest = max((len(task.encode()) for task in task_names), default=0)
    return QueueSize(name, QUEUE_DEPTH, min(SIGNAL_BYTES + longest + payload_bytes, MESSAGE_BYTES))


def event_queue_size(name: str, tasks_by_rtpu: list[list[str]]) -> QueueSize:
    """The run's event queue: EVENT_BYTES, or more where a switch's lists of an RTPU's task names
    (off and on) need it, up to MESSAGE_BYTES."""
    names = max((sum(len(task.encode()) + 2 for task in tasks) for tasks in tasks_by_rtpu), default=0)
    return QueueSize(name, QUEUE_DEPTH, max(EVENT_BYTES, min(256 + 2 * names, MESSAGE_BYTES)))


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


@dataclasses.dataclass(frozen=True, slots=True)
class LiveUpdate:
    """A live change (`pbo spawn/kill/replace/set`): read the run's live description number `sequence`
    from the run's file of it and keep it staged; the next plan applies it at its cycle boundary."""

    KIND: ClassVar[str] = "live"
    sequence: int


TaskSignal = Spawn | TurnOn | TurnOff | Kill | Clear | OperatorEvent | LinkMessage | Watch  # the signals for one task
Signal = TaskSignal | StopRtpu | SendStats | PlanPosted | LiveUpdate
SIGNAL_TYPES: dict[str, type[Signal]] = {cls.KIND: cls for cls in
                                         (Spawn, TurnOn, TurnOff, Kill, Clear, OperatorEvent, LinkMessage, Watch, StopRtpu,
                                          SendStats, PlanPosted, LiveUpdate)}


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
    """A task's lifecycle state after a signal, a cycle or a switch; `error` the last error's message.

    `output_failed`: the error is an output the run promised that could not be written (a data
    log: `errors.OutputError`); the run goes on, and its exit status says so.
    """

    KIND: ClassVar[str] = "state"
    task: str
    state: str
    error: str = ""
    output_failed: bool = False


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
    read_at: float = 0.0  # when this RTPU first read the plan in the table's header (0: not stamped)


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
    cause: str = ""  # "illegal" (configuration), "stale" (an in-var past its freshness bound), "module" (it said so),
    #                  "upstream" (a task before it said so), "lock" (the table lock held past its per-cycle wait)


@dataclasses.dataclass(frozen=True, slots=True)
class Stats:
    """A task's run figures (one task a message: an RTPU with dozens would overflow one).

    On the wire the figures are `TaskStatistics.to_json`'s mapping."""

    KIND: ClassVar[str] = "stats"
    task: str
    statistics: TaskStatistics


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
class Staged:
    """An RTPU read live description `sequence` (`LiveUpdate`); `error` if it could not."""

    KIND: ClassVar[str] = "staged"
    sequence: int
    error: str = ""


@dataclasses.dataclass(frozen=True, slots=True)
class Crashed:
    """A child failed outside any task: the exception, and its traceback."""

    KIND: ClassVar[str] = "crashed"
    error: str
    trace: str = ""


@dataclasses.dataclass(frozen=True, slots=True)
class ChildExited:
    """The supervisor's own child watch: a child process ended; wakes a supervisor waiting for events."""

    KIND: ClassVar[str] = "exited"
    role: str
    pid: int


Event = (Ready | StateChanged | Switched | Window | FirstCycle | Stable | Stats | PlantStats | PlantStalled | Refused | Staged
         | Crashed | ChildExited)
EVENT_TYPES: dict[str, type[Event]] = {cls.KIND: cls for cls in (
    Ready, StateChanged, Switched, Window, FirstCycle, Stable, Stats, PlantStats, PlantStalled, Refused, Staged, Crashed,
    ChildExited,
)}
_FIELDS: dict[type, tuple[str, ...]] = {cls: tuple(f.name for f in dataclasses.fields(cls))
                                        for cls in (*SIGNAL_TYPES.values(), *EVENT_TYPES.values())}


def event_to_wire(source: str, event: Event) -> list[Any]:
    """`[kind, source, *fields]`: what goes on the event queue."""
    if isinstance(event, Stats):
        return [event.KIND, source, event.task, event.statistics.to_json()]
    return [event.KIND, source, *(getattr(event, name) for name in _FIELDS[type(event)])]


def event_from_wire(message: list[Any]) -> tuple[str, Event]:
    """(source, event) from `[kind, source, *fields]`; anything else is our bug, named."""
    kind = message[0] if isinstance(message, list) and len(message) >= 2 else None
    cls = EVENT_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise InternalError(f"an event that is not one of {', '.join(EVENT_TYPES)} came on the event queue: "
                            f"{message!r:.200}; please report this")
    try:
        if cls is Stats:
            task, figures = message[2:]
            return str(message[1]), Stats(task, TaskStatistics.from_json(figures))
        return str(message[1]), cls(*message[2:])
    except (TypeError, ValueError, AttributeError) as exc:
        raise InternalError(f"a malformed '{kind}' event came on the event queue ({exc}): {message!r:.200}; "
                            "please report this") from None


class Queue:
    """One end of a message queue carrying msgpack-encoded lists (events: `report`, `receive_event`)."""

    def __init__(self, name: str, create: bool = False, size: QueueSize | None = None) -> None:
        """Open queue `name`, or with `create` make it new: `size` messages deep and long (default:
        the system's largest, MAX_MESSAGES of MESSAGE_BYTES)."""
        self.name = name
        if create:
            depth, length = (size.depth, size.message_bytes) if size is not None else (MAX_MESSAGES, MESSAGE_BYTES)
            self._mq = posix_ipc.MessageQueue(name, posix_ipc.O_CREX, mode=0o600, max_messages=depth,
                                              max_message_size=length)
        else:
            self._mq = posix_ipc.MessageQueue(name)
        self.owner = create

    @property
    def size(self) -> QueueSize:
        """The queue as the kernel made it: its depth and message size."""
        return QueueSize(self.name, self._mq.max_messages, self._mq.max_message_size)

    def pending(self) -> bool:
        """Whether a message waits in the queue (one system call, nothing received)."""
        waiting: int = self._mq.current_messages
        return waiting > 0

    def another_end(self) -> Queue:
        """Another end of this queue, opened in this process: closing one leaves the other open."""
        return Queue(self.name)

    def send(self, *message: Any, timeout: float | None = 1.0) -> None:
        raw = self._encode(message)
        while True:
            try:
                self._mq.send(raw, timeout=timeout)
                return
            except posix_ipc.SignalError:
                process.raise_if_stopping()
                continue  # interrupted by a signal whose handler only set a flag: send anyway

    def try_send(self, *message: Any, timeout: float = 0.5, reader_alive: Callable[[], bool] | None = None,
                 cut_to_fit: bool = False) -> bool:
        """Send, waiting at most `timeout`; False if the queue stayed full or is gone (a dead peer must not hang us).

        `reader_alive`, asked every READER_CHECK seconds of the wait, ends it as soon as the
        process that reads the queue is gone: a long wait is only worth it while someone drains.
        `cut_to_fit`: cut long strings (an event's error text) rather than refuse the message.
        """
        raw = self._encode(message, cut_to_fit)
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
        return self.try_send(*event_to_wire(source, event), timeout=timeout, reader_alive=reader_alive, cut_to_fit=True)

    def receive_event(self, timeout: float | None) -> tuple[str, Event] | None:
        """The next event as (source, event), or None if none came within `timeout` (see `receive`)."""
        message = self.receive(timeout)
        return None if message is None else event_from_wire(message)

    def _encode(self, message: tuple[Any, ...], cut_to_fit: bool = False) -> bytes:
        """The message as msgpack; with `cut_to_fit`, its long strings (an error's text, a traceback) cut
        until it fits the queue. One that does not fit even so is our bug, named, never a bare ValueError.
        """
        limit = self._mq.max_message_size
        raw: bytes = msgpack.packb(list(message))
        for longest in CUT_STRINGS_TO if cut_to_fit else ():
            if len(raw) <= limit:
                break
            raw = msgpack.packb(_cut_strings(list(message), longest))
        if len(raw) > limit:
            raise InternalError(f"a '{message[0]}' message of {len(raw)} B does not fit queue {self.name} "
                                f"(at most {limit} B); please report this")
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
        message: list[Any] = msgpack.unpackb(raw)
        return message

    def close(self) -> None:
        with contextlib.suppress(posix_ipc.ExistentialError):
            self._mq.close()
        if self.owner:
            shm.unlink_quietly("mq", self.name)


def _cut_strings(value: Any, longest: int) -> Any:
    """`value` with every string longer than `longest` cut in the middle: its start and its end say most."""
    if isinstance(value, str) and len(value) > longest:
        head = longest // 3
        return f"{value[:head]} [...{len(value) - longest} characters cut...] {value[len(value) - (longest - head):]}"
    if isinstance(value, list):
        return [_cut_strings(item, longest) for item in value]
    if isinstance(value, dict):
        return {key: _cut_strings(item, longest) for key, item in value.items()}
    return value
