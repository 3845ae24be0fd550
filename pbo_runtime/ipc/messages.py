"""Signals to RTPUs and events back to job control: msgpack over POSIX message queues.

Queues carry signals and events only, never per-cycle data (DESIGN §3). All are 0600.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import msgpack
import posix_ipc

from pbo_runtime.ipc import process
from pbo_runtime.ipc import shm
from pbo_runtime.errors import InternalError

MESSAGE_BYTES = 8192
READER_CHECK = 0.1  # seconds between checks that a queue's reader is alive, while a send waits on it


def _system_limit(name: str, default: int) -> int:
    try:
        with open(f"/proc/sys/fs/mqueue/{name}") as limit:
            return int(limit.read())
    except (OSError, ValueError):
        return default


# Linux refuses queues longer than fs.mqueue.msg_max (10 by default) even to root.
MAX_MESSAGES = min(64, _system_limit("msg_max", 10))
MESSAGE_BYTES = min(MESSAGE_BYTES, _system_limit("msgsize_max", MESSAGE_BYTES))


def signal_queue_name(subsystem: str, run_id: str, rtpu: str) -> str:
    return shm.object_name(subsystem, run_id, f"rtpu-{rtpu}")


def event_queue_name(subsystem: str, run_id: str) -> str:
    return shm.object_name(subsystem, run_id, "events")


def plant_registers_name(subsystem: str, run_id: str) -> str:
    return shm.object_name(subsystem, run_id, "plant")


def table_name(subsystem: str, run_id: str) -> str:
    return shm.object_name(subsystem, run_id, "table")


class Queue:
    """One end of a message queue carrying msgpack-encoded lists."""

    def __init__(self, name: str, create: bool = False) -> None:
        self.name = name
        flags = posix_ipc.O_CREX if create else 0
        self._mq = posix_ipc.MessageQueue(name, flags, mode=0o600, max_messages=MAX_MESSAGES, max_message_size=MESSAGE_BYTES)
        self.owner = create

    def send(self, *message: Any, timeout: float | None = 1.0) -> None:
        raw = self._encode(message)
        while True:
            try:
                self._mq.send(raw, timeout=timeout)
                return
            except posix_ipc.SignalError:
                process.raise_if_stopping()
                continue  # interrupted by a signal whose handler only set a flag: send anyway

    def try_send(self, *message: Any, timeout: float = 0.5, reader_alive: Callable[[], bool] | None = None) -> bool:
        """Send, waiting at most `timeout`; False if the queue stayed full or is gone (a dead peer must not hang us).

        `reader_alive`, asked every READER_CHECK seconds of the wait, ends it as soon as the
        process that reads the queue is gone: a long wait is only worth it while someone drains.
        """
        raw = self._encode(message)
        deadline = time.monotonic() + timeout
        while True:
            left = max(deadline - time.monotonic(), 0.0)
            if reader_alive is not None and not reader_alive():
                left = 0.0  # nobody drains it: one try, no wait
            wait = left if reader_alive is None else min(left, READER_CHECK)
            try:
                self._mq.send(raw, timeout=wait)
                return True
            except posix_ipc.BusyError:
                if wait >= left:  # waited all that was left: the queue stayed full
                    return False
            except (posix_ipc.ExistentialError, posix_ipc.SignalError, OSError):
                return False

    def _encode(self, message: tuple[Any, ...]) -> bytes:
        """The message as msgpack; one too long for the queue is our bug, named, never a bare ValueError."""
        raw = msgpack.packb(list(message))
        if len(raw) > self._mq.max_message_size:
            raise InternalError(f"a '{message[0]}' message of {len(raw)} B does not fit queue {self.name} "
                                f"(at most {self._mq.max_message_size} B); please report this")
        return raw

    def receive(self, timeout: float | None) -> list[Any] | None:
        """The next message, or None if none came within `timeout` seconds (0: do not wait).

        A stop requested while the process was not waiting is raised here (`process.stop_only_at_waits`).
        """
        process.raise_if_stopping()
        try:
            raw, _priority = self._mq.receive(timeout=max(timeout, 0.0) if timeout is not None else None)
        except posix_ipc.BusyError:
            return None
        except posix_ipc.SignalError:
            # The signal's handler has run. In the supervisor it set a flag and we return; in
            # a child it raised Stop, which posix_ipc replaced by SignalError: raise it again.
            process.raise_if_stopping()
            return None
        return msgpack.unpackb(raw)

    def close(self) -> None:
        try:
            self._mq.close()
        except posix_ipc.ExistentialError:
            pass
        if self.owner:
            shm.unlink_quietly("mq", self.name)
