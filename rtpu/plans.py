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
from pbo_runtime.ipc.messages import Event, Refused, Switched, Window
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.table.table import Header, TaskState
from pbo_runtime.task.lifecycle import Task

if TYPE_CHECKING:
    from rtpu._executive import Executive, Scheduled

# Header words read before every release, as plain ints (through a memoryview: no numpy scalar each time)
PLAN_SEQUENCE, PLAN_TIME_NS = int(Header.PLAN_SEQUENCE), int(Header.PLAN_TIME_NS)


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
        self.report = report
        self.seen = int(header[Header.PLAN_SEQUENCE]) if header is not None else 0  # the last plan applied here
        # When this RTPU first read the pending plan (off the per-cycle path: only while one is
        # pending): job control sizes the plan's lead from how long RTPUs take to read a plan.
        self.read = self.seen
        self.read_at = 0.0
        # A switch's reports (its windows, the tasks' new states, Switched), sent after the boundary's cycles
        self.held_reports: list[Event] = []
        self.configuration = -1  # index of the configuration last applied here
        self.live_loader = live_loader
        self.staged: LiveStage | None = None
        self.staged_tunes: dict[str, Any] = {}  # hosted task -> (its new spec, its Params), when its parameters changed

    def notice(self, now: float) -> float:
        """The pending plan's activation time; the first time this RTPU saw it is stamped (reported with its `Switched`)."""
        words = self.words
        assert words is not None
        sequence = words[PLAN_SEQUENCE]
        if sequence != self.read:
            self.read = sequence
            self.read_at = now
        return words[PLAN_TIME_NS] / 1e9

    def apply(self, executive: Executive) -> None:
        """Switch `executive`'s tasks to the planned configuration, at this cycle boundary."""
        header = self.header
        assert header is not None and self.reconfiguration is not None
        clock = executive.clock
        applied_at = clock.now()
        header[self.switching_words[0] + self.rtpu_index] = int(applied_at * 1e9) or 1
        sequence = int(header[Header.PLAN_SEQUENCE])
        configuration = int(header[Header.PLAN_CONFIGURATION])
        activation = header[Header.PLAN_TIME_NS] / 1e9
        if self.staged is not None:  # a live change: its configurations and tunes, at this boundary
            self._swap_in(self.staged, self.staged_tunes, executive.tasks)
            self.staged, self.staged_tunes = None, {}
        view = self.reconfiguration.views[configuration]
        held = self.held_reports.append
        self.report_windows(executive.tasks.values(), sequence, held)
        leaving = [s for s in executive.on if s.task.name not in view.members]
        entering = [s for s in executive.tasks.values() if s.task.name in view.members and s.task.state == TaskState.OFF]
        try:
            for s in leaving:
                executive.leave_on(s)
                s.task.turn_off(clock.now())
            for s in sorted(entering, key=lambda s: not s.critical):
                executive.turn_on(s, activation, plan=sequence)
            for s in executive.on:
                if s.critical:
                    executive.watch(s, configuration, activation)
        finally:
            header[self.switching_words[0] + self.rtpu_index] = 0
        self.seen = sequence
        self.configuration = configuration
        executive.holds.last_switch = activation
        done_at = clock.now()
        for s in (*leaving, *entering):
            executive.report_state(s.task, held)
        read_at = self.read_at if self.read == sequence else applied_at
        held(Switched(sequence, view.name, activation, applied_at, done_at,
                      [s.task.name for s in leaving], [s.task.name for s in entering], read_at))

    def send_held_reports(self) -> None:
        """Send what a switch held back until its boundary's cycles ran (`apply`)."""
        if self.held_reports:
            for event in self.held_reports:
                self.report(event)
            self.held_reports.clear()

    def report_windows(self, tasks: Any, following: int = 0, send: Callable[[Event], None] | None = None) -> None:
        """Per switch: what each critical task read between that switch and the next (or the stop)."""
        send = send or self.report
        s: Scheduled
        for s in tasks:
            if not s.critical:
                continue
            lost, stale = s.lost_to_switch - s.window_lost, s.stale_reads - s.window_stale
            s.window_lost, s.window_stale = s.lost_to_switch, s.stale_reads
            if self.seen:
                send(Window(self.seen, s.task.name, lost, stale))

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
