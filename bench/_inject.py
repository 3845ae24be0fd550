"""Faults injected into a live run from outside it: a process stopped, stopped while it holds the table lock.

Shared by `bench.faults` and the fault tests (tests/support.py), so both cause a fault the same way.
Each wait has a safety net that only turns a hang into an error; nothing here judges timing.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import posix_ipc

from pbo_runtime.ipc.shm import attach_segment, pid_state
from pbo_runtime.table.table import Header


class InjectionFailed(RuntimeError):
    """The fault could not be caused (the process ended, or never held the lock)."""


def table_of(subsystem: str, supervisor: int) -> str:
    """The POSIX name of the table of `subsystem`'s run whose `pbo run` is process `supervisor`."""
    [entry] = [e for e in os.listdir("/dev/shm") if e.startswith(f"pbo.{subsystem}.{supervisor}-") and e.endswith(".table")]
    return "/" + entry


def stop_process(pid: int, safety_net: float = 30.0) -> float:
    """SIGSTOP `pid` and wait until it is stopped; the CLOCK_MONOTONIC time of the signal."""
    stopped_at = time.monotonic()
    os.kill(pid, signal.SIGSTOP)
    give_up = stopped_at + safety_net
    while (state := pid_state(pid)) not in ("T", "t"):
        if state in ("", "Z", "X"):
            raise InjectionFailed(f"process {pid} ended before it could be stopped")
        if time.monotonic() > give_up:
            raise InjectionFailed(f"process {pid} did not stop within {safety_net:g} s")
        time.sleep(0.001)
    return stopped_at


def stop_while_holding_the_lock(pid: int, table_name: str, safety_net: float = 60.0) -> float:
    """SIGSTOP `pid` at a moment it holds the table lock; the CLOCK_MONOTONIC time of the stop that landed.

    It holds the lock a few microseconds per cycle, so this stops and resumes it until a stop lands
    there (its lock record names it while the lock is taken): hundreds of tries, each a fraction of
    a millisecond.
    """
    lock = posix_ipc.Semaphore(table_name + ".lock")
    mapping = attach_segment(table_name)
    header = np.frombuffer(mapping, dtype=np.int64, count=Header.LOCK_SEQUENCE + 1)
    try:
        give_up = time.monotonic() + safety_net
        while time.monotonic() < give_up:
            stopped_at = stop_process(pid)
            for _look in range(2):  # twice: another process may have taken the lock but not yet signed it
                sequence = int(header[Header.LOCK_SEQUENCE])  # a writer's tag (2 pid + 1) while odd
                holder = sequence >> 1 if sequence & 1 else int(header[Header.LOCK_HOLDER])
                if lock.value != 0 or holder != pid:
                    break
                time.sleep(0.005)
            else:
                return stopped_at
            os.kill(pid, signal.SIGCONT)
        raise InjectionFailed(f"never caught process {pid} holding the lock of {table_name}")
    finally:
        del header
        mapping.close()
        lock.close()
