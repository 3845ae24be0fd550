"""What the children's events change: the tasks' states and errors, their stable episodes, their
figures, the signals refused, and the run's faults. `EventLedger.absorb` takes one event and
changes only this ledger and the run's result; what else an event concerns (a switch's record,
a live description staged, the table's error words) it hands on through `EventOutlets`, so the
handling is tested event by event without a process."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Protocol

from pbo_runtime.config.model import TaskSpec
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.task_statistics import TaskStatistics
from pbo_runtime.reports.run_records import StableEpisode
from pbo_runtime.supervisor.failures import RunFailure
from pbo_runtime.supervisor.run_report import PlantFigures, RunResult

STABLE_EPISODES_TOLD = 5  # holds for late inputs per critical task told as they happen; the summary counts them all


@dataclass(frozen=True)
class ErrorWords:
    """What the table's header tells the critical tasks: they run locally stable while `illegal`."""

    in_error: int  # tasks of the configuration in ERROR
    not_fresh: int  # tasks of it, not critical, whose module said its inputs are not fresh
    illegal: bool


def error_words(members: Iterable[str], task_states: Mapping[str, str], stable: Mapping[str, tuple[float, str, str]],
                tasks: Mapping[str, TaskSpec]) -> ErrorWords:
    """The header's error words for the configuration of `members`, from the tasks' states and open stable episodes.

    A task that is not critical and says its inputs are not fresh (a link_receiver whose item is past
    its bound): what it writes is stale too, so the critical tasks hold until it has fresh inputs again.
    """
    members = list(members)
    in_error = sum(1 for t in members if task_states.get(t) == "ERROR")
    not_fresh = sum(1 for t in members if t in stable and t in tasks and not tasks[t].critical and stable[t][2] == "module")
    return ErrorWords(in_error, not_fresh, bool(in_error) or bool(stable))


class SwitchReports(Protocol):
    """Where an RTPU's reports of a switch go (`JobControl`)."""

    def switched(self, rtpu: str, sequence: int, applied_at: float, done_at: float, off: list[str], on: list[str],
                 read_at: float = 0.0) -> None: ...

    def window(self, sequence: int, task: str, lost: int, stale: int) -> None: ...

    def first_cycle(self, sequence: int, task: str, at: float) -> None: ...


@dataclass(frozen=True)
class EventOutlets:
    """What an event concerns beyond the ledger, given explicitly by the supervisor (or a test)."""

    switches: SwitchReports  # an RTPU's reports of a switch
    staged: Callable[[str, int, str], None]  # an RTPU read live description N (`Staged`): rtpu, sequence, error
    count_errors: Callable[[], None]  # a task entered or left ERROR, or a stable episode opened or closed
    child_exited: Callable[[], None]  # a child's death was signalled: look at the children now
    running: Callable[[], bool]  # whether the configuration is on (a plant stall while the children start is no fault)


class EventLedger:
    """The run's record of its children's events (see the module's docstring)."""

    def __init__(self, result: RunResult, say: Callable[[str], None], outlets: EventOutlets,
                 critical: Callable[[str], bool] = lambda task: True) -> None:
        self.result = result
        self.say = say
        self.outlets = outlets
        self.critical = critical  # whether a task is critical (one not known: critical)
        # each dict is this ledger's for the run (never rebound: the supervisor's parts hold them too)
        self.task_states: dict[str, str] = {}
        self.task_errors: dict[str, str] = {}
        self.stable: dict[str, tuple[float, str, str]] = {}  # task -> (since, reason, cause) of its open episode
        self.stats: dict[str, TaskStatistics] = {}  # by task, as each RTPU reported them
        self.refused: dict[str, str] = {}  # task -> why its RTPU refused the last signal

    def absorb(self, source: str, event: messages.Event) -> None:
        """One event from `source` (a child's role); a child's crash raises RunFailure."""
        if isinstance(event, messages.StateChanged):
            self._state_changed(source, event)
        elif isinstance(event, messages.Switched):
            self.outlets.switches.switched(source, event.sequence, event.applied_at, event.done_at, event.off, event.on,
                                           event.read_at)
        elif isinstance(event, messages.Window):
            self.outlets.switches.window(event.sequence, event.task, event.lost, event.stale)
        elif isinstance(event, messages.FirstCycle):
            self.outlets.switches.first_cycle(event.sequence, event.task, event.at)
        elif isinstance(event, messages.Stable):
            self._stable(event)
        elif isinstance(event, messages.Stats):
            self.stats[event.task] = event.statistics
        elif isinstance(event, messages.PlantStats):
            self.result.plant = PlantFigures.from_json(event.figures)
        elif isinstance(event, messages.PlantStalled):
            stall = (f"the plant did not run for {event.seconds:.3f} s (its process was stopped or starved) and resumed at "
                     f"simulated time {event.sim_time:.3f} s without integrating the backlog")
            if self.outlets.running():  # (while the children start, they starve it of CPU, and no task drives it yet)
                self.result.faults.append(stall)
            self.say(stall)
        elif isinstance(event, messages.Refused):
            self.refused[event.task] = event.reason
            self.say(f"{source} refused a signal for '{event.task}': {event.reason}")
        elif isinstance(event, messages.Staged):
            self.outlets.staged(source, event.sequence, event.error)
        elif isinstance(event, messages.ChildExited):
            self.outlets.child_exited()
        elif isinstance(event, messages.Crashed):
            raise RunFailure(f"{source} crashed: {event.error}" + (f"\n{event.trace}" if event.trace else ""))

    def _state_changed(self, source: str, event: messages.StateChanged) -> None:
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
            self.outlets.count_errors()

    def _stable(self, event: messages.Stable) -> None:
        task, at = event.task, event.at
        if event.entering:
            self.stable[task] = (at, event.reason, event.cause)
            if self._told(task, event.cause):
                self.say(self._stable_news(task, event.reason))
        elif task in self.stable:
            cause = self.stable[task][2]
            told = self._told(task, cause)
            self.end_stable_episode(task, at)
            began = self.result.stable_episodes[-1].since
            if told:
                self.say(f"{self._kind_of(task)} '{task}' is back to its cycle after {(at - began) * 1e3:.1f} ms"
                         + ("" if self._told(task, cause) else "; its further holds for late inputs are counted in "
                                                               "the summary, not told"))
        self.outlets.count_errors()

    def _kind_of(self, task: str) -> str:
        return "critical task" if self.critical(task) else "task"

    def _stable_news(self, task: str, reason: str) -> str:
        if not self.critical(task):  # it says its inputs are stale, and the critical tasks hold
            return f"task '{task}' has no fresh input (its cycle returned STABLE): the critical tasks hold until it has"
        return f"critical task '{task}' runs its locally stable behaviour: {reason or 'the configuration is illegal'}"

    def _told(self, task: str, cause: str) -> bool:
        """Whether a stable episode of `task` for `cause` is told as it happens: always when the
        configuration is illegal (the operator acts on it), the first few holds for late inputs."""
        return cause == "illegal" or sum(1 for e in self.result.stable_episodes
                                         if e.task == task and e.cause != "illegal") < STABLE_EPISODES_TOLD

    def end_stable_episode(self, task: str, at: float | None) -> None:
        """Into the report; `at` None: the task was still stable when the run stopped."""
        began, reason, cause = self.stable.pop(task)
        self.result.stable_episodes.append(StableEpisode(task, began, at, reason, cause))
