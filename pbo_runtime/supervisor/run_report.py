"""How the supervisor fills the run's report (`RunResult`, reports/run_result.py) from the children's
statistics, the stall watch and the table."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from pbo_runtime.config.model import Subsystem, TaskSpec
from pbo_runtime.ipc.task_statistics import Overrun, TaskStatistics
from pbo_runtime.reports.log_notes import variable_notes
from pbo_runtime.reports.run_records import StableEpisode
from pbo_runtime.reports.run_result import FinalValue, Stall, TaskReport
from pbo_runtime.reports.run_result import PlantFigures as PlantFigures
from pbo_runtime.reports.run_result import RtpuSettings as RtpuSettings
from pbo_runtime.reports.run_result import RunResult as RunResult  # where the supervisor's parts find it
from pbo_runtime.supervisor.status_reply import TaskRow
from pbo_runtime.table.snapshot import TableBusy
from pbo_runtime.table.table import StateTable, copy_variable
from pbo_runtime.table.table import StatusWord as W

if TYPE_CHECKING:
    from pbo_runtime.supervisor.job_control import JobControl
    from pbo_runtime.supervisor.stall_watch import StallWatch

STOP_TIMEOUT = 5.0  # seconds an RTPU has to stop by itself before it is signalled (and then again before SIGKILL)
# A critical task's hold on stale inputs that ended by itself within this many of its periods is a
# late input (the machine held the writer's CPU a moment), told in the summary as timing, as an
# overrun is; a longer one, one still going at the stop, or brief ones adding up to more than
# BRIEF_HOLDS_SHARE of the run are faults (exit status 2).
BRIEF_HOLD_PERIODS = 10
BRIEF_HOLDS_SHARE = 0.05


def _table_statistics(words: np.ndarray) -> TaskStatistics:
    """What a run report gives for a task whose RTPU was killed before it could report: its status
    block's counters. The percentiles are over the last 1,024 cycles (0 before)."""
    return TaskStatistics(cycles=int(words[W.CYCLES]), overruns=int(words[W.OVERRUNS]), missed=int(words[W.MISSED]),
                          jitter_max=float(words[W.JITTER_MAX]), jitter_p50=float(words[W.JITTER_P50]),
                          jitter_p99=float(words[W.JITTER_P99]), exec_p50=float(words[W.EXEC_P50]),
                          exec_p99=float(words[W.EXEC_P99]), exec_max=float(words[W.EXEC_MAX]))


class EventsTold(Protocol):
    """What the run's report takes from the children's events (`supervisor.event_ledger.EventLedger`)."""

    @property
    def task_errors(self) -> dict[str, str]: ...
    @property
    def stats(self) -> dict[str, TaskStatistics]: ...
    @property
    def stable(self) -> dict[str, tuple[float, str, str]]: ...
    def end_stable_episode(self, task: str, at: float | None) -> None: ...


