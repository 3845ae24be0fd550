"""Holds: when a critical task runs its locally stable behaviour instead of its cycle, and why.

A critical task reads its inputs before it runs. It is held while the configuration is illegal
(a switch that overran a cycle, or a task of the configuration in ERROR), while an input is older
than its freshness bound (its writer stalled: by default two of the writer's periods,
`fresh_within` in YAML), while a task upstream says its own inputs are not fresh, while the table
lock stays held past its wait, or when the module itself returns `Status.STABLE`; it resumes by
itself once they are fresh again. Each episode is reported once, with its reason. Reads older
than one writer period are counted as stale (timing, not yet a fault), and reads of a value a
task that left the configuration wrote as lost to the switch.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from pbo_runtime.ipc.messages import Event, Stable
from pbo_runtime.objects.module import Status
from pbo_runtime.supervisor.reconfiguration import Reconfiguration
from pbo_runtime.table.table import Flag, Header
from pbo_runtime.table.table import StatusWord as W

if TYPE_CHECKING:
    from rtpu._executive import Scheduled

# Why a critical task runs its locally stable behaviour (the cycle's `held`)
NOT_HELD, HELD_ILLEGAL, HELD_STALE_INPUT, HELD_BY_MODULE, HELD_UPSTREAM, HELD_LOCKED = 0, 1, 2, 3, 4, 5
SWITCH_WINDOW_PERIODS = 3  # a stale read this close after a switch is counted against the switch
AGE_TOLERANCE = 1e-7  # seconds: an input exactly one producer period old is fresh, whatever the rounding
# The default freshness bound of a critical task's input, in periods of its writer: one missed
# write is tolerated, a second one means the writer stalled.
FRESH_WITHIN_WRITER_PERIODS = 2.0
# On the real clock, a per-cycle transfer on an RTPU hosting a critical task waits for the table
# lock at most this share of the shortest critical period there: the lock is held only for a
# transfer, so a wait this long means its holder died holding it (until job control releases it)
# or stalled. Read and write together then leave the cycle three quarters of its period.
LOCK_WAIT_PERIODS = 0.125
# Header words read on every critical cycle, as plain ints (through a memoryview: no numpy scalar each time)
_FLAGS, _STATIC_SWITCH = int(Header.FLAGS), int(Flag.STATIC_SWITCH)
_TASKS_IN_ERROR = int(Header.TASKS_IN_ERROR)
_TASKS_NOT_FRESH = int(Header.TASKS_NOT_FRESH)


class Holds:
    """The hold policy of one executive's critical tasks, read from the table's header words."""

    def __init__(self, header_words: memoryview | None, switching_words: range, cycle_lock_wait: list[float | None] | None,
                 report: Callable[[Event], None]) -> None:
        self.words = header_words
        self.switching_words = switching_words  # per RTPU: when it began applying a plan (ns), 0 when done
        self.cycle_lock_wait = cycle_lock_wait  # the table's bound on a transfer's wait for the lock (None: sim clock)
        self.report = report
        self.last_switch = -math.inf  # activation time of the last plan applied here
        self.expired = -1  # the input past its bound in the last hold for a stale input

    def before_cycle(self, s: Scheduled, release: float, start: float) -> int:
        """Read a critical task's inputs and decide whether its cycle may use them: a HELD_ reason, or NOT_HELD."""
        if not s.task.read_inputs():
            s.lock_waits_given_up += 1
            return HELD_LOCKED  # its stable behaviour does without them (the last ones read stay)
        expired = self.expired = self.check_freshness(s, release)
        words = self.words  # (plain ints: no numpy scalar per read, on every critical cycle)
        if words is not None:
            # Illegal while a task of the configuration is in ERROR or a switch overran a cycle
            # (a stale input then is the switch's doing, not a fault)
            if words[_TASKS_IN_ERROR] > 0 or words[_FLAGS] & _STATIC_SWITCH:
                return HELD_ILLEGAL
            limit = (start - s.period) * 1e9
            for word in self.switching_words:
                since = words[word]
                if since and since < limit:
                    return HELD_ILLEGAL
        if expired >= 0:
            s.expired_reads += 1
            return HELD_STALE_INPUT
        if words is not None and words[_TASKS_NOT_FRESH] > 0:  # job control counts a task upstream not fresh
            return HELD_UPSTREAM
        return NOT_HELD

    def after_cycle(self, s: Scheduled, held: int, result: Status, start: float, release: float) -> None:
        """Follow the task's stable episodes: each begins, changes reason or ends with one report."""
        if held:
            s.stable_cycles += 1
            if held != s.held_for:  # an episode begins, or goes on for another reason: a new episode says why
                if s.held_for:
                    self.report(Stable(s.task.name, False, start))
                s.held_for = held
                self.report_stable(s, held, start, release)
        elif result == Status.CONTINUE:
            s.held_for = NOT_HELD
            self.report(Stable(s.task.name, False, start))

    def check_freshness(self, s: Scheduled, release: float) -> int:
        """Classify each input the critical task just read; the first past its bound, or -1 (no allocation).

        - past its freshness bound: the cycle must not use it (the task is held);
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

    def report_stable(self, s: Scheduled, held: int, start: float, release: float) -> None:
        """A stable episode begins, `held` for one of the HELD_ reasons: say why (once per episode)."""
        if held == HELD_STALE_INPUT:
            expired = self.expired
            variable = s.task.local.input_variables[expired]
            age = release - max(float(s.write_times[expired]), s.fresh_since)
            writer = s.writer_names[expired] or "its writer"
            reason = (f"in-var '{variable}' is {age * 1e3:.1f} ms old, past its freshness bound of "
                      f"{s.fresh_bounds[expired] * 1e3:.3g} ms ('{writer}' stopped writing it)")
            cause = "stale"
        elif held == HELD_BY_MODULE:
            reason, cause = "the module's own inputs are not fresh (its cycle returned STABLE)", "module"
        elif held == HELD_LOCKED:
            wait = self.cycle_lock_wait[0] if self.cycle_lock_wait else None
            reason, cause = (f"the table lock was held past its wait of {(wait or 0.0) * 1e3:.3g} ms "
                             "(its holder died holding it, or stalled)"), "lock"
        elif held == HELD_UPSTREAM:
            reason, cause = ("a task upstream has no fresh input (its cycle returned STABLE: a link's item or a topic's "
                             "message past its bound)"), "upstream"
        else:
            reason, cause = "the configuration is illegal (a task in ERROR, or a switch that overran a cycle)", "illegal"
        self.report(Stable(s.task.name, True, start, reason, cause))

    def bound_lock_wait(self, period: float) -> None:
        """A critical task of `period` turned on: the table's transfers here wait for the lock no longer than its share."""
        wait = self.cycle_lock_wait
        if wait is not None:
            wait[0] = min(wait[0] or math.inf, LOCK_WAIT_PERIODS * period)


