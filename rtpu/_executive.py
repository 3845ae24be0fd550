"""The RTPU executive: one thread that releases ON tasks on absolute deadlines (docs/architecture.md).

It waits for the earliest release with a timed receive on its signal queue, so signals and
timers share one wait; then runs the ready tasks, critical first, then earliest deadline
(maximum-urgency-first). The k-th release is epoch + k x period, counted, never summed, so the
rate does not drift and rounding does not pile up. Per task it keeps cycles, execution time, release jitter and overruns
in the table's status block, and samples for percentiles in preallocated rings.

Dynamic reconfiguration (TR §4.4): job control posts a plan in the table's header (a
configuration and an activation time); at its first cycle boundary at or after that time each
executive turns its leaving tasks off and its entering tasks on, so every RTPU switches at the
same instant without a message on the per-cycle path. A critical task reads its inputs before it
runs, and runs its locally stable behaviour instead of its cycle while the configuration is
illegal (a switch that overran a cycle, or a task of the configuration in ERROR), or while an
input is older than its freshness bound (its writer stalled: by default two of the writer's
periods, `fresh_within` in YAML), or when the module itself returns `Status.STABLE` (a device
that stopped updating); it resumes by itself when they are fresh again. It also counts reads
older than one writer period (stale reads: timing, not yet a fault). Aperiodic tasks run on
events instead of a timer.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import math
from typing import Any, Callable, Protocol

import numpy as np

from pbo_runtime.ipc import messages
from pbo_runtime.ipc.process import raise_if_stopping
from pbo_runtime.ipc.task_statistics import Overrun, TaskStatistics
from pbo_runtime.ipc.messages import Event, FirstCycle, Refused, Stable, StateChanged, Stats, Switched, Window
from pbo_runtime.objects import waits
from pbo_runtime.task import background
from pbo_runtime.task.lifecycle import Task
from pbo_runtime.objects.module import Status
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.table.table import Flag, Header, TaskState
from pbo_runtime.table.table import StatusWord as W

RING = 1 << 16  # samples kept per task for percentiles (65 s at 1 kHz)
RECENT = 1 << 10  # every RECENT cycles, the last RECENT samples' percentiles go to the table for pbo status
EVENTS_QUEUED = 16  # events an aperiodic task holds while it waits out its min inter-arrival time
SWITCH_WINDOW_PERIODS = 3  # a stale read this close after a switch is counted against the switch
AGE_TOLERANCE = 1e-7  # seconds: an input exactly one producer period old is fresh, whatever the rounding
# The default freshness bound of a critical task's input, in periods of its writer: one missed
# write is tolerated, a second one means the writer stalled (detected within 3 of the reader's
# periods when both run at one rate).
FRESH_WITHIN_WRITER_PERIODS = 2.0
# Why a critical task runs its locally stable behaviour (the cycle's `held`)
NOT_HELD, HELD_ILLEGAL, HELD_STALE_INPUT, HELD_BY_MODULE, HELD_UPSTREAM, HELD_LOCKED = 0, 1, 2, 3, 4, 5
# On the real clock, a per-cycle transfer on an RTPU hosting a critical task waits for the table
# lock at most this share of the shortest critical period there: the lock is held for microseconds,
# so a wait this long means its holder died holding it (until job control releases it) or stalled.
# Read and write together then leave the cycle three quarters of its period.
LOCK_WAIT_PERIODS = 0.125
# Header words read before every release, as plain ints (through a memoryview: no numpy scalar each time)
_FLAGS, _STOPPING, _STATIC_SWITCH = int(Header.FLAGS), int(Flag.STOPPING), int(Flag.STATIC_SWITCH)
_PLAN_SEQUENCE, _PLAN_TIME_NS = int(Header.PLAN_SEQUENCE), int(Header.PLAN_TIME_NS)
_TASKS_IN_ERROR = int(Header.TASKS_IN_ERROR)
_TASKS_NOT_FRESH = int(Header.TASKS_NOT_FRESH)
# An activation comes back from the header's nanoseconds, a boundary is epoch + k x period in
# floating point near 1e5 s of CLOCK_MONOTONIC: the two agree to a few nanoseconds, not exactly.
# Within this, a time is on the boundary (without it, half the plans put their entering tasks'
# first release one period after the activation).
ON_THE_BOUNDARY = 1e-6
OVERRUNS_KEPT = 8  # the last overruns kept per task (release, lateness, execution time) for the run report


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep_until(self, deadline: float) -> float: ...  # returns the reading that ended the wait


class SignalSource(Protocol):
    def receive(self, timeout: float | None) -> list[Any] | None: ...


class Barrier(Protocol):
    def wait(self) -> bool: ...
    def done(self) -> None: ...


class Scheduled:
    """A task's place in the executive: its next release and its timing record."""

    __slots__ = ("task", "period", "critical", "priority", "release", "release_index", "overruns", "missed", "jitter", "exec_time",
                 "samples", "jitter_max", "exec_max", "status", "aperiodic", "events", "dropped_events",
                 "last_release", "stale_reads", "stale_at_switch", "input_periods", "write_times", "stable_cycles",
                 "held_for", "first_cycle_of_plan", "last_stale", "expected_writers", "input_writers",
                 "lost_to_switch", "last_lost", "window_lost", "window_stale", "shared_status", "overrun_log",
                 "long_cycles", "fresh_bounds", "fresh_within", "writer_names", "expired_reads",
                 "fresh_since", "lock_waits_given_up")

    def __init__(self, task: Task) -> None:
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
        # Written now, not zeroed lazily: a lazily zeroed page is faulted in at its first write,
        # which was every 512 cycles on the per-cycle path (4 page faults a second at 1 kHz).
        self.jitter = np.full(RING, 0.0)
        self.exec_time = np.full(RING, 0.0)
        self.samples = 0
        self.jitter_max = 0.0
        self.exec_max = 0.0
        self.status = task.status
        self.shared_status = task.local.table.status[task.index]  # the table's own words, for what no cycle carries
        self.events: collections.deque[Any] = collections.deque(maxlen=EVENTS_QUEUED)
        self.dropped_events = 0
        self.stale_reads = 0
        self.stale_at_switch = 0
        self.last_stale = ""
        self.input_periods = [math.inf] * len(task.local.input_variables)  # producer periods, per in-var
        self.expected_writers = [-1] * len(task.local.input_variables)  # the configuration's writer, per in-var
        self.write_times = task.local.input_write_times  # gathered with the inputs: each writer's last release
        self.input_writers = task.local.input_writer  # gathered with the inputs: who wrote what was read
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
        pct = (lambda a, q: float(np.percentile(a, q)) if n else 0.0)
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