class RunReporting:
    """The supervisor's part that fills its RunResult and reads the live view's rows from the table.

    `subsystem`, `table` and `started_at` give the run's as they are now (a live change replaces
    the subsystem); `told` is what the children's events told (the supervisor's event ledger).
    """

    def __init__(self, result: RunResult, told: EventsTold, job_control: JobControl, stall_watch: StallWatch,
                 every_task: dict[str, TaskSpec], subsystem: Callable[[], Subsystem],
                 table: Callable[[], StateTable | None], started_at: Callable[[], float | None]) -> None:
        self.result = result
        self.ledger = told
        self.job_control = job_control
        self.stall_watch = stall_watch
        self.every_task = every_task  # every task the run has had, by name: live changes add and remove some
        self._subsystem = subsystem
        self._table = table
        self._started_at = started_at

    @property
    def subsystem(self) -> Subsystem:
        return self._subsystem()

    @property
    def table(self) -> StateTable | None:
        return self._table()

    @property
    def started_at(self) -> float | None:
        return self._started_at()

    @property
    def task_errors(self) -> dict[str, str]:
        return self.ledger.task_errors

    def report_run(self) -> None:
        """Switches, each task's figures, stalls, stable episodes: into the result, once the children have reported."""
        self.result.switches = [record.report() for record in self.job_control.switches]
        self.result.marks = list(self.job_control.marks)
        self.result.decisions = list(self.job_control.decisions)
        self.result.started_at = self.started_at if self.started_at is not None else 0.0
        started = self.started_at if self.started_at is not None else 0.0
        self._report_tasks_left_in_error()
        self._report_stable_episodes(started)
        for name, stats in self.ledger.stats.items():
            # an overrun's release as seconds since the configuration came on, as the summary reads it
            overruns = tuple(Overrun(o.release - started, o.late, o.took) for o in stats.last_overruns)
            spec = self.subsystem.tasks.get(name) or self.every_task[name]
            self.result.tasks[name] = TaskReport(spec.rtpu, spec.critical, self.result.states_at_stop.get(name, "?"),
                                                 self.task_errors.get(name, ""),
                                                 dataclasses.replace(stats, last_overruns=overruns))
            for device, figures in stats.devices.items():
                if figures.get("command"):  # a robot interface braked the arm: its limits were left
                    writers = {variable: final.writer for variable, final in self.result.variables.items()}
                    self.result.faults += divergence_lines(name, spec, figures, writers, started)
                elif figures.get("fault"):  # a special-purpose processor that died under its task: the task said so too
                    self.result.faults.append(f"device '{device}' of task '{name}': {figures['fault']}")
        self._report_stalls(started)
        trips = self.result.plant.watchdog_trips if self.result.plant is not None else 0
        if trips:  # no task of the run commanded the arm: only the drive itself held it
            self.result.faults.append(
                f"the arm's drive watchdog held the arm {trips} time{'s' if trips > 1 else ''}: no command came within "
                "its timeout (the plant's command_timeout) while the brakes were off; the task that drives it was "
                "stopped, starved or blocked")

    def _report_tasks_left_in_error(self) -> None:
        """A task still in ERROR at the stop is a fault of the run: nobody cleared it, and a critical task
        that needs it held the arm meanwhile (its own line says so)."""
        for name, state in self.result.states_at_stop.items():
            if state != "ERROR":
                continue
            spec = self.subsystem.tasks.get(name) or self.every_task.get(name)
            where = f" on {spec.rtpu}" if spec is not None else ""
            if any(fault.startswith(f"task '{name}'{where} ") for fault in self.result.faults):
                continue  # its failure was told as a fault when it happened (a log it could not write)
            if any(figures.get("command") for figures in self.ledger.stats.get(name, TaskStatistics()).devices.values()):
                continue  # a robot interface that braked the arm past its limits: its divergence line tells it
            error = self.task_errors.get(name, "") or "its module reported an error"
            self.result.faults.append(f"task '{name}'{where} was in ERROR at the stop: {error} "
                                      f"(while a run goes on: pbo clear {name}, then pbo on {name})")

    def _report_stable_episodes(self, started: float) -> None:
        """Close the episodes still open at the stop; tell each task's faults and timing holds (`stable_episode_lines`)."""
        for task in list(self.ledger.stable):
            self.ledger.end_stable_episode(task, None)
        periods = {name: task.period for name, task in {**self.every_task, **self.subsystem.tasks}.items()}
        self.result.stable_episodes = marked_episodes(self.result.stable_episodes, periods, self.started_at)
        faults, timing = stable_episode_lines(self.result.stable_episodes, periods, self.started_at, self.result.duration,
                                              {name for name, task in self.subsystem.tasks.items() if task.critical})
        self.result.faults += faults
        self.result.timing_holds += timing

    def _report_stalls(self, started: float) -> None:
        """Stalls into the result; the table's counters for tasks whose RTPU was killed before it could report."""
        killed = self.result.unstopped
        for stall in self.stall_watch.episodes:
            self.result.stalls.append(Stall(stall.task, stall.rtpu, stall.since - started,
                                            None if stall.until is None else stall.until - started, stall.rtpu in killed))
        if not killed:
            return
        assert self.table is not None
        for task in self.subsystem.tasks.values():
            if task.name in self.result.tasks or task.rtpu not in killed:
                continue
            self.result.tasks[task.name] = TaskReport(
                task.rtpu, task.critical, self.result.states_at_stop.get(task.name, "?"), self.task_errors.get(task.name, ""),
                _table_statistics(self.table.status[task.index]), from_table=True)  # its RTPU never reported
        if not self.result.failure:
            stuck = [s.task for s in self.stall_watch.episodes if s.until is None and s.rtpu in killed]
            were = "was" if len(killed) == 1 else "were"
            self.result.failure = (
                f"{', '.join(killed)} did not stop within {STOP_TIMEOUT:g} s and {were} killed: the kill components of its "
                "tasks did not run" + (f" (stalled: {', '.join(stuck)})" if stuck else ""))

    def read_final_values(self) -> None:
        """Every variable's last value, lock-free; if a writer left the table mid-write, as it is, marked torn."""
        if self.table is None:
            return
        table, torn = self.table, False
        notes = variable_notes(self.subsystem)  # a plot of an .npy log takes its units from here
        tasks = (*self.subsystem.tasks.values(), *self.every_task.values())
        for var in self.subsystem.variables.values():
            slot = table.layout.slot(var.name)
            try:
                if torn:
                    raise TableBusy("busy for the variables before")  # one wait for "busy" is enough
                value, seq, _when, writer = table.read(var.name)
            except TableBusy:
                value, seq, _when, writer = copy_variable(table.view(var.name), table.words, slot.meta_word, table.status)
                torn = True
            self.result.variables[var.name] = FinalValue(
                value.tolist(), seq, next((t.name for t in tasks if t.index == writer), "job control"), notes[var.name][1],
                torn)

    def status_rows(self) -> list[TaskRow]:
        """The live view's data, from a lock-free copy of the table's status blocks.

        A table kept busy gives the blocks as they are: each figure is one word, and the view
        must not wait on a writer.
        """
        rows: list[TaskRow] = []
        if self.table is None:
            return rows
        try:
            blocks = self.table.status_blocks()
        except TableBusy:
            blocks = self.table.status.copy()
        for task in self.subsystem.tasks.values():
            rows.append(TaskRow.from_words(task.name, task.rtpu, blocks[task.index]))
        return rows


