"""The plan's lead: how far ahead of its posting a switch plan activates, sized from measured read delays.

Job control posts a plan in the table's header and wakes the RTPUs; each must have read it by its
activation for all of them to switch at that one instant. How long that takes is measured on every
plan, not assumed: each RTPU stamps when it first read the plan (`Switched.read_at`), and the
plan's read delay is its slowest RTPU's stamp minus the clock reading job control took the lead
from. The lead is a high quantile of the recent read delays plus a margin, within bounds:

    lead = clamp(MARGIN_FACTOR x q + MARGIN, LEAD_MIN, LEAD_MAX)

where q is the ceil(n / 100)-th largest of the last WINDOW delays (their p99 or above; the maximum
while fewer than 100 are known). Until FIRST_SAMPLES plans were read the lead is LEAD_MAX, the fixed
lead it replaces. A plan an RTPU read too late for its activation is still safe (that RTPU applies
it at its first cycle boundary after, before anything of it runs in the old configuration:
docs/reconfiguration.md); its delay enters the window like any other, and raises the next leads
as soon as more than one plan in a hundred was that slow (at once, under 100 plans).
"""

from __future__ import annotations

import bisect
import collections
import math

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

    def quantile(self) -> float:
        """The ceil(n / 100)-th largest recent delay: at or above their p99 (nan: none yet)."""
        n = len(self.ordered)
        if not n:
            return math.nan
        return self.ordered[n - math.ceil(n / 100)]

    @property
    def value(self) -> float:
        """The lead the next plan gets."""
        if len(self.ordered) < self.first_samples:
            return self.maximum
        return min(max(MARGIN_FACTOR * self.quantile() + MARGIN, self.minimum), self.maximum)
