"""A switch plan's posting at real-time priority, on the real clock.

The supervisor runs at SCHED_OTHER: any ordinary process may preempt it between the clock reading
a plan's activation is counted from and the plan's words in the header, and the plan's lead must
cover that gap. For those few microseconds it runs at SCHED_FIFO, below the RTPUs and the plant,
so only they (and the kernel) can hold it off; then it goes back to its own policy.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from pbo_runtime.table.table import Header

# Below the RTPUs (50, 55) and the plant (60); above a task's helper processes (a log's encoder,
# a special-purpose processor: SCHED_FIFO 1), which must not hold a plan off.
POSTING_FIFO_PRIORITY = 40


class RealtimePriority:
    """A block run at SCHED_FIFO `priority` where the OS allows it (`with` gives True), else as before
    (False); then back to the policy the process had when this was made.

    Made once per process that posts (nothing else changes its policy meanwhile): entering costs one
    system call, which counts in every switch's latency, where a generator-based context manager and
    reading the policy again would cost several times that.
    """

    __slots__ = ("fifo", "previous", "raised")

    def __init__(self, priority: int = POSTING_FIFO_PRIORITY) -> None:
        self.fifo = os.sched_param(priority)
        self.raised = False
        try:
            self.previous: tuple[int, os.sched_param] | None = (os.sched_getscheduler(0), os.sched_getparam(0))
        except (OSError, AttributeError):  # (no such calls on this OS)
            self.previous = None

    def __enter__(self) -> bool:
        self.raised = False
        if self.previous is not None:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, self.fifo)
                self.raised = True
            except OSError:  # no permission (CAP_SYS_NICE, ulimit -r): the plan's lead covers it
                pass
        return self.raised

    def __exit__(self, *exc: object) -> None:
        if self.raised and self.previous is not None:
            os.sched_setscheduler(0, *self.previous)
            self.raised = False


def at_realtime_priority(priority: int = POSTING_FIFO_PRIORITY) -> RealtimePriority:
    """Run the block at SCHED_FIFO `priority` where the OS allows it (True), else as before (False)."""
    return RealtimePriority(priority)


_posting: list[RealtimePriority] = []  # this process's, once made (a forked child makes its own)
os.register_at_fork(after_in_child=_posting.clear)


def realtime_posting() -> RealtimePriority:
    """This process's posting priority, made at its first plan (its policy read then), used for every plan."""
    if not _posting:
        _posting.append(RealtimePriority())
    return _posting[0]


# The plan's words, as plain ints: written through a memoryview, no enum member looked up in the posting
PLAN_CONFIGURATION, PLAN_TIME_NS = int(Header.PLAN_CONFIGURATION), int(Header.PLAN_TIME_NS)
PLAN_SEQUENCE = int(Header.PLAN_SEQUENCE)


def write_plan(header: Any, configuration: int, activation_ns: int, sequence: int) -> None:
    """A plan's words in the table's header (the array, or its words as a memoryview), the sequence
    last: an executive that sees it sees the whole plan."""
    header[PLAN_CONFIGURATION] = configuration
    header[PLAN_TIME_NS] = activation_ns
    header[PLAN_SEQUENCE] = sequence


def rewrite_plan(header: np.ndarray) -> None:
    """The plan's words written as they are (`write_plan`), to time a posting: no executive sees a new plan."""
    words = header.data
    write_plan(words, words[PLAN_CONFIGURATION], words[PLAN_TIME_NS], words[PLAN_SEQUENCE])
