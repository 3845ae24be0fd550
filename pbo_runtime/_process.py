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


def raise_if_stopping() -> None:
    """Re-raise a Stop that a C extension swallowed (posix_ipc turns it into SignalError)."""
    if _requested:
        raise Stop(_requested)


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
