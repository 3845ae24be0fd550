"""Threads and processes of an RTPU beside its executive's: they run below it, and never hold its GIL for long.

Each runs SCHED_FIFO with SCHED_RESET_ON_FORK, as the executive does: a process one of them
starts (a log's encoder) begins at SCHED_OTHER. Inheriting the real-time priority, its
interpreter's start-up would hold both CPUs from every ordinary process, a device's processor
among them, until it stepped down itself.
"""

from __future__ import annotations

import os
import threading

HELPER_FIFO_PRIORITY = 1  # the lowest real-time priority: above every ordinary process, below every executive
GIL_HANDOVER = 0.0002  # s: an RTPU's switch interval, within the spin before each release (rtpu/__main__.py)


def below_the_cycle() -> None:
    """Run this thread just below every executive: SCHED_FIFO at the lowest priority when its
    process's executive runs SCHED_FIFO, else SCHED_OTHER.

    A thread of an RTPU shares the executive's GIL. At SCHED_OTHER, preempted by any process of
    the machine while it holds the GIL, it would hold the executive off its release for as long
    (a priority inversion). At the lowest real-time priority it runs whenever the executive
    waits for the GIL, and gives it back within the RTPU's switch interval (`GIL_HANDOVER`)."""
    native = threading.get_native_id()
    if native == os.getpid():
        return  # the executive's own thread
    _helpers.add(native)
    _lower(native)


def process_below_the_cycle(pid: int) -> None:
    """Run the helper process `pid` (its main thread: a device's processor) just below every
    executive, as `below_the_cycle` does a thread. For a process whose start-up is done: the
    imports and first calls of a process at a real-time priority would hold an RTPU's CPU."""
    _helpers.add(pid)
    _lower(pid)


def lower_helpers() -> None:
    """Again for every helper thread and process started so far: a restarted RTPU takes SCHED_FIFO only when
    its first task turns on, after its tasks' inits started theirs."""
    for native in list(_helpers):
        _lower(native)


_helpers: set[int] = set()  # native ids of the threads that called `below_the_cycle`, pids given `process_below_the_cycle`


def _lower(native: int) -> None:
    try:
        executive_fifo = os.sched_getscheduler(os.getpid()) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
        if executive_fifo:
            os.sched_setscheduler(native, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(HELPER_FIFO_PRIORITY))
        else:
            os.sched_setscheduler(native, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        _helpers.discard(native)  # (ended)
