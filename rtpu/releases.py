"""When a task is released, and what each cycle's timing records.

The k-th release of a periodic task is epoch + k x period, counted, never summed, so the rate does
not drift and rounding does not pile up. A cycle that ends past its next release is an overrun:
the releases already gone are skipped, keeping the phase. Jitter and execution time go to the
table's status words and to preallocated rings, whose recent percentiles reach the table once
per RECENT cycles. Nothing on a cycle's path allocates.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import numpy as np

from pbo_runtime.table.table import StatusWord as W

if TYPE_CHECKING:
    from rtpu._executive import Scheduled

RING = 1 << 16  # timing samples kept per task for its percentiles
RING_STEP = 1 << 13  # samples of a ring written in one step (16 pages): well under a period
RECENT = 1 << 10  # every RECENT cycles, the last RECENT samples' percentiles go to the table for pbo status
OVERRUNS_KEPT = 8  # the last overruns kept per task (release, lateness, execution time) for the run report
# An activation comes back from the header's nanoseconds, a boundary is epoch + k x period in
# floating point near 1e5 s of CLOCK_MONOTONIC: the two agree to a few nanoseconds, not exactly.
# Within this, a time is on the boundary (without it, half the plans would put their entering
# tasks' first release one period after the activation).
ON_THE_BOUNDARY = 1e-6
# The status words a release writes, as plain ints: a numpy index of an IntEnum costs several
# times a plain int's, and the words are written through a memoryview (`Scheduled.status_words`)
_JITTER_LAST, _JITTER_MAX = int(W.JITTER_LAST), int(W.JITTER_MAX)
_EXEC_LAST, _EXEC_MAX = int(W.EXEC_LAST), int(W.EXEC_MAX)


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep_until(self, deadline: float) -> float: ...  # returns the reading that ended the wait


class Barrier(Protocol):
    """The simulated clock's turns (`clock.lockstep`): `wait` for a step (True: a new tick), `done` with it."""

    def wait(self) -> bool: ...
    def done(self) -> None: ...


def first_release(s: Scheduled, at: float, epoch: float) -> float:
    """The first release of periodic task `s` at or after `at`, on its grid of epoch + k x period."""
    s.release_index = max(math.ceil((at - ON_THE_BOUNDARY - epoch) / s.period), 0)
    return epoch + s.release_index * s.period


def record_jitter(s: Scheduled, jitter: float) -> float:
    """How late the cycle started after its release (never below zero) into the status words; returned."""
    if jitter < 0.0:
        jitter = 0.0  # simulated clock: a release a few ulps past its tick
    status = s.status_words
    status[_JITTER_LAST] = jitter
    if jitter > s.jitter_max:
        s.jitter_max = jitter
        status[_JITTER_MAX] = jitter
    return jitter


def close_cycle(s: Scheduled, release: float, jitter: float, start: float, end: float, epoch: float) -> float:
    """Record the timing of the cycle of `release` that ran from `start` to `end`; return the next release.

    A periodic task's next release is the first of its grid after `end`: past its deadline, the
    overrun is counted and the releases already gone are skipped, keeping the phase (next =
    epoch + k x period, never end + period). An aperiodic task is released again by its next
    queued event, after its minimum inter-arrival time.
    """
    took = end - start
    samples = s.samples
    k = samples & (RING - 1)
    s.jitter_ring[k] = jitter
    s.exec_ring[k] = took
    s.samples = samples = samples + 1
    if not samples & (RECENT - 1):
        publish_recent(s)
    status = s.status_words
    status[_EXEC_LAST] = took
    if took > s.exec_max:
        s.exec_max = took
        status[_EXEC_MAX] = took
    s.last_release = release
    if s.aperiodic:
        return max(release + s.period, end) if s.events else math.inf
    s.release_index += 1
    following = epoch + s.release_index * s.period
    if end > following:
        skipped = int((end - release) // s.period)
        record_overrun(s, release, jitter, took, skipped)
        s.release_index += skipped - 1
        following = epoch + s.release_index * s.period
        if following <= end:
            s.release_index += 1
            following = epoch + s.release_index * s.period
    return following


def publish_recent(s: Scheduled) -> None:
    """Percentiles of the last RECENT cycles into the table (once per RECENT cycles: off the usual path)."""
    start = (s.samples - RECENT) & (RING - 1)
    jitter = np.partition(s.jitter[start:start + RECENT], (RECENT // 2, RECENT * 99 // 100))
    exec_time = np.partition(s.exec_time[start:start + RECENT], (RECENT // 2, RECENT * 99 // 100))
    shared = s.shared_status
    shared[W.JITTER_P50] = jitter[RECENT // 2]
    shared[W.JITTER_P99] = jitter[RECENT * 99 // 100]
    shared[W.EXEC_P50] = exec_time[RECENT // 2]
    shared[W.EXEC_P99] = exec_time[RECENT * 99 // 100]


def record_overrun(s: Scheduled, release: float, jitter: float, took: float, skipped: int) -> None:
    """Count an overrun and keep why in the flat ring (its slots are floats already there: nothing is allocated)."""
    k = 3 * (s.overruns % OVERRUNS_KEPT)
    log = s.overrun_log
    log[k] = release
    log[k + 1] = jitter
    log[k + 2] = took
    if took > s.period:
        s.long_cycles += 1
    s.overruns += 1
    s.missed += skipped - 1 if skipped > 1 else 0
    s.status[W.OVERRUNS] = s.overruns
    s.shared_status[W.MISSED] = s.missed  # straight into the table: not one of the words a cycle carries


def written_ring(between: Callable[[], None] | None = None) -> np.ndarray:
    """A timing ring of RING zeros, every page written now: a page faulted in at its first write
    would be on the per-cycle path. `between` runs after each RING_STEP samples (a live spawn
    runs the RTPU's due cycles there)."""
    ring = np.empty(RING)
    for start in range(0, RING, RING_STEP):
        ring[start:start + RING_STEP] = 0.0
        if between is not None:
            between()
    return ring
