"""The run's event queue when its participants are hosted in the supervisor's process (`--one-process`).

The same messages, encoded and decoded as on the POSIX queue (`messages.Queue`), in the order
they were sent, held in the process instead of the kernel: a participant that reports while
the supervisor waits in its turn cannot wait for room, since the reader is the one that called
it. The POSIX queue is still made (a run's queues, manifest and sizes are those of a run of
processes); nothing is sent on it.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from typing import Any

import msgpack

from pbo_runtime.ipc import process
from pbo_runtime.ipc.limits import QueueSize
from pbo_runtime.ipc.messages import Queue


class LocalQueue(Queue):
    """A queue whose sender and reader are the same process: unbounded, first in, first out."""

    def __init__(self, name: str, size: QueueSize) -> None:
        super().__init__(name, create=True, size=size)
        self._held: collections.deque[bytes] = collections.deque()

    def pending(self) -> bool:
        return bool(self._held)

    def send(self, *message: Any, timeout: float | None = 1.0) -> None:
        self._held.append(self._encode(message))

    def try_send(self, *message: Any, timeout: float = 0.5, reader_alive: Callable[[], bool] | None = None,
                 cut_to_fit: bool = False) -> bool:
        self._held.append(self._encode(message, cut_to_fit))
        return True

    def receive(self, timeout: float | None) -> list[Any] | None:
        """The next message; none held waits out `timeout` (nothing in the process can send meanwhile)."""
        process.raise_if_stopping()
        if self._held:
            message: list[Any] = msgpack.unpackb(self._held.popleft())
            return message
        if timeout:
            time.sleep(timeout)
        return None
