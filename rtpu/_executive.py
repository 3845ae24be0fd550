"""The RTPU executive: one thread that releases ON tasks on absolute deadlines (docs/architecture.md).

It waits for the earliest release with a timed receive on its signal queue, so signals and
timers share one wait; then runs the released tasks, most urgent first. The Executive composes
the concepts of rtpu/: when tasks are released and what each cycle's timing records
(`releases`), when a critical task is held to its stable behaviour (`holds`), plans and live
changes applied at a cycle boundary (`plans`), and what each signal does (`signals`). Per task
it keeps its timing record and figures in `Scheduled`, and the table's status block.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from pbo_runtime.ipc.messages import Event, FirstCycle, Refused, StateChanged, Stats
from pbo_runtime.ipc.process import raise_if_stopping
from pbo_runtime.ipc.task_statistics import Overrun, TaskStatistics
from pbo_runtime.objects.module import Status
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.table.table import Flag, Header, TaskState
from pbo_runtime.task import background
from pbo_runtime.task.lifecycle import Task
from rtpu.holds import HELD_BY_MODULE, NOT_HELD, Holds, release_lost_to_the_lock, watch_inputs
from rtpu.plans import PLAN_SEQUENCE, LiveStage, Plans
from rtpu.releases import (
    ON_THE_BOUNDARY,
    OVERRUNS_KEPT,
    RING,
    Barrier,
    Clock,
    close_cycle,
    first_release,
    record_jitter,
    written_ring,
)
from rtpu.signals import EVENTS_QUEUED, SignalSource, handle_signal

# Header words read before every release, as plain ints (through a memoryview: no numpy scalar each time)
_FLAGS, _STOPPING = int(Header.FLAGS), int(Flag.STOPPING)
# What a cycle returns, read once: an enum member read through its class costs a tenth of a microsecond
_CONTINUE, _STABLE = Status.CONTINUE, Status.STABLE


class Scheduled:
    """A task's place in the executive: its next release and its timing record."""

    __slots__ = (
        "aperiodic",
        "critical",
        "dropped_events",
        "events",
        "exec_max",
        "exec_ring",
        "exec_time",
        "expected_writers",
        "expired_reads",
        "first_cycle_of_plan",
        "fresh_bounds",
        "fresh_since",
        "fresh_within",
        "held_for",
        "input_periods",
        "input_writers",
        "jitter",
        "jitter_max",
        "jitter_ring",
        "last_lost",
        "last_release",
        "last_stale",
        "lock_waits_given_up",
        "long_cycles",
        "lost_to_switch",
        "missed",
        "overrun_log",
        "overruns",
        "period",
        "priority",
        "release",
        "release_index",
        "samples",
        "shared_status",
        "stable_cycles",
        "stale_at_switch",
        "stale_reads",
        "status",
        "status_words",
        "task",
        "window_lost",
        "window_stale",
        "write_times",
        "writer_names",
    )

    def __init__(self, task: Task, between: Callable[[], None] | None = None) -> None:
        """`between`: called between the steps of writing the timing rings (a live spawn runs the
        RTPU's due cycles there: the rings are a megabyte of pages faulted in)."""
        self.task = task
        spec = task.spec
        self.aperiodic = bool(getattr(spec, "aperiodic", False))
        self.period = (getattr(spec, "min_interarrival", None) or spec.period) if self.aperiodic else spec.period
        self.critical = spec.critical
        self.priority = spec.priority
        self.release = math.inf
        self.release_index = 0  # periodic: release = epoch + release_index * period
        self.last_release = -math.inf
        self.overruns = 0
        self.missed = 0
        self.long_cycles = 0  # overruns the cycle alone caused (it took more than a period)
        self.overrun_log = np.zeros(3 * OVERRUNS_KEPT)  # flat ring: release, lateness, execution time
        self.jitter = written_ring(between)
        self.exec_time = written_ring(between)
        self.jitter_ring: Any = self.jitter.data  # the same rings as memoryviews: per-cycle stores of floats
        self.exec_ring: Any = self.exec_time.data
        self.samples = 0
        self.jitter_max = 0.0
        self.exec_max = 0.0
        self.status = task.status
        self.status_words: Any = task.status.data  # the same words: a store costs about half a numpy array's
        self.shared_status = task.local.table.status[task.index]  # the table's own words, for what no cycle carries
        self.events: collections.deque[Any] = collections.deque(maxlen=EVENTS_QUEUED)
        self.dropped_events = 0
        self.stale_reads = 0
        self.stale_at_switch = 0
        self.last_stale = ""
        self.input_periods = [math.inf] * len(task.local.input_variables)  # producer periods, per in-var
        self.expected_writers = [-1] * len(task.local.input_variables)  # the configuration's writer, per in-var
        # Gathered with the inputs: each writer's last release, and who wrote what was read. Read
        # through memoryviews, as plain floats: the freshness check's arithmetic on numpy scalars
        # would cost several times its own.
        self.write_times: Any = task.local.input_write_times.data
        self.input_writers: Any = task.local.input_writer.data
        self.lost_to_switch = 0
        self.last_lost = ""
        self.window_lost = 0  # counts at the last switch: what a switch's window adds is the difference
        self.window_stale = 0
        self.stable_cycles = 0
        self.held_for = NOT_HELD  # why the current stable episode holds the task (one of the HELD_ reasons)
        # Freshness bound per in-var (seconds; inf: not watched), set per configuration by `_watch`
        self.fresh_bounds = [math.inf] * len(task.local.input_variables)
        self.writer_names = [""] * len(task.local.input_variables)
        by_port = getattr(spec, "fresh_within", None) or {}
        variable_of = {b.port.name: b.variable for b in spec.bindings}
        self.fresh_within = {variable_of[port]: bound for port, bound in by_port.items() if port in variable_of}
        # When the configuration it watches came on: what was written before counts as written
        # then, so each writer has its bound from the switch (or start) to write a first value.
        self.fresh_since = 0.0
        self.expired_reads = 0  # cycles a critical task ran stable because an input was past its bound
        self.lock_waits_given_up = 0  # releases whose read found the table lock held past `cycle_lock_wait`
        self.first_cycle_of_plan = 0  # a plan's sequence until this entering task ran its first cycle

    def statistics(self, devices: dict[str, dict[str, Any]] | None = None) -> TaskStatistics:
        """Its figures so far, with its drivers' own (`devices`): built for a report, never per cycle."""
        n = min(self.samples, RING)
        jitter = self.jitter[:n]
        exec_time = self.exec_time[:n]

        def pct(a: np.ndarray, q: float) -> float:
            return float(np.percentile(a, q)) if n else 0.0

        local = self.task.local
        return TaskStatistics(
            cycles=self.task.cycles, overruns=self.overruns, missed=self.missed, errors=self.task.errors,
            jitter_p50=pct(jitter, 50), jitter_p99=pct(jitter, 99), jitter_max=self.jitter_max,
            exec_p50=pct(exec_time, 50), exec_p99=pct(exec_time, 99), exec_max=self.exec_max,
            bytes_in=local.bytes_in, bytes_out=local.bytes_out, bytes_moved_per_cycle=local.bytes_moved,
            stale_reads=self.stale_reads, stale_reads_at_switches=self.stale_at_switch, last_stale_read=self.last_stale,
            cycles_lost_to_switches=self.lost_to_switch, last_cycle_lost=self.last_lost,
            stable_cycles=self.stable_cycles, expired_reads=self.expired_reads,
            lock_waits_given_up=self.lock_waits_given_up, dropped_events=self.dropped_events,
            overruns_long_cycle=self.long_cycles, last_overruns=self.last_overruns(),
            outputs=tuple(dict.fromkeys(self.task.context.outputs)), devices=devices or {})

    def last_overruns(self) -> tuple[Overrun, ...]:
        """The last OVERRUNS_KEPT overruns, oldest first."""
        kept = min(self.overruns, OVERRUNS_KEPT)
        first = self.overruns - kept
        log = self.overrun_log
        return tuple(Overrun(float(log[3 * k]), float(log[3 * k + 1]), float(log[3 * k + 2]))
                     for k in ((first + i) % OVERRUNS_KEPT for i in range(kept)))



