"""What every child process of a run does first: die with its parent, stop cleanly on SIGTERM.

The supervisor's death reaches a child as SIGHUP (PR_SET_PDEATHSIG), often more than once:
Linux sends it each time the child is handed from an ending thread of the supervisor to
another, and a SIGKILLed supervisor ends thread by thread. A repeat is not a second request
(which would stop the child at once, wherever it is): the child stops as it was asked to the
first time, within `STOP_BOUND` (its tasks' kills brake the arm), and only then at once.
"""

from __future__ import annotations

import ctypes
import os
import select
import signal
import sys
from types import FrameType

DEATH_SIGNAL = signal.SIGHUP  # what Linux sends a child when its supervisor dies
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, DEATH_SIGNAL)
STOP_BOUND = 1.0  # seconds a child whose supervisor died has to stop by itself before it stops at once
DEATH_WAIT = 2.0  # seconds a child told of its supervisor's death waits at most for it to be over (it ends thread by thread)


class Stop(BaseException):
    """Raised in a child by SIGTERM/SIGINT/SIGHUP so its `finally` blocks clean up.

    A BaseException, like KeyboardInterrupt: a module's `except Exception` (or the runtime's
    own, which turns a module's failure into its ERROR state) must never swallow it.
    """


_requested = ""
_parent = 0  # the supervisor's pid (`become_child`); 0: this process has none
_hung_up = False  # the death signal came: the supervisor is dying or dead
_only_at_waits = False


def _stop_signal(signum: int, _frame: FrameType | None) -> None:
    """The first stop signal raises Stop (only records it, once `stop_only_at_waits`); a second one
    raises at once, unless the supervisor's death was said (then `STOP_BOUND` takes over)."""
    global _requested, _hung_up
    if signum == DEATH_SIGNAL and not _hung_up:
        _hung_up = True
        signal.setitimer(signal.ITIMER_REAL, STOP_BOUND)  # `_stop_now` when it runs out
    if _requested:
        if _hung_up:
            return
        raise Stop(signal.Signals(signum).name)
    _requested = signal.Signals(signum).name
    if not _only_at_waits:
        raise Stop(_requested)


def _stop_now(_signum: int, _frame: FrameType | None) -> None:
    raise Stop(f"{_requested or 'stop'}, not stopped within {STOP_BOUND:g} s")


def raise_if_stopping() -> None:
    """Raise Stop if one was requested: a C extension swallowed it (posix_ipc turns it into
    SignalError), or the process takes stops only at its waits (`stop_only_at_waits`)."""
    if _requested:
        raise Stop(_requested)


def stop_requested() -> str:
    """The name of the signal that asked this process to stop ('' if none did)."""
    return _requested


def supervisor_told_gone() -> bool:
    """Whether this child was told its supervisor is dying or dead (no waiting: `supervisor_gone` waits)."""
    return _parent != 0 and (_hung_up or os.getppid() != _parent)


def supervisor_gone() -> bool:
    """True once the supervisor this child was started by has died (never, for a process without one).

    While it is this process's parent and no death signal came, it lives. Otherwise its end is
    waited for on a pidfd, at most DEATH_WAIT: a supervisor being SIGKILLed sends the death
    signal from each of its threads as it ends, before it is over."""
    if not supervisor_told_gone():
        return False
    try:
        pidfd = os.pidfd_open(_parent)
    except ProcessLookupError:
        return True
    except (AttributeError, OSError):  # no pidfd here: what /proc says now
        from pbo_runtime.ipc.shm import pid_alive

        return not pid_alive(_parent)
    try:
        return bool(select.select([pidfd], [], [], DEATH_WAIT)[0])
    finally:
        os.close(pidfd)


def supervisor_dying() -> None:
    """This process found its supervisor's death another way (its channel to it closed without a word):
    as if the death signal came first, which may come only after."""
    global _hung_up
    _hung_up = True


def stopping_done() -> None:
    """The stop is over (what is left is leaving): the bound no longer applies."""
    signal.setitimer(signal.ITIMER_REAL, 0)


def stop_only_at_waits() -> None:
    """From now on a stop signal requests a stop, which the process's next wait raises.

    An RTPU calls this before its executive runs. A Stop raised wherever the signal landed could
    land between a transfer's acquire and release of the table lock (no try/finally there: it is
    the per-cycle path); the stop path then took the lock again and waited on itself for ever.
    The executive's one wait (`Queue.receive`, the lockstep barrier) raises it instead, at most a
    cycle later. A second signal raises at once, for a module that never returns to the wait.
    """
    global _only_at_waits
    _only_at_waits = True
    for signum in STOP_SIGNALS:
        signal.signal(signum, _stop_signal)


def become_child(parent_pid: int) -> None:
    """Ask Linux to send us DEATH_SIGNAL when the supervisor dies, and turn it and SIGTERM/SIGINT into `Stop`."""
    global _parent
    _parent = parent_pid
    for signum in STOP_SIGNALS:
        signal.signal(signum, _stop_signal)
    signal.signal(signal.SIGALRM, _stop_now)
    try:
        PR_SET_PDEATHSIG = 1
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, DEATH_SIGNAL, 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:  # the parent died before the request took effect
        sys.exit(3)
