"""Noticing a child's death the moment it happens, not at the next look.

A thread waits in poll(2) on a pidfd per child (Linux 5.3: readable once the process has
exited) and, when one becomes readable, puts a `ChildExited` event on the supervisor's own
event queue, so a supervisor waiting for events wakes at once and handles the death in its own
thread (`Children.check`). The thread never touches the run's state: it only wakes.
Where pidfds are missing the supervisor still finds the death at its next look, as before.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
from collections.abc import Callable


class ChildWatch:
    """Calls `exited(role, pid)` from its thread once for each watched process that ends."""

    def __init__(self, exited: Callable[[str, int], object]) -> None:
        self._exited = exited
        self._poll = select.poll()
        self._watched: dict[int, tuple[str, int]] = {}  # pidfd -> (role, pid)
        self._lock = threading.Lock()
        self._wake_read, self._wake_write = os.pipe2(os.O_CLOEXEC | os.O_NONBLOCK)
        self._poll.register(self._wake_read, select.POLLIN)
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="child-watch", daemon=True)
        self._thread.start()

    @staticmethod
    def available() -> bool:
        return hasattr(os, "pidfd_open")

    def watch(self, role: str, pid: int) -> bool:
        """Watch `pid`; False where this kernel or Python has no pidfd (the periodic look remains)."""
        try:
            pidfd = os.pidfd_open(pid)
        except (AttributeError, OSError):
            return False
        with self._lock:
            self._watched[pidfd] = (role, pid)
            self._poll.register(pidfd, select.POLLIN)
        os.write(self._wake_write, b"w")  # poll picks the new descriptor up at once
        return True

    def close(self) -> None:
        with self._lock:
            self._closed = True
        with contextlib.suppress(OSError):
            os.write(self._wake_write, b"q")
        self._thread.join(timeout=1.0)
        for fd in (*self._watched, self._wake_read, self._wake_write):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._watched.clear()

    def _run(self) -> None:
        while True:
            ready = self._poll.poll()
            with self._lock:
                if self._closed:
                    return
                ended = [self._watched.pop(fd) for fd, _ in ready if fd in self._watched]
                for fd, _ in ready:
                    if fd == self._wake_read:
                        with contextlib.suppress(BlockingIOError):
                            os.read(self._wake_read, 64)
                    elif fd not in self._watched:
                        self._poll.unregister(fd)
                        os.close(fd)
            for role, pid in ended:
                self._exited(role, pid)
