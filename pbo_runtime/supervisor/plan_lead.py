"""The plan's lead: how far ahead of its posting a switch plan activates, sized from measured delays.

Job control posts a plan in the table's header and wakes the RTPUs; each must have it by its own
deadline, the first release at or after the activation of a task ON there or entering (its
boundary), for all of them to switch at that one instant. An RTPU whose own timer wakes it then
reads the header before that boundary's cycles: it needs only the plan written by then, and the
time from the last clock reading before the plan's words to the words in the header (the post
delay; job control counts the activation again from that reading) is measured on every plan. One
that only the plan's wake-up brings (its next release is later, or an aperiodic task may run at
any time) needs the plan read by then. How long that takes is measured on every plan too: each
RTPU stamps when it first read the plan (`Switched.read_at`), and the plan's read delay is its
slowest RTPU's stamp minus the clock reading job control took the lead from. The lead is a high
quantile of the recent read delays plus a margin, within bounds:

    lead = clamp(MARGIN_FACTOR x q + MARGIN, LEAD_MIN, LEAD_MAX)

where q is the ceil(n / 100)-th largest of the last WINDOW delays (their p99 or above; the maximum
while fewer than 100 are known). Until FIRST_SAMPLES plans were read the lead is LEAD_MAX, the fixed
lead it replaces (the post delays: job control times the plan's words written as they are before a
run's first plan, so only the read delays start there). A plan an RTPU read too late for its
activation is still safe (that RTPU applies it at its first cycle boundary after, before anything
of it runs in the old configuration:
docs/reconfiguration.md); its delay enters the window like any other, and raises the next leads
as soon as more than one plan in a hundred was that slow (at once, under 100 plans). The post
delays make a second estimate the same way, bounded below by POST_LEAD_MIN; the activation is the
first boundary of the grid every RTPU meets with the estimate it needs (`earliest_activation`).
"""

from __future__ import annotations

import bisect
import collections
import math
from dataclasses import dataclass

LEAD_MIN = 0.0002  # seconds: below this a preempted supervisor or RTPU would miss it too often
LEAD_MAX = 0.002  # seconds: the fixed lead this estimate replaces, and its bound
MARGIN = 0.0001  # seconds added to the quantile: a wake-up's tail beyond what the window saw
MARGIN_FACTOR = 1.5  # the quantile scaled too: a load that doubles delays still mostly fits
WINDOW = 256  # plans whose read delays are kept
FIRST_SAMPLES = 4  # plans measured before the lead follows the measurements


class PlanLead:
    """The running estimate of the lead a plan needs (seconds), from the read delays recorded so far."""

    def __init__(self, minimum: float = LEAD_MIN, maximum: float = LEAD_MAX, window: int = WINDOW,
                 first_samples: int = FIRST_SAMPLES) -> None:
        self.minimum = minimum
        self.maximum = maximum
        self.first_samples = first_samples
        self.recent: collections.deque[float] = collections.deque(maxlen=window)  # in arrival order
        self.ordered: list[float] = []  # the same delays, sorted (a quantile without sorting each time)
        self.late = 0  # plans some RTPU read after their activation
        # The lead the next plan gets: kept up to date as each delay is recorded, since a switch's
        # request reads it on the way to its activation, where each step counts in its latency
        self.value = self._estimate()

    def record(self, delay: float, late: bool = False) -> None:
        """A plan's read delay: its slowest RTPU's first read minus the clock reading its lead was added to."""
        if not math.isfinite(delay):
            return
        delay = max(delay, 0.0)
        if len(self.recent) == self.recent.maxlen:
            gone = self.recent[0]
            del self.ordered[bisect.bisect_left(self.ordered, gone)]
        self.recent.append(delay)
        bisect.insort(self.ordered, delay)
        self.late += late
        self.value = self._estimate()

    def quantile(self) -> float:
        """The ceil(n / 100)-th largest recent delay: at or above their p99 (nan: none yet)."""
        n = len(self.ordered)
        if not n:
            return math.nan
        return self.ordered[n - math.ceil(n / 100)]

    def _estimate(self) -> float:
        if len(self.ordered) < self.first_samples:
            return self.maximum
        return min(max(MARGIN_FACTOR * self.quantile() + MARGIN, self.minimum), self.maximum)


POST_LEAD_MIN = 0.00005  # seconds: the least time given for a plan to be in the header before an RTPU's boundary
LOOKAHEAD = 64  # grid boundaries tried before the plan takes the first one every RTPU meets by a wake-up
_ON_THE_BOUNDARY = 1e-9  # a release this close to a time is at it (the executive's first_release)


@dataclass(frozen=True)
class RtpuAround:
    """One RTPU around a plan: its release epoch, the periods of its periodic tasks ON before the
    switch (staying or leaving) and of those entering, and whether an aperiodic task is ON or enters
    (one may run at any time)."""

    epoch: float
    on_periods: tuple[float, ...]
    entering_periods: tuple[float, ...]
    aperiodic: bool


def deadline(rtpu: RtpuAround, activation: float) -> tuple[float, bool]:
    """By when `rtpu` must have a plan activating at `activation`, and whether its own timer wakes it
    then (True: a release of a task ON there, after which it reads the header before any cycle; False:
    only the plan's wake-up brings it). inf: nothing runs there around the plan."""
    if rtpu.aperiodic:
        return activation, False

    # each period's first release at or after the activation (plain loops: a switch's request waits on this)
    epoch = rtpu.epoch
    since = activation - _ON_THE_BOUNDARY - epoch
    own = entering = math.inf
    for period in rtpu.on_periods:
        first = epoch + max(math.ceil(since / period), 0) * period
        if first < own:
            own = first
    for period in rtpu.entering_periods:
        first = epoch + max(math.ceil(since / period), 0) * period
        if first < entering:
            entering = first
    return min(own, entering), own <= entering


def earliest_activation(requested: float, epoch: float, grid: float, rtpus: list[RtpuAround], post_lead: float,
                        wake_lead: float) -> tuple[float, float]:
    """(activation, the lead it gives): the first boundary of the grid (epoch + k x grid) at least
    `post_lead` after `requested` that every RTPU meets: one its own timer wakes by its deadline
    needs the plan in the header by then (`post_lead`), one only the wake-up brings needs it read
    (`wake_lead`). The lead is the most any RTPU needed, counted back from the activation."""
    activation = epoch + math.ceil((requested + post_lead - epoch) / grid - 1e-9) * grid
    for _ in range(LOOKAHEAD):
        lead, met = post_lead, True
        for rtpu in rtpus:
            due, woken_by_itself = deadline(rtpu, activation)
            need = post_lead if woken_by_itself else wake_lead
            if requested + need > due + 1e-12:
                met = False
                break
            if math.isfinite(due):
                lead = max(lead, need - (due - activation))
        if met:
            return activation, lead
        activation += grid
    first = epoch + math.ceil((requested + wake_lead - epoch) / grid - 1e-9) * grid
    return first, wake_lead
