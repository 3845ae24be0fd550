"""What every child process of a run does first: die with its parent, stop cleanly on SIGTERM."""

from __future__ import annotations

import ctypes
import os
import signal
import sys


class Stop(Exception):
    """Raised in a child by SIGTERM/SIGINT so its `finally` blocks clean up."""


def _raise_stop(signum: int, _frame) -> None:
    raise Stop(signal.Signals(signum).name)


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