def watch_inputs(s: Scheduled, reconfiguration: Reconfiguration, configuration: int, since: float) -> None:
    """Point a critical task's freshness check at the writers of its inputs in `configuration`, from `since` on."""
    watch_writers(s, writers_to_watch(s, reconfiguration, configuration), since)


@dataclasses.dataclass(frozen=True, slots=True)
class WatchedWriters:
    """What a critical task's freshness check follows in one configuration, per in-var (`writers_to_watch`)."""

    writers: list[int]  # the configuration's writer (task index; -1: none)
    periods: list[float]  # its period
    bounds: list[float]  # the input's freshness bound
    names: list[str]  # the writer's name, for a report


def writers_to_watch(s: Scheduled, reconfiguration: Reconfiguration, configuration: int) -> WatchedWriters:
    """The writers of critical task `s`'s inputs in `configuration`, looked up ahead of the boundary that
    makes them the ones watched (`watch_writers`)."""
    variables = s.task.local.input_variables
    writers = [reconfiguration.writer_of(configuration, v) for v in variables]
    periods = [period for _, period in writers]
    return WatchedWriters(
        [writer for writer, _ in writers], periods,
        [s.fresh_within.get(v, FRESH_WITHIN_WRITER_PERIODS * p) + AGE_TOLERANCE for v, p in zip(variables, periods, strict=True)],
        [reconfiguration.task_names.get(writer, "") for writer, _ in writers])


def watch_writers(s: Scheduled, watched: WatchedWriters, since: float) -> None:
    """Point a critical task's freshness check at `watched`, from `since` on: stores into its lists, no lookup."""
    s.fresh_since = since
    s.task.local.watch_writers(watched.writers)
    s.input_periods[:] = watched.periods
    s.expected_writers[:] = watched.writers
    s.fresh_bounds[:] = watched.bounds
    s.writer_names[:] = watched.names


def release_lost_to_the_lock(s: Scheduled) -> Status:
    """A task that is not critical found the table lock held past its wait: this release is lost, not held."""
    s.lock_waits_given_up += 1
    s.missed += 1
    s.shared_status[W.MISSED] = s.missed
    return Status.CONTINUE
