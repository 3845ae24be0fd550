"""What every child process of a run does first: die with its parent, stop cleanly on SIGTERM."""

from __future__ import annotations

import ctypes
import os
import signal
import sys


class Stop(BaseException):
    """Raised in a child by SIGTERM/SIGINT so its `finally` blocks clean up.

    A BaseException, like KeyboardInterrupt: a module's `except Exception` (or the runtime's
    own, which turns a module's failure into its ERROR state) must never swallow it.
    """


_requested = ""


def _raise_stop(signum: int, _frame) -> None:
    global _requested
    _requested = signal.Signals(signum).name
    raise Stop(_requested)


def _request_stop(signum: int, _frame) -> None:
    global _requested
    if _requested:  # asked twice (a stuck module, an impatient operator): stop now
        raise Stop(signal.Signals(signum).name)
    _requested = signal.Signals(signum).name


def raise_if_stopping() -> None:
    """Raise Stop if one was requested: a C extension swallowed it (posix_ipc turns it into
    SignalError), or the process takes stops only at its waits (`stop_only_at_waits`)."""
    if _requested:
        raise Stop(_requested)


def stop_requested() -> str:
    """The name of the signal that asked this process to stop ('' if none did)."""
    return _requested


def stop_only_at_waits() -> None:
    """From now on SIGTERM/SIGINT request a stop, which the process's next wait raises.

    An RTPU calls this before its executive runs. A Stop raised wherever the signal landed could
    land between a transfer's acquire and release of the table lock (no try/finally there: it is
    the per-cycle path); the stop path then took the lock again and waited on itself for ever.
    The executive's one wait (`Queue.receive`, the lockstep barrier) raises it instead, at most a
    cycle later. A second signal raises at once, for a module that never returns to the wait.
    """
    signal.signal(signal.SIGTERM, _request_stop)
    signal.signal(signal.SIGINT, _request_stop)


def become_child(parent_pid: int) -> None:
    """Ask Linux to SIGTERM us when the supervisor dies, and turn SIGTERM/SIGINT into `Stop`."""
    signal.signal(signal.SIGTERM, _raise_stop)
    signal.signal(signal.SIGINT, _raise_stop)
    try:
        PR_SET_PDEATHSIG = 1
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:  # the parent died before the request took effect
        sys.exit(3)
