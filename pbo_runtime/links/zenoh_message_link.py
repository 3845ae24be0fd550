"""The message link over eclipse-zenoh: an aperiodic link with the semantics of `links.message_link.MessageLink`.

The queue lives at the receiver (the end that creates the link and listens); each sender has a
window of `capacity` messages, refilled by the credits the receiver sends as it takes messages,
so a full receiver refuses a send (`LinkFullError`) instead of dropping it. Messages come out in
priority order, oldest first within one. `open_aperiodic` opens an end from the spec the
application runner hands down (`links.ends`).

No Python runs in zenoh's threads: they only push samples into channels (messages into a FIFO,
credits and the receiver's comings and goings into rings), and the thread that calls `send` or
`receive` drains them, so a real-time caller never waits for a lock or the GIL held by one of
zenoh's threads at normal priority. A `receive()` without a timeout blocks in the FIFO with the
GIL released; a timed wait looks at its channels again after a pause that doubles from 20 µs to
1 ms (the binding has no timed wait on a channel).
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
SENDER_WINDOWS = 8  # senders whose full windows the receiver's channel holds between two receives (zenoh's thread
# waits for room beyond that: nothing is dropped)
STATUS_RING = 8  # the newest matching statuses a sender keeps: a receiver's leaving is seen though it came back since
WAIT_FIRST, WAIT_LONGEST = 20e-6, 1e-3  # seconds between two looks of a waiting call: doubling from the first


class ZenohMessageLink(SessionEnd):
    """One process's end of an aperiodic link over zenoh. `create` makes the receiving end; `attach` a sender.

    The threads that call an end share `_mine` (never zenoh's threads), held only while a call
    drains its channels and updates the window or the queue, never while it waits.
    """

    transport = "zenoh"
    wakes_on_close = True  # a `receive()` without a timeout returns (raising) when another thread closes the end

    def __init__(self, name: str, owner: bool, capacity: int, max_message_bytes: int) -> None:
        self.name = name
        self.key = key_expression(name)
        self.owner = owner
        self.capacity = capacity
        self.max_message_bytes = max_message_bytes
        self._id = int.from_bytes(os.urandom(7), "little")
        self._mine = threading.Lock()  # guards everything below
        self._sent = self._consumed = 0  # this end's messages sent, and taken by the receiver's receive()
        self._queue: list[tuple[int, int, int, int, Any]] = []  # receiver: (-priority, arrival, sender, sent ns, body)
        self._arrival = itertools.count()
        self._consumed_by: dict[int, int] = {}  # receiver: per sender id
        self._credit_keys: dict[int, str] = {}  # receiver: per sender id, where its credits go
        self._credit_options: dict[str, Any] = {}
        self._malformed = 0
        self._publisher: Any = None
        self._inbox: Any = None  # receiver: the FIFO channel receive() drains (and blocks in, without a timeout)
        self._blocked = 0  # receiver: receives blocked in the FIFO now (a send to itself wakes them)
        self._closed_channel: type[Exception] = Exception  # receiver: what a closed channel raises (zenoh.ZError)
        self._drain_at_most = 0  # receiver: the FIFO's size, the most one drain takes
        self._credits: Any = None  # sender: the subscriber whose one-credit ring send() drains
        self._statuses: Any = None  # sender: the matching listener whose ring of statuses send() drains

    @classmethod
    def create(cls, name: str, capacity: int = SYSTEM_CAPACITY, max_message_bytes: int = SYSTEM_MESSAGE_BYTES, *,
               port: int | None = None, host: str = LOOPBACK, session: Any = None) -> ZenohMessageLink:
        """The receiving end, holding the queue: listens on `tcp/<host>:<port>` (or uses `session`)."""
        if capacity < 1:
            raise MessageLinkError(f"message link '{name}': capacity must be >= 1, got: {capacity}")
        if max_message_bytes < 16:
            raise MessageLinkError(f"message link '{name}': max_message_bytes must be >= 16, got: {max_message_bytes}")
        zenoh = zenoh_module()
        listen, connect = endpoints(name, port, host, session, listening=True)
        link = cls(name, True, capacity, max_message_bytes)
        link._closed_channel = zenoh.ZError
        link._open_session(session, listen, connect)
        try:
            link._drain_at_most = capacity * SENDER_WINDOWS
            messages = link._session.declare_subscriber(f"{link.key}/message", zenoh.handlers.FifoChannel(link._drain_at_most))
            link._entities.append(messages)
            link._inbox = messages.handler  # its handler, not the subscriber: a close from another thread wakes a recv
            link._credit_options = {"congestion_control": zenoh.CongestionControl.BLOCK,
                                    "priority": getattr(zenoh.Priority, MESSAGE_PRIORITY), "express": True}
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
            link._credits = link._session.declare_subscriber(f"{link.key}/credit/{link._id:x}",
                                                             zenoh.handlers.RingChannel(1))  # credits are cumulative
            link._entities.append(link._credits)
            link._publisher = link._session.declare_publisher(
                f"{link.key}/message",
                congestion_control=zenoh.CongestionControl.BLOCK,  # a message is never dropped by the network
                priority=getattr(zenoh.Priority, MESSAGE_PRIORITY),
                express=True,
            )
            link._entities.append(link._publisher)
            link._statuses = link._publisher.declare_matching_listener(zenoh.handlers.RingChannel(STATUS_RING))
            link._entities.append(link._statuses)
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
        """What the receiver answers an attaching sender (in zenoh's thread: constants only, no lock)."""
        return {"format": MESSAGE_FORMAT, "capacity": self.capacity, "max_message_bytes": self.max_message_bytes,
                "pid": os.getpid(), "host": socket.gethostname()}

    # --- sending ------------------------------------------------------------------------------

    def send(self, body: Any, priority: int = 0, timeout: float | None = 0.0) -> None:
        """Send `body`; wait at most `timeout` s for room in this end's window (0: never, None: as long as it takes).

        Raises `LinkFullError` if the receiver still holds `capacity` of this end's messages.
        """
        sent_ns = time.monotonic_ns()
        raw = encode_message(self.name, priority, [self._id, sent_ns, priority, body], self.max_message_bytes)
        publisher = self._publisher
        if self._session is None:
            raise MessageLinkError(f"message link '{self.name}' is closed")
        if publisher is not None and not publisher.matching_status.matching:
            raise self._no_receiver()
        deadline = None if timeout is None else time.monotonic() + timeout
        pause = WAIT_FIRST
        wake = False
        while True:
            with self._mine:
                gone = self._take_credits() and not publisher.matching_status.matching  # it left since the check
                if not gone and self._sent - self._consumed < self.capacity:
                    self._sent += 1
                    if publisher is None:  # the receiving end sends to itself
                        self._enqueue(self._id, sent_ns, priority, body)
                        wake = self._blocked > 0
                    break
            if gone:
                raise self._no_receiver()
            pause = _pause(deadline, pause)
            if pause < 0:
                raise LinkFullError(self.name, self.capacity, timeout or 0.0, bound="")
        if publisher is not None:
            publisher.put(raw)
        elif wake:  # an empty sample in its own FIFO (local delivery is at once): a blocked receive looks again
            self._session.put(f"{self.key}/message", b"")

    def _no_receiver(self) -> MessageLinkError:
        return MessageLinkError(f"message link '{self.name}' has no receiver connected: the message was not sent",
                                hint="has the receiving subsystem stopped? send again once it is back")

    def _take_credits(self, always: bool = False) -> bool:
        """Drain the statuses, and the credit if the window is full (or `always`), under `_mine`.

        True if the receiver left since the last look. A credit left in its ring while there is
        room loses nothing: the next one counts it too.
        """
        statuses, credits = self._statuses, self._credits
        if credits is None:
            return False
        left = False
        while (status := statuses.try_recv()) is not None:
            left = left or not status.matching
        if left:  # what the receiver held is gone with it: a new one counts from 0
            self._sent = self._consumed = 0
            while credits.try_recv() is not None:  # the old receiver's, sent before it left
                pass
            return True
        if not always and self._sent - self._consumed < self.capacity:
            return False
        sample = credits.try_recv()
        if sample is not None:
            consumed = msgpack.unpackb(sample.payload.to_bytes())
            if isinstance(consumed, int) and consumed > self._consumed:  # cumulative: a late one changes nothing
                self._consumed = consumed
        return False

    # --- receiving ----------------------------------------------------------------------------

    def _take_messages(self, first: Any = None) -> None:
        """Decode `first` and what zenoh put in the FIFO since the last look into the priority queue (under `_mine`)."""
        inbox = self._inbox
        if first is not None:
            self._decode(first.payload.to_bytes())
        if inbox is None:
            return
        try:
            for _ in range(self._drain_at_most):
                sample = inbox.try_recv()
                if sample is None:
                    return
                self._decode(sample.payload.to_bytes())
        except self._closed_channel:  # another thread closed this end: nothing more will come
            return

    def _decode(self, raw: bytes) -> None:
        if not raw:
            return  # a wake-up (see send)
        try:
            sender, sent_ns, priority, body = msgpack.unpackb(raw, raw=False)
        except (ValueError, TypeError, msgpack.UnpackException):
            self._malformed += 1
            return
        if type(sender) is not int or type(sent_ns) is not int or type(priority) is not int:
            self._malformed += 1
            return
        self._enqueue(sender, sent_ns, priority, body)

    def _enqueue(self, sender: int, sent_ns: int, priority: int, body: Any) -> None:
        heapq.heappush(self._queue, (-priority, next(self._arrival), sender, sent_ns, body))

    def receive(self, timeout: float | None = None) -> Message | None:
        """The waiting message of highest priority (oldest first within one), or None after `timeout` s (0: do not wait).

        Without a timeout it blocks in zenoh's channel, the GIL released, until a message comes or
        another thread closes this end (`MessageLinkError`); with one it looks again after pauses.
        """
        if not self.owner:
            raise MessageLinkError(
                f"message link '{self.name}': only the end that created it receives; this one attached to send"
            )
        deadline = None if timeout is None else time.monotonic() + timeout
        pause = WAIT_FIRST
        while True:
            with self._mine:
                self._take_messages()
                if self._malformed:
                    count, self._malformed = self._malformed, 0
                    raise MessageLinkError(f"message link '{self.name}' received {count} message(s) it cannot decode",
                                           hint="do both ends run the same version of pbo-runtime?")
                if self._queue:
                    negative_priority, _, sender, sent_ns, body = heapq.heappop(self._queue)
                    consumed = self._consumed_by[sender] = self._consumed_by.get(sender, 0) + 1
                    if sender == self._id:
                        self._consumed = consumed
                    break
                inbox = self._inbox
                if timeout is None and inbox is not None:
                    self._blocked += 1
            if timeout is None:
                self._block_in(inbox)
                continue
            pause = _pause(deadline, pause)
            if pause < 0:
                return None
        if sender != self._id and self._session is not None:
            self._session.put(self._credit_key(sender), msgpack.packb(consumed), **self._credit_options)
        return Message(body, -negative_priority, sent_ns)

    def _block_in(self, inbox: Any) -> None:
        """Wait in the FIFO, the GIL released, for the next sample; it goes to the queue."""
        if inbox is None:
            raise MessageLinkError(f"message link '{self.name}' is closed")
        sample = None
        try:
            sample = inbox.recv()
        except self._closed_channel:  # the channel closed: another thread closed this end
            raise MessageLinkError(f"message link '{self.name}' is closed") from None
        finally:
            with self._mine:
                self._blocked -= 1
                self._take_messages(sample)

    def _credit_key(self, sender: int) -> str:
        key = self._credit_keys.get(sender)
        if key is None:
            key = self._credit_keys[sender] = f"{self.key}/credit/{sender:x}"
        return key

    @property
    def waiting(self) -> int:
        """The receiver: messages in its queue. A sender: its messages the receiver has not taken yet."""
        with self._mine:
            if self.owner:
                self._take_messages()
                return len(self._queue)
            self._take_credits(always=True)
            return self._sent - self._consumed

    def _forget(self) -> None:
        self._publisher = self._inbox = self._credits = self._statuses = None  # (waiting messages go with the session)

    def unlink(self) -> None:
        """Nothing to remove (kept for the shm link's interface)."""

    def __enter__(self) -> ZenohMessageLink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def _pause(deadline: float | None, pause: float) -> float:
    """Sleep before the next look of a waiting call and return the next pause; -1 once `deadline` has passed."""
    if deadline is not None:
        left = deadline - time.monotonic()
        if left <= 0:
            return -1.0
        pause = min(pause, left)
    time.sleep(pause)
    return min(pause * 2, WAIT_LONGEST)


def open_aperiodic(spec: RunLink, role: str) -> ZenohMessageLink:
    """One end of an application's zenoh message link: the server listens on the spec's endpoint, the sender connects."""
    host, port = spec_endpoint(spec)
    if role == "server":
        return ZenohMessageLink.create(spec.key, spec.capacity or SYSTEM_CAPACITY, port=port, host=host)
    return ZenohMessageLink.attach(spec.key, port=port, host=host, wait=DEFAULT_WAIT if spec.wait is None else spec.wait)
