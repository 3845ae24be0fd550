"""A switch plan's posting at real-time priority, on the real clock.

The supervisor runs at SCHED_OTHER: any ordinary process may preempt it between the clock reading
a plan's activation is counted from and the plan's words in the header, and the plan's lead must
cover that gap. For those few microseconds it runs at SCHED_FIFO, below the RTPUs and the plant,
so only they (and the kernel) can hold it off; then it goes back to its own policy.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from pbo_runtime.table.table import Header

# Below the RTPUs (50, 55) and the plant (60); above a task's helper processes (a log's encoder,
# a special-purpose processor: SCHED_FIFO 1), which must not hold a plan off.
POSTING_FIFO_PRIORITY = 40


@contextmanager
def at_realtime_priority(priority: int = POSTING_FIFO_PRIORITY) -> Iterator[bool]:
    """Run the block at SCHED_FIFO `priority` where the OS allows it (True), else as before (False)."""
    try:
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except (OSError, AttributeError):  # no permission (CAP_SYS_NICE, ulimit -r): the plan's lead covers it
        yield False
        return
    try:
        yield True
    finally:
        os.sched_setscheduler(0, policy, param)


def write_plan(header: np.ndarray, configuration: int, activation_ns: int, sequence: int) -> None:
    """A plan's words in the table's header, the sequence last: an executive that sees it sees the whole plan."""
    header[Header.PLAN_CONFIGURATION] = configuration
    header[Header.PLAN_TIME_NS] = activation_ns
    header[Header.PLAN_SEQUENCE] = sequence


def rewrite_plan(header: np.ndarray) -> None:
    """The plan's words written as they are (`write_plan`), to time a posting: no executive sees a new plan."""
    words = (Header.PLAN_CONFIGURATION, Header.PLAN_TIME_NS, Header.PLAN_SEQUENCE)
    write_plan(header, *(int(header[word]) for word in words))