class LiveStage(Protocol):
    """A live description an RTPU read (`LiveUpdate`), staged until the next plan applies it."""

    reconfiguration: Reconfiguration
    tasks: dict[str, tuple[int, Any]]  # every task of the live description: (status block, params)
    spec: Callable[[str], Any]  # a task's full TaskSpec (its module looked up: only for a task hosted here)
    factories: dict[str, Callable[[], Task]]  # this RTPU's tasks, each made afresh from its live spec


class Executive:
    """Runs the tasks of one RTPU. `handle` deals with one signal; `run_once` is one wait + cycles."""

    def __init__(self, clock: Clock, signals: SignalSource, report: Callable[[Event], None], epoch: float = 0.0,
                 header: np.ndarray | None = None, reconfiguration: Reconfiguration | None = None,
                 rtpu_index: int = 0, n_rtpus: int = 1, report_at_stop: Callable[[Event], None] | None = None,
                 live_loader: Callable[[int], LiveStage] | None = None,
                 cycle_lock_wait: list[float | None] | None = None) -> None:
        self.clock = clock
        # The table's bound on a per-cycle transfer's wait for the lock (`StateTable.cycle_lock_wait`),
        # set when a critical task turns on; None on the simulated clock, whose turns never contend.
        self.cycle_lock_wait = cycle_lock_wait
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
        self.running = True
        self.idle_wait = 0.05
        # a task's drivers' own figures (a special-purpose processor's timing), reported with its statistics
        self.device_figures: Callable[[str], dict[str, Any]] = lambda task: {}
        self.header = header  # the table's int64 header: plans, switching words, error count
        self.header_words = memoryview(header) if header is not None else None  # the same words, read as ints
        self.reconfiguration = reconfiguration
        self.rtpu_index = rtpu_index
        self.switching_words = range(int(Header.SWITCHING_SINCE_NS), int(Header.SWITCHING_SINCE_NS) + n_rtpus)
        self.plan_seen = int(header[Header.PLAN_SEQUENCE]) if header is not None else 0
        # When this RTPU first read the pending plan (off the per-cycle path: only while one is
        # pending): job control sizes the plan's lead from how long RTPUs take to read a plan.
        self.plan_read = self.plan_seen
        self.plan_read_at = 0.0
        # A switch's reports (its windows, the tasks' new states, Switched) wait until the
        # boundary's cycles ran: each is a message, and the entering tasks' first cycle comes first.
        self.held_reports: list[Event] = []
        self.configuration = -1  # index of the configuration last applied here
        self.last_switch = -math.inf  # activation time of the last plan applied
        self.release_slack = getattr(clock, "release_slack", 0.0)  # sim clock: a release a few ulps late is due
        self.spin = getattr(clock, "spin", 0.0)  # real clock: the wait on signals ends this long before a release
        # Live changes (`pbo spawn/kill/replace/set`): a LiveUpdate stages the run's new description,
        # and the next plan swaps it in at its cycle boundary (`apply_plan`), tunes included.
        self.live_loader = live_loader
        self.staged: LiveStage | None = None
        self.staged_tunes: dict[str, Any] = {}  # hosted task -> (its new spec, its Params), when its parameters changed
        # What a task's off or kill hands off (a log's last chunk and footer): done by a thread of
        # lower priority, never between two cycles; waited for at the stop (`stop`).
        background.process_background().start()
        self.cycles_between_steps = False  # `run` (the real clock): due cycles run between the steps of a spawn

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
        signals = self.signals
        # A queue says whether a signal waits in one cheap system call; a receive that finds none
        # costs ten times as much (an exception), and most ticks bring no signal.
        pending: Callable[[], bool] = getattr(signals, "pending", lambda: True)
        while self.running:
            new_tick = barrier.wait()
            try:
                raise_if_stopping()  # a stop that came while this process was not waiting (`stop_only_at_waits`)
                while self.running and pending():
                    message = signals.receive(0)
                    if message is None:
                        break
                    self.handle(message)
                if new_tick and self.running:
                    self._plan_if_due()
                    self._run_ready()
                    self._send_held_reports()
            finally:
                barrier.done()

    def _plan_if_due(self) -> bool:
        """Read a newly posted plan; apply it if its boundary has come. True if it was applied."""
        words = self.header_words
        if words is not None and words[_PLAN_SEQUENCE] != self.plan_seen:
            now = self.clock.now()
            self._read_plan(words[_PLAN_SEQUENCE], now)
            if now + self.release_slack + ON_THE_BOUNDARY >= words[_PLAN_TIME_NS] / 1e9:
                self.apply_plan()
                return True
        return False

    def _read_plan(self, sequence: int, now: float) -> None:
        """Stamp the first time this RTPU saw plan `sequence` (reported with its `Switched`)."""
        if sequence != self.plan_read:
            self.plan_read = sequence
            self.plan_read_at = now

    def run_once(self) -> None:
        clock = self.clock
        next_release = math.inf
        for s in self.on:
            if s.release < next_release:
                next_release = s.release
        now = clock.now()
        words = self.header_words
        if words is not None and words[_PLAN_SEQUENCE] != self.plan_seen:
            self._read_plan(words[_PLAN_SEQUENCE], now)
            activation = words[_PLAN_TIME_NS] / 1e9
            if now + self.release_slack + ON_THE_BOUNDARY >= activation:
                self.apply_plan()  # late (this RTPU read the plan after its activation): before any cycle
                self._run_ready()
                self._send_held_reports()
                return
            if activation < next_release:
                next_release = activation
        if next_release == math.inf:
            wait = self.idle_wait
        else:
            wait = next_release - now
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
        if words is not None and words[_PLAN_SEQUENCE] != self.plan_seen:
            # A plan posted while this RTPU waited, due by this boundary: applied before the
            # boundary's cycles, never after them. The RTPU that hosts the entering tasks has a
            # boundary at the activation, so it needs no wake-up to switch on time; an RTPU that
            # read the plan too late for its activation applies it here, at its first boundary
            # after it, before anything runs in the old configuration.
            self._read_plan(words[_PLAN_SEQUENCE], woke)
            if woke + self.release_slack + ON_THE_BOUNDARY >= words[_PLAN_TIME_NS] / 1e9:
                self.apply_plan()
                self._run_ready()
                self._send_held_reports()
                return
        self._run_ready(woke)

    def _run_ready(self, first_now: float | None = None) -> None:
        """Run every released task once, most urgent first (maximum-urgency-first); no allocation.

        Urgency: critical before not; then the earlier deadline (release + period); then the
        higher user priority. `first_now`: the time the wait ended (`Clock.sleep_until`), so the
        first cycle's jitter is timed where a bare loop times it; later picks read the clock.
        """
        clock = self.clock
        on = self.on
        slack = self.release_slack
        now = clock.now() if first_now is None else first_now
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
            now = clock.now()

    def _cycle(self, s: Scheduled, start: float) -> None:
        release = s.release
        status = s.status
        task = s.task
        jitter = start - release
        if jitter < 0.0:
            jitter = 0.0  # simulated clock: a release a few ulps past its tick
        status[W.JITTER_LAST] = jitter
        if jitter > s.jitter_max:
            s.jitter_max = jitter
            status[W.JITTER_MAX] = jitter
        if s.aperiodic:
            task.context.event = s.events.popleft() if s.events else None
        held = NOT_HELD
        expired = -1
        if s.critical:
            # first: whether the cycle may use them depends on how old they are
            if not task.read_inputs():
                held = HELD_LOCKED  # its stable behaviour does without them (the last ones read stay)
                s.lock_waits_given_up += 1
            else:
                expired = self._check_freshness(s, release)
                if self._configuration_illegal(start, s.period):
                    held = HELD_ILLEGAL  # (a stale input then is the switch's doing, not a fault)
                elif expired >= 0:
                    held = HELD_STALE_INPUT
                    s.expired_reads += 1
                elif self._upstream_not_fresh():
                    held = HELD_UPSTREAM
            if held:
                result = task.run_read_stable_cycle(release)
            else:
                result = task.run_read_cycle(release)
        elif task.read_inputs():
            result = task.run_read_cycle(release)
        else:  # the lock stayed held past the wait: this release is lost, the RTPU's critical cycles are not
            s.lock_waits_given_up += 1
            s.missed += 1
            s.shared_status[W.MISSED] = s.missed
            result = Status.CONTINUE
        if result is Status.STABLE:
            held = held or HELD_BY_MODULE
            result = Status.CONTINUE
        if held:
            s.stable_cycles += 1
            if held != s.held_for:  # an episode begins, or goes on for another reason: a new episode says why
                if s.held_for:
                    self.report(Stable(task.name, False, start))
                s.held_for = held
                self._report_stable(s, held, start, expired, release)
        elif s.held_for and result == Status.CONTINUE:
            s.held_for = NOT_HELD
            self.report(Stable(task.name, False, start))
        end = self.clock.now()
        took = end - start
        k = s.samples & (RING - 1)
        s.jitter[k] = jitter
        s.exec_time[k] = took
        s.samples += 1
        if not s.samples & (RECENT - 1):
            self._publish_recent(s)
        status[W.EXEC_LAST] = took
        if took > s.exec_max:
            s.exec_max = took
            status[W.EXEC_MAX] = took
        if s.first_cycle_of_plan:
            self.report(FirstCycle(s.first_cycle_of_plan, task.name, start))
            s.first_cycle_of_plan = 0
        s.last_release = release
        if s.aperiodic:
            s.release = max(release + s.period, end) if s.events else math.inf
        else:
            s.release_index += 1
            following = self.epoch + s.release_index * s.period
            if end > following:
                # The deadline passed: count the overrun and skip the releases already gone,
                # keeping the phase (next = epoch + k * period, never end + period).
                # Record why (the flat ring's slots are floats already there: nothing is allocated).
                k = 3 * (s.overruns % OVERRUNS_KEPT)
                log = s.overrun_log
                log[k] = release
                log[k + 1] = jitter
                log[k + 2] = took
                if took > s.period:
                    s.long_cycles += 1
                s.overruns += 1
                skipped = int((end - release) // s.period)
                s.missed += skipped - 1 if skipped > 1 else 0
                status[W.OVERRUNS] = s.overruns
                s.shared_status[W.MISSED] = s.missed  # straight into the table: not one of the words a cycle carries
                s.release_index += skipped - 1
                following = self.epoch + s.release_index * s.period
                if following <= end:
                    s.release_index += 1
                    following = self.epoch + s.release_index * s.period
            s.release = following
        if result != Status.CONTINUE:
            self._leave_on(s)
            self._report_state(task)

    @staticmethod
    def _publish_recent(s: Scheduled) -> None:
        """Percentiles of the last RECENT cycles into the table, once per RECENT cycles (~1 s at 1 kHz)."""
        start = (s.samples - RECENT) & (RING - 1)
        jitter = np.partition(s.jitter[start:start + RECENT], (RECENT // 2, RECENT * 99 // 100))
        exec_time = np.partition(s.exec_time[start:start + RECENT], (RECENT // 2, RECENT * 99 // 100))
        shared = s.shared_status
        shared[W.JITTER_P50] = jitter[RECENT // 2]
        shared[W.JITTER_P99] = jitter[RECENT * 99 // 100]
        shared[W.EXEC_P50] = exec_time[RECENT // 2]
        shared[W.EXEC_P99] = exec_time[RECENT * 99 // 100]

    def _check_freshness(self, s: Scheduled, release: float) -> int:
        """Classify each input the critical task just read; the first past its bound, or -1 (no allocation).

        - past its freshness bound: the cycle must not use it (the caller runs `stable_cycle`);
        - lost to a switch: the value still comes from a task the configuration no longer has
          writing it (the switch cost the consumer a fresh input);
        - stale: the configuration's writer wrote it, but more than one of its periods ago (the
          writer ran late: timing, not reconfiguration). A writer that never ran yet is skipped.
        """
        times = s.write_times
        periods = s.input_periods
        bounds = s.fresh_bounds
        writers = s.input_writers
        expected = s.expected_writers
        since = s.fresh_since
        counted = False
        for i in range(len(periods)):
            wanted = expected[i]
            if wanted < 0:
                continue
            written_at = times[i]
            if release - (written_at if written_at > since else since) > bounds[i]:
                return i
            if counted:
                continue
            written_by = writers[i]
            if written_by != wanted and written_by >= 0:
                s.lost_to_switch += 1
                s.last_lost = (f"{s.task.local.input_variables[i]} at {release:.6f}: still written by task "
                               f"#{int(written_by)}, expected #{wanted}")
                counted = True
            elif written_at > 0.0 and release - written_at > periods[i] + AGE_TOLERANCE:
                s.stale_reads += 1
                if release - self.last_switch < SWITCH_WINDOW_PERIODS * s.period:
                    s.stale_at_switch += 1
                s.last_stale = f"{s.task.local.input_variables[i]} at {release:.6f}: age {(release - written_at) * 1e3:.3f} ms"
                counted = True
        return -1

    def _report_stable(self, s: Scheduled, held: int, start: float, expired: int, release: float) -> None:
        """A critical task's stable episode begins, `held` for one of the HELD_ reasons: say why
        (off the usual path: once per episode)."""
        if held == HELD_STALE_INPUT:
            variable = s.task.local.input_variables[expired]
            age = release - max(float(s.write_times[expired]), s.fresh_since)
            writer = s.writer_names[expired] or "its writer"
            reason = (f"in-var '{variable}' is {age * 1e3:.1f} ms old, past its freshness bound of "
                      f"{s.fresh_bounds[expired] * 1e3:.3g} ms ('{writer}' stopped writing it)")
            cause = "stale"
        elif held == HELD_BY_MODULE:
            reason, cause = "the module's own inputs are not fresh (its cycle returned STABLE)", "module"
        elif held == HELD_LOCKED:
            reason, cause = (f"the table lock was held past its wait of {self.cycle_lock_wait[0] * 1e3:.3g} ms "
                             "(its holder died holding it, or stalled)"), "lock"
        elif held == HELD_UPSTREAM:
            reason, cause = ("a task upstream has no fresh input (its cycle returned STABLE: a link's item or a topic's "
                             "message past its bound)"), "upstream"
        else:
            reason, cause = "the configuration is illegal (a task in ERROR, or a switch that overran a cycle)", "illegal"
        self.report(Stable(s.task.name, True, start, reason, cause))

    def _upstream_not_fresh(self) -> bool:
        """True while job control counts a task of the configuration whose cycle says its inputs are not fresh."""
        words = self.header_words
        return words is not None and words[_TASKS_NOT_FRESH] > 0

    def _configuration_illegal(self, now: float, period: float) -> bool:
        """True while a task of the configuration is in ERROR or a switch has overrun a cycle."""
        words = self.header_words  # (plain ints: no numpy scalar per read, on every critical cycle)
        if words is None:
            return False
        if words[_TASKS_IN_ERROR] > 0 or words[_FLAGS] & _STATIC_SWITCH:
            return True
        limit = (now - period) * 1e9
        for word in self.switching_words:
            since = words[word]
            if since and since < limit:
                return True
        return False

    # --- reconfiguration ----------------------------------------------------------------------

    def apply_plan(self) -> None:
        """Switch this RTPU's tasks to the planned configuration, at this cycle boundary."""
        header = self.header
        assert header is not None and self.reconfiguration is not None
        clock = self.clock
        applied_at = clock.now()
        header[self.switching_words[0] + self.rtpu_index] = int(applied_at * 1e9) or 1
        sequence = int(header[Header.PLAN_SEQUENCE])
        configuration = int(header[Header.PLAN_CONFIGURATION])
        activation = header[Header.PLAN_TIME_NS] / 1e9
        if self.staged is not None:  # a live change: its configurations and tunes, at this boundary
            self._swap_in(self.staged, self.staged_tunes)
            self.staged, self.staged_tunes = None, {}
        view = self.reconfiguration.views[configuration]
        held = self.held_reports.append
        self.report_windows(sequence, held)
        leaving = [s for s in self.on if s.task.name not in view.members]
        entering = [s for s in self.tasks.values() if s.task.name in view.members and s.task.state == TaskState.OFF]
        try:
            for s in leaving:
                self._leave_on(s)
                s.task.turn_off(clock.now())
            for s in sorted(entering, key=lambda s: not s.critical):
                self._turn_on(s, activation, plan=sequence)
            for s in self.on:
                if s.critical:
                    self._watch(s, configuration, activation)
        finally:
            header[self.switching_words[0] + self.rtpu_index] = 0
        self.plan_seen = sequence
        self.configuration = configuration
        self.last_switch = activation
        done_at = clock.now()
        for s in (*leaving, *entering):
            self._report_state(s.task, held)
        read_at = self.plan_read_at if self.plan_read == sequence else applied_at
        held(Switched(sequence, view.name, activation, applied_at, done_at,
                      [s.task.name for s in leaving], [s.task.name for s in entering], read_at))

    def _send_held_reports(self) -> None:
        """Send what a switch held back until its boundary's cycles ran (`apply_plan`)."""
        if self.held_reports:
            for event in self.held_reports:
                self.report(event)
            self.held_reports.clear()

    def _swap_in(self, stage: LiveStage, tunes: dict[str, Any]) -> None:
        """The staged live description becomes this RTPU's: who is in which configuration, who writes
        what; tasks whose tunable parameters changed take them now, between two cycles."""
        self.reconfiguration = stage.reconfiguration
        for name, (spec, params) in tunes.items():
            try:
                self.tasks[name].task.tune(spec, params)
            except Exception as exc:  # noqa: BLE001 - the checker passed the values: a module that refuses them says why
                self.report(Refused(name, f"tune: {exc}"))

    def report_windows(self, following: int = 0, send: Callable[[Event], None] | None = None) -> None:
        """Per switch: what each critical task read between that switch and the next (or the stop)."""
        send = send or self.report
        for s in self.tasks.values():
            if not s.critical:
                continue
            lost, stale = s.lost_to_switch - s.window_lost, s.stale_reads - s.window_stale
            s.window_lost, s.window_stale = s.lost_to_switch, s.stale_reads
            if self.plan_seen:
                send(Window(self.plan_seen, s.task.name, lost, stale))

    def _watch(self, s: Scheduled, configuration: int, since: float) -> None:
        """Point a critical task's freshness check at the writers of its inputs in `configuration`, on since `since`."""
        assert self.reconfiguration is not None
        variables = s.task.local.input_variables
        s.fresh_since = since
        writers = [self.reconfiguration.writer_of(configuration, v) for v in variables]
        s.task.local.watch_writers([w for w, _ in writers])
        for i, (writer, period) in enumerate(writers):
            s.input_periods[i] = period
            s.expected_writers[i] = writer
            s.fresh_bounds[i] = s.fresh_within.get(variables[i], FRESH_WITHIN_WRITER_PERIODS * period) + AGE_TOLERANCE
            s.writer_names[i] = self.reconfiguration.task_names.get(writer, "")

    def _turn_on(self, s: Scheduled, at: float, plan: int = 0) -> None:
        if s.aperiodic:  # released by its first event; messages that came while it was off are served now
            s.release = max(self.clock.now(), s.last_release + s.period) if s.events else math.inf
        else:
            s.release = self._first_release(s, at)
        if s.task.turn_on(self.clock.now()):
            self.on.append(s)
            s.first_cycle_of_plan = plan
            if s.critical and self.cycle_lock_wait is not None:
                wait = self.cycle_lock_wait
                wait[0] = min(wait[0] or math.inf, LOCK_WAIT_PERIODS * s.period)

    # --- signals ----------------------------------------------------------------------------

    def add(self, task: Task, factory: Callable[[], Task] | None = None) -> None:
        """Host a task; `factory` makes a fresh instance when a killed task is spawned again (static switches)."""
        self.tasks[task.name] = Scheduled(task)
        if factory is not None:
            self.factories[task.name] = factory

    def handle(self, message: list[Any]) -> None:
        """One signal as it came off the queue (`[kind, *fields]`, decoded by `messages.signal_from_wire`)."""
        self._report_background_failures()
        signal = messages.signal_from_wire(message)
        if isinstance(signal, messages.StopRtpu):
            self.stop()
            return
        if isinstance(signal, messages.SendStats):
            self.report_statistics()
            return
        if isinstance(signal, messages.PlanPosted):  # a wake-up: the plan itself is in the table's header
            return
        if isinstance(signal, messages.LiveUpdate):
            self._stage(signal.sequence)
            return
        name = signal.task if signal is not None else message[1]
        s = self.tasks.get(name)
        if s is None and isinstance(signal, messages.Spawn) and name in self.factories:  # spawned live
            with self._cycling_meanwhile():
                s = self.tasks[name] = self._make(name)
        if s is None:
            self.report(Refused(name, f"no task '{name}' on this RTPU"))
            return
        task = s.task
        op = message[0]
        try:
            if isinstance(signal, messages.Spawn):
                with self._cycling_meanwhile():  # an init's waits (a device starting) run the due cycles
                    if task.state == TaskState.KILLED and name in self.factories:
                        s = self.tasks[name] = self._make(name)  # a new instance: TR 4.4, static
                        task = s.task
                    task.spawn(self.clock.now())
                self._cycles_due()
                # What the process built up to here (imports, the task and its module) lives as
                # long as the task: freezing it keeps it out of every later collection, which then
                # walks only what the run allocates. A full collection of an RTPU process walks
                # some 30,000 objects in 4-5 ms, several overruns at 1 kHz if it came mid-run.
                gc.freeze()
            elif isinstance(signal, messages.TurnOn):
                if self.before_first_on is not None:
                    first, self.before_first_on = self.before_first_on, None
                    first()
                at = signal.at if signal.at is not None else self.clock.now()
                self._turn_on(s, at)
                if s.critical and self.reconfiguration is not None and signal.configuration is not None:
                    self._watch(s, int(signal.configuration), at)
            elif isinstance(signal, messages.Watch):
                if s.critical and self.reconfiguration is not None:
                    self._watch(s, int(signal.configuration), self.clock.now())
            elif isinstance(signal, messages.TurnOff):
                self._leave_on(s)
                task.turn_off(self.clock.now())
            elif isinstance(signal, messages.Kill):
                self._leave_on(s)
                task.kill(self.clock.now())
            elif isinstance(signal, messages.Clear):
                task.clear()
            elif isinstance(signal, messages.OperatorEvent):
                self._event(s, signal.values)
                return
            elif isinstance(signal, messages.LinkMessage):  # from a link's relay (TaskContext.serve_link): no reply to anyone
                self._event(s, signal.payload, quiet=True)
                return
            else:
                self.report(Refused(name, f"unknown signal '{op}'"))
                return
        except Exception as exc:  # a refused signal is job control's mistake, not a crash
            self.report(Refused(name, f"{op}: {exc}"))
            return
        self._report_state(task)

    def _make(self, name: str) -> Scheduled:
        """A new instance of task `name` (its module imported if it was not yet), and its place here.

        Each step may take a millisecond or more (an import, an init, the timing rings written):
        the cycles that came due meanwhile run between the steps (`_cycles_due`), not after them all."""
        task = self.factories[name]()
        self._cycles_due()
        made = Scheduled(task)
        self._cycles_due()
        return made

    def _cycles_due(self) -> None:
        """On the real clock, between two steps of a signal's slow work (a spawn): run the cycles
        released meanwhile, after a plan whose boundary came meanwhile, as the loop would. (The
        simulated clock runs cycles on its ticks only.)"""
        if not self.cycles_between_steps:
            return
        applied = self._plan_if_due()
        self._run_ready()
        if applied:
            self._send_held_reports()

    def _cycling_meanwhile(self) -> contextlib.AbstractContextManager[None]:
        """On the real clock, a spawn's waits (`waits.sleep_while_cycling`) run the cycles due
        meanwhile (`_sleep_cycling`); on the simulated clock they are plain waits (time stands still)."""
        return waits.cycles_meanwhile(self._sleep_cycling) if self.cycles_between_steps else contextlib.nullcontext()

    def _sleep_cycling(self, seconds: float) -> None:
        """Wait `seconds` and run each cycle that comes due meanwhile, at its release."""
        clock = self.clock
        end = clock.now() + seconds
        while True:
            self._cycles_due()
            if clock.now() >= end:
                return
            following = min((s.release for s in self.on), default=math.inf)
            clock.sleep_until(min(end, following))

    def _stage(self, sequence: int) -> None:
        """Read live description `sequence` and keep it for the next plan; its tasks on this RTPU can be spawned now."""
        try:
            if self.live_loader is None:
                raise RuntimeError("this RTPU was started without a live description")
            stage = self.live_loader(sequence)
            tunes = {}
            for name, s in self.tasks.items():
                index, params = stage.tasks.get(name, (-1, None))
                if index == s.task.index and params != s.task.spec.params and s.task.state != TaskState.KILLED:
                    spec = stage.spec(name)
                    tunes[name] = (spec, s.task.tune_params(spec))  # built now: the boundary only calls tune
        except Exception as exc:  # noqa: BLE001 - job control refuses the change and says why
            self.report(messages.Staged(sequence, f"{type(exc).__name__}: {exc}"))
            return
        self.staged, self.staged_tunes = stage, tunes
        self.factories.update(stage.factories)
        self.report(messages.Staged(sequence))

    def _event(self, s: Scheduled, payload: Any, quiet: bool = False) -> None:
        """An event for an aperiodic task: released now, or after its minimum inter-arrival time.

        `quiet`: a message from another subsystem (TR §5.1). While its server is not ON yet it
        waits in the server's queue (released when it turns on), since the other subsystem may
        start first; an operator's event is refused instead, for the operator to read.
        """
        if not s.aperiodic:
            self.report(Refused(s.task.name, "event: the task is periodic"))
            return
        on = s.task.state == TaskState.ON
        if not on and not quiet:
            self.report(Refused(s.task.name, f"event: the task is {s.task.state.name}, not ON"))
            return
        if len(s.events) == s.events.maxlen:
            s.dropped_events += 1
        s.events.append(payload)
        if on and s.release == math.inf:
            s.release = max(self.clock.now(), s.last_release + s.period)

    def stop(self) -> None:
        """Turn everything off and kill it (kill runs off first), then report statistics."""
        self.report = self.report_at_stop
        self._send_held_reports()
        self.report_windows()
        for s in list(self.tasks.values()):
            if s.task.state in (TaskState.ON, TaskState.OFF, TaskState.ERROR):
                self._leave_on(s)
                try:
                    s.task.kill(self.clock.now())
                except Exception as exc:
                    self.report(Refused(s.task.name, f"kill: {exc}"))
                self._report_state(s.task)
        self._report_background_failures(background.close_process_background())
        self.report_statistics()
        self.running = False

    def _report_background_failures(self, failures: list[background.Failure] | None = None) -> None:
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

    def _first_release(self, s: Scheduled, at: float) -> float:
        s.release_index = max(math.ceil((at - ON_THE_BOUNDARY - self.epoch) / s.period), 0)
        return self.epoch + s.release_index * s.period

    def _leave_on(self, s: Scheduled) -> None:
        if s in self.on:
            self.on.remove(s)

    def _report_state(self, task: Task, send: Callable[[Event], None] | None = None) -> None:
        (send or self.report)(StateChanged(task.name, task.state.name, task.last_error, task.output_failed))
