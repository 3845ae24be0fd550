"""The message link over eclipse-zenoh: an aperiodic link with the semantics of `links.message_link.MessageLink`.

The queue lives at the receiver (the end that creates the link and listens); each sender has a
window of `capacity` messages, refilled by the credits the receiver sends as it takes messages,
so a full receiver refuses a send (`LinkFullError`) instead of dropping it. Messages come out in
priority order, oldest first within one. `open_aperiodic` opens an end from the spec the
application runner hands down (`links.ends`).
"""

from __future__ import annotations

import heapq
import itertools
import os
import socket
import threading
import time
from typing import Any

import msgpack

from pbo_runtime.errors import PboError
from pbo_runtime.links.message_link import (
    SYSTEM_CAPACITY,
    SYSTEM_MESSAGE_BYTES,
    LinkFullError,
    Message,
    MessageLinkError,
    encode_message,
)
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.links.zenoh_session import (
    ANSWER_TIMEOUT,
    DEFAULT_WAIT,
    LOOPBACK,
    SessionEnd,
    endpoints,
    key_expression,
    spec_endpoint,
    zenoh_module,
)

MESSAGE_FORMAT = 1
MESSAGE_PRIORITY = "INTERACTIVE_HIGH"  # zenoh.Priority of messages and credits: above bulk data, below periodic items