def divergence_lines(task: str, spec: Any, figures: Mapping[str, Any], writers: Mapping[str, str],
                     started: float) -> list[str]:
    """One line per time the robot interface `task` braked the arm for leaving its limits, naming
    when (from `started`, the run's clock when the configuration came on) and the task that wrote
    the command it was given (the last writer of that in-var's variable, from `writers`)."""
    lines = []
    for fault in figures.get("faults", [figures]):
        variable = next((b.variable for b in spec.bindings if b.port.name == fault["command"]), fault["command"])
        writer = writers.get(variable, "")
        by = f"task '{writer}'" if writer and writer != "job control" else "job control" if writer else "no task"
        lines.append(f"{fault['fault']} at {fault.get('at', started) - started:.3f} s into the run (robot interface "
                     f"'{task}'; its '{variable}' was written by {by})")
    return lines


def marked_episodes(episodes: Sequence[StableEpisode], periods: Mapping[str, float],
                    started_at: float | None) -> list[StableEpisode]:
    """Each episode marked `while_starting` (it began before the configuration came on and ended) and
    `brief` (it ended by itself within BRIEF_HOLD_PERIODS of its task's periods)."""
    marked = []
    for episode in episodes:
        seconds = episode.seconds
        marked.append(dataclasses.replace(
            episode, while_starting=started_at is not None and episode.since < started_at and seconds is not None,
            brief=seconds is not None and seconds < BRIEF_HOLD_PERIODS * periods.get(episode.task, 0.0)))
    return marked


