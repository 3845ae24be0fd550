"""Clocks the executive reads time through, so a simulated clock can drive it (STYLE §13).

Times are float seconds on CLOCK_MONOTONIC, which every process of the machine shares, so
RTPUs can agree on release instants without talking. `sleep_until` returns the time it saw when
the wait ended: the executive times the release from that reading, not from a later one.
"""

from __future__ import annotations

import ctypes
import time

import numpy as np

from pbo_runtime.table.table import Header


def release_stagger(shortest_period: float, n_rtpus: int) -> float:
    """The offset between consecutive RTPUs' releases on the real clock: the period spaced evenly.

    RTPU i releases at epoch + i x stagger + k x period. Even spacing keeps any two RTPUs'
    releases as far apart as the period allows, so their spins before a release, their cycles
    and their lock holds overlap least. With 4 RTPUs on 2 CPUs at 1 kHz, spreading them over
    0.45 of the period (until issue 6) made the spins collide: release jitter p99 about 180 µs,
    against about 30 µs evenly spaced (bench/realtime). A task that reads what the RTPU before
    it wrote in the same period gives the writer 1/n of the period to finish.
    """
    return shortest_period / n_rtpus if n_rtpus > 1 else 0.0


class RealClock:
    """Wall time: sleep in the kernel until `spin` before a deadline, then spin to it."""

    def __init__(self, spin: float = 0.0002) -> None:
        self.spin = spin
        self.now = time.monotonic

    def sleep_until(self, deadline: float) -> float:
        """Wait until `deadline`; return the reading that ended the spin (the first at or past it).

        Returning that reading lets the caller time the release at the instant the wait saw it,
        as a bare loop does, instead of at a second reading taken after its own Python work.
        """
        now = self.now
        remaining = deadline - now() - self.spin
        if remaining > 0:
            time.sleep(remaining)
        seen = now()
        while seen < deadline:
            seen = now()
        return seen


class ManualClock:
    """A clock that moves only when told: for unit tests of the executive (no sleeping)."""

    def __init__(self, start: float = 0.0) -> None:
        self.time = start

    def now(self) -> float:
        return self.time

    def advance(self, seconds: float) -> None:
        self.time += seconds

    def sleep_until(self, deadline: float) -> float:
        if deadline > self.time:
            self.time = deadline
        return self.time


class SimClock:
    """Simulated time (`--clock sim`): the tick the supervisor released, read from the table's header.

    It never sleeps: the lockstep barrier (`clock.lockstep`) decides when time moves. `release_slack`
    lets a release computed by adding periods in floating point (k x 1 ms may come out a few
    ulps past the tick) still count as due at its tick. Time stands still within a participant's
    turn (`stands_still_within_a_turn`): the executive reads it once a turn.
    """

    stands_still_within_a_turn = True

    def __init__(self, header: np.ndarray, tick: float) -> None:
        self.header = header
        self._words = header.data  # the header's words as plain ints: no numpy scalar per read
        self._time_word = int(Header.SIM_TIME_NS)
        self.release_slack = tick * 1e-3

    def now(self) -> float:
        return self._words[self._time_word] / 1e9

    def sleep_until(self, deadline: float) -> float:
        return self.now()  # never waits: the lockstep barrier moves time


def lower_timer_slack(nanoseconds: int = 1) -> bool:
    """Ask Linux for a tighter wake-up (default slack 50 µs makes every wake late). True if done."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_TIMERSLACK = 29
        done: int = libc.prctl(PR_SET_TIMERSLACK, nanoseconds, 0, 0, 0)
        return done == 0
    except (OSError, AttributeError):
        return False


def process_started() -> float:
    """The CLOCK_MONOTONIC second this process started (its fork), to the kernel's clock tick (10 ms).

    /proc/self/stat's start time counts clock ticks since boot, on CLOCK_BOOTTIME; the two clocks
    differ only by the time the machine slept. 0.0 where /proc cannot tell.
    """
    import os

    try:
        with open("/proc/self/stat", encoding="ascii") as stream:
            fields = stream.read().rpartition(")")[2].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")  # field 22 of stat(5); the name ends at ")"
        return time.monotonic() - (time.clock_gettime(time.CLOCK_BOOTTIME) - started)
    except (OSError, ValueError, IndexError, AttributeError):
        return 0.0
