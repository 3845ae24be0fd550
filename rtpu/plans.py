"""Plans: dynamic reconfiguration at a cycle boundary (TR §4.4), and live changes staged for the next plan.

Job control posts a plan in the table's header (a configuration and an activation time); at its
first cycle boundary at or after that time each executive turns its leaving tasks off and its
entering tasks on, so every RTPU switches at the same instant without a message on the per-cycle
path. A live change (`pbo spawn/kill/replace/set`) comes as a `LiveUpdate`: the RTPU reads the
run's new description and stages it; the next plan swaps it in at its boundary, tunes included.
A switch's reports wait until the boundary's cycles ran: the entering tasks' first cycle comes first.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from pbo_runtime.config.model import TaskSpec
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.messages import Event, Refused, StateChanged, Switched, Window
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.table.table import Header, TaskState
from pbo_runtime.task.lifecycle import Task
from rtpu.holds import WatchedWriters, watch_writers, writers_to_watch

if TYPE_CHECKING:
    from rtpu._executive import Executive, Scheduled

# Header words read before every release, as plain ints (through a memoryview: no numpy scalar each time)
PLAN_SEQUENCE, PLAN_TIME_NS = int(Header.PLAN_SEQUENCE), int(Header.PLAN_TIME_NS)
PLAN_CONFIGURATION = int(Header.PLAN_CONFIGURATION)


class Boundary:
    """A plan read for one RTPU's tasks ahead of its boundary, and what the boundary did.

    Read when the RTPU first sees the plan (it then waits for the activation): who leaves, who
    enters (critical first), whose freshness watch follows which writers. The boundary only turns
    tasks off and on; it keeps what its reports need, which are built after its cycles ran. The
    reading holds while the RTPU's tasks did not change (`Executive.changes`) and no other live
    description was staged.
    """

    __slots__ = (
        "activation",
        "applied_at",
        "changes",
        "closed",
        "configuration",
        "critical",
        "done_at",
        "entering",
        "leaving",
        "read_at",
        "reconfiguration",
        "sequence",
        "staged",
        "states",
        "turning_on",
        "view_name",
        "watches",
        "windows",
    )

    def __init__(self, sequence: int, configuration: int, activation: float, changes: int, staged: LiveStage | None,
                 reconfiguration: Reconfiguration, view_name: str, leaving: list[Scheduled], entering: list[Scheduled],
                 watches: list[tuple[Scheduled, WatchedWriters]], critical: list[Scheduled]) -> None:
        self.sequence, self.configuration, self.activation = sequence, configuration, activation
        # what the reading holds for: the RTPU's changes count, the live change staged and its description then
        self.changes, self.staged, self.reconfiguration = changes, staged, reconfiguration
        self.view_name = view_name
        self.leaving, self.entering = leaving, entering
        self.turning_on = sorted(entering, key=lambda s: not s.critical)  # the order they turn on in
        self.watches = watches  # each critical task ON after the switch, with its writers there
        self.critical = critical  # every critical task hosted: their windows close at the switch
        # set by the boundary
        self.applied_at = self.done_at = self.read_at = 0.0
        self.closed = 0  # the plan whose window the switch closed (0: none before the first)
        self.windows: list[tuple[str, int, int]] = []  # (task, lost, stale) of that window
        self.states: list[tuple[TaskState, str, bool]] = []  # each leaving, then entering task's state after it

    def reports(self) -> list[Event]:
        """The switch's reports, in order: the windows it closed, the tasks' new states, `Switched`."""
        events: list[Event] = [Window(self.closed, name, lost, stale) for name, lost, stale in self.windows]
        tasks = (*self.leaving, *self.entering)
        events += [StateChanged(s.task.name, state.name, error, failed)
                   for s, (state, error, failed) in zip(tasks, self.states, strict=True)]
        events.append(Switched(self.sequence, self.view_name, self.activation, self.applied_at, self.done_at,
                               [s.task.name for s in self.leaving], [s.task.name for s in self.entering], self.read_at))
        return events


@dataclasses.dataclass(frozen=True)
class LiveStage:
    """A live description an RTPU read (`LiveUpdate`), staged until the next plan applies it."""

    reconfiguration: Reconfiguration
    tasks: dict[str, tuple[int, Any]]  # every task of the live description: (status block, params)
    spec: Callable[[str], TaskSpec]  # a task's full spec (its module looked up: only for a task hosted here)
    factories: dict[str, Callable[[], Task]]  # this RTPU's tasks, each made afresh from its live spec


class Plans:
    """One RTPU's view of the run's plans: the one it applied, the one pending, the live change staged."""

    def __init__(self, header: np.ndarray | None, reconfiguration: Reconfiguration | None, rtpu_index: int, n_rtpus: int,
                 live_loader: Callable[[int], LiveStage] | None, report: Callable[[Event], None]) -> None:
        self.header = header  # the table's int64 header: plans, switching words
        self.words = header.data if header is not None else None  # the same words, read as ints (a memoryview)
        self.reconfiguration = reconfiguration
        self.rtpu_index = rtpu_index
        self.switching_words = range(int(Header.SWITCHING_SINCE_NS), int(Header.SWITCHING_SINCE_NS) + n_rtpus)
        self.switching_word = self.switching_words[rtpu_index]  # set while this RTPU switches
        self.report = report
        self.seen = int(header[Header.PLAN_SEQUENCE]) if header is not None else 0  # the last plan applied here
        # When this RTPU first read the pending plan (off the per-cycle path: only while one is
        # pending): job control sizes the plan's lead from how long RTPUs take to read a plan.
        self.read = self.seen
        self.read_at = 0.0
        self.prepared: Boundary | None = None  # the pending plan, read for this RTPU's tasks when first seen
        # A switch's reports (its windows, the tasks' new states, Switched), sent after the boundary's cycles
        self.held_reports: list[Event | Boundary] = []
        self.configuration = -1  # index of the configuration last applied here
        self.live_loader = live_loader
        self.staged: LiveStage | None = None
        self.staged_tunes: dict[str, Any] = {}  # hosted task -> (its new spec, its Params), when its parameters changed

    def notice(self, now: float, executive: Executive | None = None) -> float:
        """The pending plan's activation time; the first time this RTPU saw it is stamped (reported with
        its `Switched`). Given `executive` (the RTPU is about to wait), the plan is read for its tasks
        if it was not yet (`prepare`)."""
        words = self.words
        assert words is not None
        sequence = words[PLAN_SEQUENCE]
        if sequence != self.read:
            self.read = sequence
            self.read_at = now
        if executive is not None and (self.prepared is None or self.prepared.sequence != sequence):
            self.prepared = self.prepare(executive)
        return words[PLAN_TIME_NS] / 1e9

    def prepare(self, executive: Executive) -> Boundary:
        """Read the pending plan for `executive`'s tasks as they are now: what its boundary will do."""
        words = self.words
        assert words is not None and self.reconfiguration is not None
        sequence = words[PLAN_SEQUENCE]
        configuration, activation = words[PLAN_CONFIGURATION], words[PLAN_TIME_NS] / 1e9
        staged = self.staged
        reconfiguration = staged.reconfiguration if staged is not None else self.reconfiguration
        view = reconfiguration.views[configuration]
        members = view.members
        leaving = [s for s in executive.on if s.task.name not in members]
        entering = [s for s in executive.tasks.values() if s.task.name in members and s.task.state == TaskState.OFF]
        staying = [s for s in executive.on if s.critical and s.task.name in members]
        watches = [(s, writers_to_watch(s, reconfiguration, configuration)) for s in (*staying, *entering) if s.critical]
        return Boundary(sequence, configuration, activation, executive.changes, staged, self.reconfiguration, view.name,
                        leaving, entering, watches, [s for s in executive.tasks.values() if s.critical])

    def apply(self, executive: Executive) -> None:
        """Switch `executive`'s tasks to the planned configuration, at this cycle boundary.

        Only the switch itself is done here: what it turns off and on was read with the plan
        (`prepare`), unless the tasks changed since; its reports are built after the boundary's cycles."""
        words = self.words
        assert words is not None
        clock = executive.clock
        applied_at = clock.now()
        words[self.switching_word] = int(applied_at * 1e9) or 1
        plan = self.prepared
        if (plan is None or plan.sequence != words[PLAN_SEQUENCE] or plan.changes != executive.changes
                or plan.staged is not self.staged or plan.reconfiguration is not self.reconfiguration):
            plan = self.prepare(executive)
        self.prepared = None
        activation = plan.activation
        if self.staged is not None:  # a live change: its configurations and tunes, at this boundary
            self._swap_in(self.staged, self.staged_tunes, executive.tasks)
            self.staged, self.staged_tunes = None, {}
        plan.closed, plan.windows = self.seen, self._close_windows(plan.critical)
        try:
            for s in plan.leaving:
                executive.leave_on(s)
                s.task.turn_off(clock.now())
            for s in plan.turning_on:
                executive.turn_on(s, activation, plan=plan.sequence)
            for s, watched in plan.watches:
                if s.task.state == TaskState.ON:
                    watch_writers(s, watched, activation)
        finally:
            words[self.switching_word] = 0
        self.seen = plan.sequence
        self.configuration = plan.configuration
        executive.holds.last_switch = activation
        plan.done_at = clock.now()
        plan.applied_at = applied_at
        plan.read_at = self.read_at if self.read == plan.sequence else applied_at
        plan.states = [(s.task.state, s.task.last_error, s.task.output_failed) for s in (*plan.leaving, *plan.entering)]
        self.held_reports.append(plan)

    def send_held_reports(self) -> None:
        """Send what a switch held back until its boundary's cycles ran (`apply`)."""
        if self.held_reports:
            for held in self.held_reports:
                if isinstance(held, Boundary):
                    for event in held.reports():
                        self.report(event)
                else:
                    self.report(held)
            self.held_reports.clear()

    def report_windows(self, tasks: Any) -> None:
        """Per switch: what each critical task read between that switch and the next (or the stop)."""
        for name, lost, stale in self._close_windows([s for s in tasks if s.critical]):
            self.report(Window(self.seen, name, lost, stale))

    def _close_windows(self, critical: list[Scheduled]) -> list[tuple[str, int, int]]:
        """Each critical task's lost and stale reads since the last switch (none before the first); the next window opens."""
        closed = []
        for s in critical:
            lost, stale = s.lost_to_switch - s.window_lost, s.stale_reads - s.window_stale
            s.window_lost, s.window_stale = s.lost_to_switch, s.stale_reads
            if self.seen:
                closed.append((s.task.name, lost, stale))
        return closed

    def stage(self, sequence: int, tasks: dict[str, Scheduled], factories: dict[str, Callable[[], Task]],
              hand_off: Callable[[Callable[[], None]], None] | None = None) -> None:
        """Read live description `sequence` and keep it for the next plan; its tasks on this RTPU can be spawned now.

        `hand_off`: on the real clock, the reading (a file, a JSON text, the configurations built)
        runs in the RTPU's background thread, not between two cycles, and says Staged from there.
        Job control posts the change's plan only once every RTPU said so."""
        hosted = [(name, s.task) for name, s in tasks.items()]  # taken here: the executive's thread changes `tasks`
        if hand_off is None:
            self._stage(sequence, hosted, factories)
        else:
            hand_off(lambda: self._stage(sequence, hosted, factories))

    def _stage(self, sequence: int, hosted: list[tuple[str, Task]], factories: dict[str, Callable[[], Task]]) -> None:
        try:
            if self.live_loader is None:
                raise RuntimeError("this RTPU was started without a live description")
            stage = self.live_loader(sequence)
            tunes = {}
            for name, task in hosted:
                index, params = stage.tasks.get(name, (-1, None))
                if index == task.index and params != task.spec.params and task.state != TaskState.KILLED:
                    spec = stage.spec(name)
                    tunes[name] = (spec, task.tune_params(spec))  # built now: the boundary only calls tune
        except Exception as exc:  # job control refuses the change and says why
            self.report(messages.Staged(sequence, f"{type(exc).__name__}: {exc}"))
            return
        self.staged, self.staged_tunes = stage, tunes
        factories.update(stage.factories)
        self.report(messages.Staged(sequence))

    def _swap_in(self, stage: LiveStage, tunes: dict[str, Any], tasks: dict[str, Scheduled]) -> None:
        """The staged live description becomes this RTPU's: who is in which configuration, who writes
        what; tasks whose tunable parameters changed take them now, between two cycles."""
        self.reconfiguration = stage.reconfiguration
        for name, (spec, params) in tunes.items():
            try:
                tasks[name].task.tune(spec, params)
            except Exception as exc:  # the checker passed the values: a module that refuses them says why
                self.report(Refused(name, f"tune: {exc}"))