class ZenohMessageLink(SessionEnd):
    """One process's end of an aperiodic link over zenoh. `create` makes the receiving end; `attach` a sender."""

    transport = "zenoh"

    def __init__(self, name: str, owner: bool, capacity: int, max_message_bytes: int) -> None:
        self.name = name
        self.key = key_expression(name)
        self.owner = owner
        self.capacity = capacity
        self.max_message_bytes = max_message_bytes
        self._id = int.from_bytes(os.urandom(7), "little")
        self._room = threading.Condition()  # guards everything below
        self._sent = self._consumed = 0  # this end's messages sent, and taken by the receiver's receive()
        self._queue: list[tuple[int, int, int, int, Any]] = []  # receiver: (-priority, arrival, sender, sent ns, body)
        self._arrival = itertools.count()
        self._consumed_by: dict[int, int] = {}  # receiver: per sender id
        self._malformed = 0
        self._publisher: Any = None

    @classmethod
    def create(cls, name: str, capacity: int = SYSTEM_CAPACITY, max_message_bytes: int = SYSTEM_MESSAGE_BYTES, *,
               port: int | None = None, host: str = LOOPBACK, session: Any = None) -> ZenohMessageLink:
        """The receiving end, holding the queue: listens on `tcp/<host>:<port>` (or uses `session`)."""
        if capacity < 1:
            raise MessageLinkError(f"message link '{name}': capacity must be >= 1, got: {capacity}")
        if max_message_bytes < 16:
            raise MessageLinkError(f"message link '{name}': max_message_bytes must be >= 16, got: {max_message_bytes}")
        listen, connect = endpoints(name, port, host, session, listening=True)
        link = cls(name, True, capacity, max_message_bytes)
        link._open_session(session, listen, connect)
        try:
            link._entities.append(link._session.declare_subscriber(f"{link.key}/message", link._on_message))
            link._answer_as("receiver", link._describe)
        except BaseException:
            link._close_session()
            raise
        return link

    @classmethod
    def attach(cls, name: str, *, port: int | None = None, host: str = LOOPBACK, session: Any = None,
               wait: float | None = DEFAULT_WAIT) -> ZenohMessageLink:
        """A sending end: connects to the receiver's `tcp/<host>:<port>` (or uses `session`) and learns its capacity."""
        zenoh = zenoh_module()
        listen, connect = endpoints(name, port, host, session, listening=False)
        link = cls(name, False, 0, 0)
        link._open_session(session, listen, connect, wait)
        try:
            receivers = [e for e in link._other_ends(f"{link.key}/end/receiver") if e.get("format") == MESSAGE_FORMAT]
            if not receivers:
                where = f"on {connect[0]}" if connect else "on the given session"
                raise MessageLinkError(f"no message link '{name}': no receiver answered {where}: "
                                       "has the subsystem that creates it started?")
            link.capacity = int(receivers[0]["capacity"])
            link.max_message_bytes = int(receivers[0]["max_message_bytes"])
            link._entities.append(link._session.declare_subscriber(f"{link.key}/credit/{link._id:x}", link._on_credit))
            link._publisher = link._session.declare_publisher(
                f"{link.key}/message",
                congestion_control=zenoh.CongestionControl.BLOCK,  # a message is never dropped by the network
                priority=getattr(zenoh.Priority, MESSAGE_PRIORITY),
                express=True,
            )
            link._entities.append(link._publisher)
            link._entities.append(link._publisher.declare_matching_listener(link._on_matching))
            give_up = time.monotonic() + ANSWER_TIMEOUT  # the receiver answered: its subscription is on its way
            while not link._publisher.matching_status.matching and time.monotonic() < give_up:
                time.sleep(0.001)
        except BaseException:
            link._close_session()
            raise
        return link

    def _missing(self, detail: str) -> PboError:
        return MessageLinkError(f"no message link '{self.name}': {detail}: has the subsystem that creates it started?")

    def _describe(self) -> dict[str, Any]:
        return {"format": MESSAGE_FORMAT, "capacity": self.capacity, "max_message_bytes": self.max_message_bytes,
                "pid": os.getpid(), "host": socket.gethostname()}

    # --- sending ------------------------------------------------------------------------------

    def send(self, body: Any, priority: int = 0, timeout: float | None = 0.0) -> None:
        """Send `body`; wait at most `timeout` s for room in this end's window (0: never, None: as long as it takes).

        Raises `LinkFullError` if the receiver still holds `capacity` of this end's messages.
        """
        sent_ns = time.monotonic_ns()
        raw = encode_message(self.name, priority, [self._id, sent_ns, priority, body], self.max_message_bytes)
        if self._session is None:
            raise MessageLinkError(f"message link '{self.name}' is closed")
        if self._publisher is not None and not self._publisher.matching_status.matching:
            raise MessageLinkError(f"message link '{self.name}' has no receiver connected: the message was not sent",
                                   hint="has the receiving subsystem stopped? send again once it is back")
        with self._room:
            full = self._sent - self._consumed >= self.capacity
            if full and (timeout == 0 or not self._room.wait_for(lambda: self._sent - self._consumed < self.capacity, timeout)):
                raise LinkFullError(self.name, self.capacity, timeout or 0.0, bound="")
            self._sent += 1
            if self._publisher is None:  # the receiving end sends to itself
                self._enqueue(self._id, sent_ns, priority, body)
                return
        self._publisher.put(raw)

    def _on_credit(self, sample: Any) -> None:
        consumed = msgpack.unpackb(sample.payload.to_bytes())
        with self._room:
            if consumed > self._consumed:  # credits are cumulative: a late one changes nothing
                self._consumed = consumed
                self._room.notify_all()

    def _on_matching(self, status: Any) -> None:
        if not status.matching:  # the receiver left: what it held is gone, a new one counts from 0
            with self._room:
                self._sent = self._consumed = 0
                self._room.notify_all()

    # --- receiving ----------------------------------------------------------------------------

    def _on_message(self, sample: Any) -> None:
        try:
            sender, sent_ns, priority, body = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        except (ValueError, TypeError, msgpack.UnpackException):
            with self._room:
                self._malformed += 1
                self._room.notify_all()
            return
        with self._room:
            self._enqueue(sender, sent_ns, priority, body)

    def _enqueue(self, sender: int, sent_ns: int, priority: int, body: Any) -> None:
        heapq.heappush(self._queue, (-priority, next(self._arrival), sender, sent_ns, body))
        self._room.notify_all()

    def receive(self, timeout: float | None = None) -> Message | None:
        """The waiting message of highest priority (oldest first within one), or None after `timeout` s (0: do not wait)."""
        if not self.owner:
            raise MessageLinkError(
                f"message link '{self.name}': only the end that created it receives; this one attached to send"
            )
        with self._room:
            if not self._queue and timeout != 0:
                self._room.wait_for(lambda: self._queue or self._malformed, timeout)
            if self._malformed:
                count, self._malformed = self._malformed, 0
                raise MessageLinkError(f"message link '{self.name}' received {count} message(s) it cannot decode",
                                       hint="do both ends run the same version of pbo-runtime?")
            if not self._queue:
                return None
            negative_priority, _, sender, sent_ns, body = heapq.heappop(self._queue)
            consumed = self._consumed_by[sender] = self._consumed_by.get(sender, 0) + 1
            if sender == self._id:
                self._consumed = consumed
                self._room.notify_all()
        if sender != self._id and self._session is not None:
            self._session.put(
                f"{self.key}/credit/{sender:x}",
                msgpack.packb(consumed),
                congestion_control=zenoh_module().CongestionControl.BLOCK,
                priority=getattr(zenoh_module().Priority, MESSAGE_PRIORITY),
                express=True,
            )
        return Message(body, -negative_priority, sent_ns)

    @property
    def waiting(self) -> int:
        """The receiver: messages in its queue. A sender: its messages the receiver has not taken yet."""
        with self._room:
            return len(self._queue) if self.owner else self._sent - self._consumed

    def _forget(self) -> None:
        self._publisher = None  # (a receiver's waiting messages are dropped with its session)

    def unlink(self) -> None:
        """Nothing to remove (kept for the shm link's interface)."""

    def __enter__(self) -> ZenohMessageLink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def open_aperiodic(spec: RunLink, role: str) -> ZenohMessageLink:
    """One end of an application's zenoh message link: the server listens on the spec's endpoint, the sender connects."""
    host, port = spec_endpoint(spec)
    if role == "server":
        return ZenohMessageLink.create(spec.key, spec.capacity or SYSTEM_CAPACITY, port=port, host=host)
    return ZenohMessageLink.attach(spec.key, port=port, host=host, wait=DEFAULT_WAIT if spec.wait is None else spec.wait)