class Executive:
    """Runs the tasks of one RTPU. `handle` deals with one signal; `run_once` is one wait + cycles."""

    def __init__(self, clock: Clock, signals: SignalSource, report: Callable[[Event], None], epoch: float = 0.0,
                 header: np.ndarray | None = None, reconfiguration: Reconfiguration | None = None,
                 rtpu_index: int = 0, n_rtpus: int = 1, report_at_stop: Callable[[Event], None] | None = None,
                 live_loader: Callable[[int], LiveStage] | None = None,
                 cycle_lock_wait: list[float | None] | None = None) -> None:
        self.clock = clock
        self.signals = signals
        self.report = report  # report(event): events to job control (ipc.messages), on state changes only
        # At stop no cycle waits on a report, and the last windows, states and statistics must
        # not be dropped while every RTPU fills job control's queue at once: these may wait longer.
        self.report_at_stop = report_at_stop or report
        self.epoch = epoch  # releases are aligned to epoch + k * period
        self.tasks: dict[str, Scheduled] = {}
        self.factories: dict[str, Callable[[], Task]] = {}
        # called once, before the first task is turned on (a restarted RTPU takes SCHED_FIFO then)
        self.before_first_on: Callable[[], None] | None = None
        self.on: list[Scheduled] = []
        self.changes = 0  # counts changes to the tasks hosted or their states: a plan read before one is read again
        self.running = True
        self.idle_wait = 0.05
        # a task's drivers' own figures (a special-purpose processor's timing), reported with its statistics
        self.device_figures: Callable[[str], dict[str, Any]] = lambda task: {}
        self.header = header  # the table's int64 header: plans, switching words, error count
        self.plans = Plans(header, reconfiguration, rtpu_index, n_rtpus, live_loader, report)
        self.header_words = self.plans.words  # the same words, read as ints
        # The table's bound on a per-cycle transfer's wait for the lock (`StateTable.cycle_lock_wait`),
        # set when a critical task turns on; None on the simulated clock, whose turns never contend.
        self.cycle_lock_wait = cycle_lock_wait
        self.holds = Holds(self.header_words, self.plans.switching_words, cycle_lock_wait, report)
        self.release_slack = getattr(clock, "release_slack", 0.0)  # sim clock: a release a few ulps late is due
        self.spin = getattr(clock, "spin", 0.0)  # real clock: the wait on signals ends this long before a release
        # Simulated clock: time moves only between turns, so within a turn one reading serves every cycle
        self._time_stands_still = bool(getattr(clock, "stands_still_within_a_turn", False))
        # What a task's off or kill hands off (a log's last chunk and footer): done by a thread of
        # lower priority, never between two cycles; waited for at the stop (`stop`).
        background.process_background().start()
        # A queue says whether a signal waits in one cheap system call; a receive that finds none
        # costs far more (an exception), and most ticks bring no signal.
        self._signal_pending: Callable[[], bool] = getattr(signals, "pending", lambda: True)
        self.cycles_between_steps = False  # `run` (the real clock): due cycles run between the steps of a spawn

    @property
    def reconfiguration(self) -> Reconfiguration | None:
        """Who is in which configuration and who writes what: the file's, or the live description's last applied."""
        return self.plans.reconfiguration

    @reconfiguration.setter
    def reconfiguration(self, reconfiguration: Reconfiguration | None) -> None:
        self.plans.reconfiguration = reconfiguration

    # --- the loop ---------------------------------------------------------------------------

    def run(self) -> None:
        self.cycles_between_steps = True
        while self.running:
            self.run_once()

    def run_lockstep(self, barrier: Barrier) -> None:
        """The simulated clock's loop: per step, serve the queued signals; per new tick, the plan and the cycles.

        Nothing here waits on time: the supervisor releases a tick only when every participant
        finished the previous one, so the same inputs give the same cycles, bit for bit.
        """
        while self.running:
            new_tick = barrier.wait()
            try:
                raise_if_stopping()  # a stop that came while this process was not waiting (`stop_only_at_waits`)
                self.step_lockstep(new_tick)
            finally:
                barrier.done()

    def step_lockstep(self, new_tick: bool) -> None:
        """One turn on the simulated clock: serve the queued signals; on a new tick, the plan and the cycles.

        The whole of a turn, whoever gives it: this RTPU's own process (`run_lockstep`), or the
        one process that runs every participant of a simulated run in turn (`rtpu.in_process`).
        """
        if self.running and self._signal_pending():
            signal_queue = self.signals
            while True:
                message = signal_queue.receive(0)
                if message is None:
                    break
                self.handle(message)
                if not (self.running and self._signal_pending()):
                    break
        if new_tick and self.running:
            words = self.header_words
            if words is not None and words[PLAN_SEQUENCE] != self.plans.seen:
                self.plan_if_due()
            self.run_ready()
            if self.plans.held_reports:
                self.plans.send_held_reports()

    def run_once(self) -> None:
        """Wait for the earliest release (or a signal, or a plan's boundary), then run what is due."""
        clock = self.clock
        plans = self.plans
        next_release = math.inf
        for s in self.on:
            if s.release < next_release:
                next_release = s.release
        now = clock.now()
        words = self.header_words
        if words is not None and words[PLAN_SEQUENCE] != plans.seen:
            activation = plans.notice(now, self)  # read for this RTPU's tasks now: the boundary only switches
            if now + self.release_slack + ON_THE_BOUNDARY >= activation:
                self._switch_and_run()  # late (this RTPU read the plan after its activation): before any cycle
                return
            if activation < next_release:
                next_release = activation
        wait = self.idle_wait if next_release == math.inf else next_release - now
        # The kernel wait ends `spin` before the release; the clock spins the rest. All of this
        # runs before the release: nothing between the spin's end and the cycle but the pick.
        spin = self.spin
        message = self.signals.receive(wait - spin if wait > spin else 0)
        if message is not None:
            self.handle(message)
            return
        if next_release == math.inf:
            return
        if words is not None and words[_FLAGS] & _STOPPING:
            self.stop()  # the run is over: a cycle now would only compete with the others' stop work
            return
        woke = clock.sleep_until(next_release)
        # A plan posted while this RTPU waited, due by this boundary: applied before the boundary's
        # cycles, never after them. The RTPU that hosts the entering tasks has a boundary at the
        # activation; one that read the plan too late for its activation applies it here, at its
        # first boundary after it, before anything runs in the old configuration.
        if (words is not None and words[PLAN_SEQUENCE] != plans.seen
                and woke + self.release_slack + ON_THE_BOUNDARY >= plans.notice(woke)):
            self._switch_and_run()
            return
        self.run_ready(woke)

    def plan_if_due(self) -> bool:
        """Read a newly posted plan; apply it if its boundary has come. True if it was applied."""
        words = self.header_words
        if words is not None and words[PLAN_SEQUENCE] != self.plans.seen:
            now = self.clock.now()
            if now + self.release_slack + ON_THE_BOUNDARY >= self.plans.notice(now):
                self.apply_plan()
                return True
        return False

    def _switch_and_run(self) -> None:
        """Apply the plan at this boundary, run the boundary's cycles, then send the switch's reports."""
        self.apply_plan()
        self.run_ready()
        self.plans.send_held_reports()

    def run_ready(self, first_now: float | None = None) -> None:
        """Run every released task once, most urgent first (maximum-urgency-first); no allocation.

        Urgency: critical before not; then the earlier deadline (release + period); then the
        higher user priority. `first_now`: the time the wait ended (`Clock.sleep_until`), so the
        first cycle's jitter is timed where a bare loop times it; later picks read the clock.
        """
        clock = self.clock
        on = self.on
        slack = self.release_slack
        now = clock.now() if first_now is None else first_now
        still = self._time_stands_still
        while True:
            due = now + slack
            best = None
            for s in on:
                if s.release > due:
                    continue
                if best is None or s.critical > best.critical:
                    best = s
                elif s.critical == best.critical:
                    deadline, best_deadline = s.release + s.period, best.release + best.period
                    if deadline < best_deadline or (deadline == best_deadline and s.priority > best.priority):
                        best = s
            if best is None:
                return
            self._cycle(best, now)
            if not still:
                now = clock.now()

    def _cycle(self, s: Scheduled, start: float) -> None:
        """One release of `s`, begun at `start`: its cycle or its stable behaviour, its timing, its next release."""
        release = s.release
        task = s.task
        jitter = record_jitter(s, start - release)
        if s.aperiodic:
            task.context.event = s.events.popleft() if s.events else None
        held = NOT_HELD
        if s.critical:
            held = self.holds.before_cycle(s, release, start)  # reads the inputs first: their age decides
            result = task.run_read_stable_cycle(release) if held else task.run_read_cycle(release)
        elif task.read_inputs():
            result = task.run_read_cycle(release)
        else:  # the lock stayed held past the wait: this release is lost, the RTPU's critical cycles are not
            result = release_lost_to_the_lock(s)
        if result is _STABLE:
            held = held or HELD_BY_MODULE
            result = _CONTINUE
        if held or s.held_for:
            self.holds.after_cycle(s, held, result, start, release)
        end = start if self._time_stands_still else self.clock.now()
        s.release = close_cycle(s, release, jitter, start, end, self.epoch)
        if s.first_cycle_of_plan:
            self.report(FirstCycle(s.first_cycle_of_plan, task.name, start))
            s.first_cycle_of_plan = 0
        if result != _CONTINUE:
            self.leave_on(s)
            self.report_state(task)

    # --- the tasks hosted here ------------------------------------------------------------------

    def add(self, task: Task, factory: Callable[[], Task] | None = None) -> None:
        """Host a task; `factory` makes a fresh instance when a killed task is spawned again (static switches)."""
        self.tasks[task.name] = Scheduled(task)
        self.changes += 1
        if factory is not None:
            self.factories[task.name] = factory

    def handle(self, message: list[Any]) -> None:
        """One signal as it came off the queue (`signals.handle_signal`)."""
        handle_signal(self, message)

    def apply_plan(self) -> None:
        """Switch this RTPU's tasks to the planned configuration, at this cycle boundary (`plans`)."""
        self.plans.apply(self)

    def report_windows(self) -> None:
        """Per switch: what each critical task read between that switch and the next (or the stop)."""
        self.plans.report_windows(self.tasks.values())

    def turn_on(self, s: Scheduled, at: float, plan: int = 0) -> None:
        """Turn `s` on, released at its first boundary at or after `at` (aperiodic: by its first event)."""
        if s.aperiodic:  # released by its first event; messages that came while it was off are served now
            s.release = max(self.clock.now(), s.last_release + s.period) if s.events else math.inf
        else:
            s.release = first_release(s, at, self.epoch)
        self.changes += 1
        if s.task.turn_on(self.clock.now()):
            self.on.append(s)
            s.first_cycle_of_plan = plan
            if s.critical and self.cycle_lock_wait is not None:
                self.holds.bound_lock_wait(s.period)

    def watch(self, s: Scheduled, configuration: int, since: float) -> None:
        """A critical task's freshness check follows the writers of `configuration`, from `since` on (`holds.watch_inputs`)."""
        if s.critical and self.plans.reconfiguration is not None:
            watch_inputs(s, self.plans.reconfiguration, configuration, since)

    def leave_on(self, s: Scheduled) -> None:
        self.changes += 1
        if s in self.on:
            self.on.remove(s)

    def stop(self) -> None:
        """Turn everything off and kill it (kill runs off first), then report statistics."""
        self.report = self.plans.report = self.holds.report = self.report_at_stop
        self.plans.send_held_reports()
        self.report_windows()
        for s in list(self.tasks.values()):
            if s.task.state in (TaskState.ON, TaskState.OFF, TaskState.ERROR):
                self.leave_on(s)
                try:
                    s.task.kill(self.clock.now())
                except Exception as exc:
                    self.report(Refused(s.task.name, f"kill: {exc}"))
                self.report_state(s.task)
        self.report_background_failures(background.close_process_background())
        self.report_statistics()
        self.running = False

    def off_the_cycle(self, work: Callable[[], None]) -> None:
        """Run `work` in this RTPU's background thread, below the executive (`task.background`):
        a live change's reading and building, which between two cycles would make releases late."""
        background.process_background().hand_off(work, "", "staging a live change")

    # --- reports ----------------------------------------------------------------------------

    def report_background_failures(self, failures: list[background.Failure] | None = None) -> None:
        """Work a task handed off that failed (`PortBasedObject.hand_off`): the task's error, reported
        as a component's would be (an output that could not be written fails the run)."""
        for failure in background.process_background().take_failures() if failures is None else failures:
            s = self.tasks.get(failure.task)
            state = s.task.state.name if s is not None else TaskState.KILLED.name
            self.report(StateChanged(failure.task, state, f"{failure.what} failed: {failure.error}", failure.output))

    def report_statistics(self) -> None:
        """One Stats event per task: an RTPU hosting dozens of tasks would overflow one message."""
        for name, s in self.tasks.items():
            self.report(Stats(name, s.statistics(self.device_figures(name))))

    def report_state(self, task: Task, send: Callable[[Event], None] | None = None) -> None:
        (send or self.report)(StateChanged(task.name, task.state.name, task.last_error, task.output_failed))