def stable_episode_lines(episodes: Sequence[StableEpisode], periods: Mapping[str, float], started_at: float | None,
                         duration: float, critical: set[str] | None = None) -> tuple[list[str], list[str]]:
    """(faults, timing holds): one line per critical task and cause, from its stable episodes.

    Episodes of stale inputs or of a module's own STABLE count, once the configuration came on:
    while it comes on, task by task, a critical task on first may hold the arm until its writers
    run, which is what it is for (`while_starting`). An episode is brief when it ended by itself
    within BRIEF_HOLD_PERIODS of its task's periods (`brief`; see `marked_episodes`).
    Brief ones are timing unless they add up to more than BRIEF_HOLDS_SHARE of the run. A task that
    is not critical (in `critical`, when given) and returned STABLE had no fresh input (a link's
    item past its bound); the critical tasks' holds it caused (cause "upstream") are in the
    episodes, and the fault is told once, at the task that saw the stale input. Holds because the
    table lock stayed held past the cycle's wait (cause "lock": a process died holding it) are
    timing, told with how often: the fault is the death, which the run tells. A hold because the
    configuration is illegal (a task in ERROR) is the operator's to end; one still going at the stop
    is a fault: the arm stayed braked.
    """
    origin = started_at if started_at is not None else 0.0
    grouped: dict[tuple[str, str], list[StableEpisode]] = {}
    locked: dict[str, list[StableEpisode]] = {}
    braked: list[StableEpisode] = []
    for episode in marked_episodes(episodes, periods, started_at):
        if episode.cause in ("stale", "module") and not episode.while_starting:
            grouped.setdefault((episode.task, episode.cause), []).append(episode)
        elif episode.cause == "lock":
            locked.setdefault(episode.task, []).append(episode)
        elif episode.cause == "illegal" and episode.until is None:
            braked.append(episode)
    faults, timing = [], []
    for episode in braked:  # the operator did not bring the configuration back: the arm stayed held
        faults.append(f"critical task '{episode.task}' ran its locally stable behaviour "
                      f"{_episodes([episode], origin)}: {episode.reason}")
    for (task, _), group in grouped.items():
        brief = [e for e in group if e.brief]
        held = sum(e.seconds or 0.0 for e in brief)
        if len(brief) == len(group) and held <= BRIEF_HOLDS_SHARE * duration:
            timing.append(f"critical task '{task}' held {_episodes(brief, origin)}, each back to its cycle within "
                          f"{BRIEF_HOLD_PERIODS} periods (a late input: timing, not a fault): {brief[0].reason}")
        elif critical is not None and task not in critical:
            faults.append(f"task '{task}' had no fresh input {_episodes(group, origin)} (its cycle returned STABLE: "
                          "a link's item or a topic's message past its bound), and the critical tasks held meanwhile")
        else:
            faults.append(f"critical task '{task}' ran its locally stable behaviour {_episodes(group, origin)}: "
                          f"{group[0].reason}")
    for task, locks in locked.items():
        timing.append(f"critical task '{task}' held {_episodes(locks, origin)}, rather than wait for the table lock: "
                      f"{locks[0].reason}")
    return faults, timing


def _episodes(episodes: list[StableEpisode], origin: float) -> str:
    """How long, or how often, and from when: "for 1.0 ms, from 2.232 s into the run", "3 times (the longest ...)"."""
    first = episodes[0]
    if len(episodes) == 1:
        lasted = "until the stop" if first.seconds is None else f"for {first.seconds * 1e3:.1f} ms"
        return f"{lasted}, from {first.since - origin:.3f} s into the run"
    ended = [e.seconds for e in episodes if e.seconds is not None]
    longest = "one until the stop" if len(ended) < len(episodes) else f"the longest {max(ended) * 1e3:.1f} ms"
    return f"{len(episodes)} times ({longest}), the first from {first.since - origin:.3f} s into the run"
