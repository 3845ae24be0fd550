"""Aperiodic links between subsystems: bounded priority message queues (TR §5.1).

A message is any msgpack-encodable value (dicts, lists, str, bytes, numbers, bools, None) sent
with a priority and stamped with its sending time; the receiver gets the highest priority first
and, within a priority, the oldest first (POSIX message queues order them so). The queue is
bounded: a sender that must not wait gets `LinkFullError` at once, naming the link, its capacity
and what to do. The queue is 0600 and its creator unlinks it on close.

Unlike the run's signal queues (`messages`), these carry data between subsystems, so their
errors are the sender's to handle, never swallowed.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import Any

import msgpack
import posix_ipc

from pbo_runtime.errors import PboError
from pbo_runtime.ipc import messages, process, shm

MAX_PRIORITY = posix_ipc.QUEUE_PRIORITY_MAX
SYSTEM_CAPACITY = messages.MAX_MESSAGES  # fs.mqueue.msg_max (10 by default), capped at 64
SYSTEM_MESSAGE_BYTES = messages.MESSAGE_BYTES  # fs.mqueue.msgsize_max (8192 by default)
ENVELOPE_BYTES = 16  # what the time stamp and msgpack's framing add to a message's body


class MessageLinkError(PboError):
    """A message link is missing, cannot be made as asked, or was given a message it cannot carry."""

    def __init__(self, message: str, hint: str = "") -> None:
        self.message = message
        self.hint = hint
        super().__init__(f"{message}\n  hint: {hint}" if hint else message)


class LinkFullError(MessageLinkError):
    """The link stayed full for as long as the sender was willing to wait.

    `bound`: what caps the capacity, for the hint; a posix_ipc queue's is fs.mqueue.msg_max,
    a zenoh link's window has none but memory.
    """

    def __init__(self, name: str, capacity: int, waited: float,
                 bound: str = f" (at most fs.mqueue.msg_max = {SYSTEM_CAPACITY})") -> None:
        self.name = name
        self.capacity = capacity
        self.waited = waited
        how_long = "the sender asked not to wait" if waited <= 0 else f"it stayed full for {waited:g} s"
        super().__init__(
            f"message link '{name}' is full: {capacity} of {capacity} messages waiting ({how_long})",
            hint=(
                "the receiver is not keeping up: receive more often, send with a timeout to wait for room, "
                f"or create the link with a larger capacity{bound}"
            ),
        )


@dataclass(frozen=True)
class Message:
    """One received message."""

    body: Any
    priority: int
    sent_ns: int  # CLOCK_MONOTONIC ns when it was sent (`time.monotonic_ns()`)


def encode_message(name: str, priority: int, fields: list[Any], max_message_bytes: int) -> bytes:
    """A message's bytes for either transport, or MessageLinkError saying what the sender must change."""
    if not 0 <= priority <= MAX_PRIORITY:
        raise MessageLinkError(f"message link '{name}': priority must be in 0..{MAX_PRIORITY}, got: {priority}")
    try:
        raw: bytes = msgpack.packb(fields, use_bin_type=True)
    except (TypeError, ValueError, OverflowError) as exc:
        raise MessageLinkError(
            f"message link '{name}': cannot encode the message: {exc}",
            hint="send dicts, lists, str, bytes, numbers, bools and None (a numpy array as .tolist())",
        ) from None
    if len(raw) > max_message_bytes:
        raise MessageLinkError(
            f"message link '{name}': a message of {len(raw)} bytes (encoded) exceeds its {max_message_bytes} bytes",
            hint="send bulk data through a triple buffer (a periodic link), or create the link with a larger max_message_bytes",
        )
    return raw


class MessageLink:
    """One process's end of an aperiodic link. `create` makes the queue; `attach` opens it."""

    def __init__(self, name: str, queue: posix_ipc.MessageQueue, owner: bool) -> None:
        self.name = name
        self.owner = owner
        self._queue = queue
        self.capacity = queue.max_messages
        self.max_message_bytes = queue.max_message_size

    @classmethod
    def create(cls, name: str, capacity: int = SYSTEM_CAPACITY, max_message_bytes: int = SYSTEM_MESSAGE_BYTES) -> MessageLink:
        """Create a new 0600 queue holding at most `capacity` messages of `max_message_bytes` (encoded)."""
        if capacity < 1:
            raise MessageLinkError(f"message link '{name}': capacity must be >= 1, got: {capacity}")
        if max_message_bytes < ENVELOPE_BYTES:
            raise MessageLinkError(
                f"message link '{name}': max_message_bytes must be >= {ENVELOPE_BYTES}, got: {max_message_bytes}"
            )
        try:
            queue = posix_ipc.MessageQueue(
                name, posix_ipc.O_CREX, mode=0o600, max_messages=capacity, max_message_size=max_message_bytes
            )
        except ValueError:
            raise MessageLinkError(
                f"message link '{name}': the system refused a queue of {capacity} messages of {max_message_bytes} bytes",
                hint=(
                    f"at most fs.mqueue.msg_max = {SYSTEM_CAPACITY} messages of fs.mqueue.msgsize_max = "
                    f"{SYSTEM_MESSAGE_BYTES} bytes (raise them with sysctl, or send bulk data through a triple buffer)"
                ),
            ) from None
        return cls(name, queue, owner=True)

    @classmethod
    def attach(cls, name: str) -> MessageLink:
        try:
            queue = posix_ipc.MessageQueue(name)
        except posix_ipc.ExistentialError:
            raise MessageLinkError(f"no message link '{name}': has the subsystem that creates it started?") from None
        return cls(name, queue, owner=False)

    def send(self, body: Any, priority: int = 0, timeout: float | None = 0.0) -> None:
        """Queue `body`; wait at most `timeout` seconds for room (0: never wait, None: wait as long as it takes).

        Raises `LinkFullError` if the queue stayed full.
        """
        raw = encode_message(self.name, priority, [time.monotonic_ns(), body], self.max_message_bytes)
        while True:
            try:
                self._queue.send(raw, timeout=timeout, priority=priority)
                return
            except posix_ipc.BusyError:
                raise LinkFullError(self.name, self.capacity, timeout or 0.0) from None
            except posix_ipc.SignalError:
                process.raise_if_stopping()  # a handler that only set a flag: send anyway

    def receive(self, timeout: float | None = None) -> Message | None:
        """The waiting message of highest priority (oldest first within one), or None after `timeout` s (0: do not wait)."""
        if timeout == 0 and self._queue.current_messages == 0:
            return None  # a polling receive on an empty queue raises in posix_ipc, far dearer than asking
        try:
            raw, priority = self._queue.receive(timeout=timeout)
        except posix_ipc.BusyError:
            return None
        except posix_ipc.SignalError:
            process.raise_if_stopping()
            return None
        sent_ns, body = msgpack.unpackb(raw, raw=False)
        return Message(body, priority, sent_ns)

    @property
    def waiting(self) -> int:
        """Messages in the queue now."""
        waiting: int = self._queue.current_messages
        return waiting

    def close(self) -> None:
        """Close this end (and, for the creator, unlink the queue: messages still in it are dropped)."""
        with contextlib.suppress(posix_ipc.ExistentialError):
            self._queue.close()
        if self.owner:
            self.unlink()

    def unlink(self) -> None:
        shm.unlink_quietly("mq", self.name)

    def __enter__(self) -> MessageLink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def message_link_name(subsystem: str, run_id: str, link: str) -> str:
    """The POSIX name of a message link's queue among the run's objects."""
    return shm.object_name(subsystem, run_id, f"msg-{link}")
