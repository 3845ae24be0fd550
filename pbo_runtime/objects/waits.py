"""Waiting in a task's `init` while the RTPU's other tasks go on cycling.

A task spawned live (`pbo spawn`, `pbo replace`) runs its `init` in the RTPU's executive thread,
between two cycles of the tasks already on there. An init that must wait for something outside
(a special-purpose processor's process to start, a device to answer) polls with
`sleep_while_cycling` instead of `time.sleep`: while the executive spawns a task on the real
clock it runs the cycles that come due during the sleep (`cycles_meanwhile`); anywhere else (the
start-up's spawns before any task is on, the simulated clock, another thread, a test) it sleeps.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator

_cycling: tuple[int, Callable[[float], None]] | None = None  # (the executive's thread, its sleep)


def sleep_while_cycling(seconds: float) -> None:
    """Sleep about `seconds`; in a live spawn's init, the RTPU's due cycles run meanwhile.

    0: no sleep, only the cycles due now (a long computation in `init` lets them run between
    its steps, as `arm_model` does between joints)."""
    global _cycling
    cycling = _cycling
    if cycling is None or cycling[0] != threading.get_ident():
        if seconds > 0:
            time.sleep(seconds)
        return
    _cycling = None  # a cycle run meanwhile that waited itself would only sleep: cycles never nest
    try:
        cycling[1](seconds)
    finally:
        _cycling = cycling


@contextlib.contextmanager
def cycles_meanwhile(sleep: Callable[[float], None]) -> Iterator[None]:
    """While in this block, `sleep_while_cycling` in this thread calls `sleep` (the executive's:
    it runs the due cycles until the time is up)."""
    global _cycling
    before, _cycling = _cycling, (threading.get_ident(), sleep)
    try:
        yield
    finally:
        _cycling = before
