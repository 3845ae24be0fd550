"""The run's queues when its participants are hosted in the supervisor's process (`--one-process`).

The event queue (`LocalQueue`): the same messages, encoded and decoded as on the POSIX queue
(`messages.Queue`), in the order they were sent, held in the process instead of the kernel: a
participant that reports while the supervisor waits in its turn cannot wait for room, since the
reader is the one that called it. The POSIX queue is still made (a run's queues, manifest and
sizes are those of a run of processes); nothing is sent on it.

An RTPU's signal queue (`CountedQueue`): the POSIX queue itself, whose every end (job
control's, the RTPU's, its relays') is opened in this process and counts what it sends and
receives in one count they share: whether a signal waits, asked at each of the RTPU's turns,
is read from that count instead of the kernel.
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


class CountedQueue(Queue):
    """A POSIX queue whose senders and reader are all in this process: `pending` reads their shared count."""

    def __init__(self, name: str, create: bool = False, size: QueueSize | None = None,
                 waiting: list[int] | None = None) -> None:
        super().__init__(name, create=create, size=size)
        self._waiting = [0] if waiting is None else waiting  # messages sent and not yet received, by any end

    def another_end(self) -> CountedQueue:
        return CountedQueue(self.name, waiting=self._waiting)

    def pending(self) -> bool:
        return self._waiting[0] > 0

    def send(self, *message: Any, timeout: float | None = 1.0) -> None:
        super().send(*message, timeout=timeout)
        self._waiting[0] += 1

    def try_send(self, *message: Any, timeout: float = 0.5, reader_alive: Callable[[], bool] | None = None,
                 cut_to_fit: bool = False) -> bool:
        sent = super().try_send(*message, timeout=timeout, reader_alive=reader_alive, cut_to_fit=cut_to_fit)
        if sent:
            self._waiting[0] += 1
        return sent

    def receive(self, timeout: float | None) -> list[Any] | None:
        message = super().receive(timeout)
        if message is not None:
            self._waiting[0] -= 1
        return message


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
