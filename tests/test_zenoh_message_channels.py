"""The message link over zenoh takes messages, credits and the receiver's comings and goings from
channels that the caller's thread drains: nothing it was allowed to send is lost while nobody calls
`receive`, late credits still open the window, a bad message is reported, a restarted receiver
starts a window afresh, and no Python runs in zenoh's threads. One process, sessions on loopback.
"""

from __future__ import annotations

import os
import threading

import msgpack
import pytest

from pbo_runtime.ipc import messages
from pbo_runtime.links import zenoh_message_link
from pbo_runtime.links.message_link import LinkFullError, MessageLinkError
from pbo_runtime.links.relay import MessageRelay
from pbo_runtime.links.zenoh_message_link import SENDER_WINDOWS, ZenohMessageLink
from pbo_runtime.links.zenoh_session import endpoint, free_port, link_key, open_session
from tests.support import unique_name, until

pytest.importorskip("zenoh")

SAFETY_NET = 30.0  # seconds: a broken link fails instead of hanging the suite (no test asserts on time)


def key(part: str) -> str:
    return link_key(f"test-{os.getpid()}-{os.urandom(3).hex()}", part)


def connected(sender: ZenohMessageLink) -> None:
    until(lambda: sender._publisher.matching_status.matching, f"the receiver of '{sender.name}'")


@pytest.fixture
def hub():
    """A receiver on a free port, and a client session for the senders (as another subsystem's)."""
    port = free_port()
    with ZenohMessageLink.create(key("goals"), capacity=3, port=port) as receiver:
        session = open_session(connect=[endpoint(port)], wait=SAFETY_NET)
        try:
            yield receiver, session
        finally:
            session.close()


@pytest.mark.parametrize("senders", [3, SENDER_WINDOWS + 1], ids=["a few senders", "more than the channel holds"])
def test_what_senders_send_while_nobody_receives_comes_out_later_in_priority_order(hub, senders):
    receiver, session = hub
    ends = [ZenohMessageLink.attach(receiver.name, session=session) for _ in range(senders)]
    for end in ends:
        connected(end)
    for number, end in enumerate(ends):
        for order in range(receiver.capacity):
            end.send({"sender": number, "order": order}, priority=order % 2)
        with pytest.raises(LinkFullError):
            end.send("one too many")
    total = senders * receiver.capacity
    until(lambda: receiver.waiting == total, f"{total} messages in the receiver's queue")
    taken = [receiver.receive(timeout=0) for _ in range(total)]
    assert receiver.receive(timeout=0) is None
    assert [m.priority for m in taken] == sorted((m.priority for m in taken), reverse=True)
    for number in range(senders):
        mine = [(m.priority, m.body["order"]) for m in taken if m.body["sender"] == number]
        assert mine == sorted(((order % 2, order) for order in range(receiver.capacity)), key=lambda p: (-p[0], p[1]))
    for end in ends:
        end.close()


def test_credits_taken_late_open_the_whole_window(hub):
    import zenoh

    receiver, session = hub
    with ZenohMessageLink.attach(receiver.name, session=session) as sender:
        connected(sender)
        observer = session.declare_subscriber(f"{receiver.key}/credit/{sender._id:x}", zenoh.handlers.RingChannel(1))
        credited = [0]

        def every_credit_came() -> bool:
            sample = observer.try_recv()
            credited[0] = msgpack.unpackb(sample.payload.to_bytes()) if sample is not None else credited[0]
            return credited[0] == receiver.capacity

        for order in range(receiver.capacity):
            sender.send(order)
        until(lambda: receiver.waiting == receiver.capacity, "the window's messages at the receiver")
        assert [receiver.receive(timeout=0).body for _ in range(receiver.capacity)] == list(range(receiver.capacity))
        until(every_credit_came, "the receiver's credits at the sender's session")  # the sender has not looked
        until(lambda: sender.waiting == 0, "the sender's window to open")
        for order in range(receiver.capacity):
            sender.send(order)  # no wait: the newest credit counted every message the receiver took
        with pytest.raises(LinkFullError):
            sender.send("one too many")
        observer.undeclare()


def test_a_sender_that_waits_for_room_gets_it_when_the_receiver_takes_a_message(hub):
    receiver, session = hub
    with ZenohMessageLink.attach(receiver.name, session=session) as sender:
        connected(sender)
        for order in range(receiver.capacity):
            sender.send(order)
        until(lambda: receiver.waiting == receiver.capacity, "the window's messages at the receiver")
        taker = threading.Thread(target=receiver.receive, args=(SAFETY_NET,))
        taker.start()
        sender.send("after room", timeout=SAFETY_NET)
        taker.join()
        assert sender.waiting == receiver.capacity


def test_a_sender_waiting_for_room_is_refused_when_the_receiver_leaves():
    port = free_port()
    receiver = ZenohMessageLink.create(key("goals"), capacity=2, port=port)
    with ZenohMessageLink.attach(receiver.name, port=port) as sender:
        connected(sender)
        sender.send(1)
        sender.send(2)
        closer = threading.Timer(0.1, receiver.close)  # most often while the send waits (else its first check refuses)
        closer.start()
        with pytest.raises(MessageLinkError, match=r"has no receiver connected: the message was not sent\n  hint: "):
            sender.send(3, timeout=SAFETY_NET)
        closer.join()


@pytest.mark.parametrize("payload", [b"\xc1", msgpack.packb([1, 2]), msgpack.packb(["who", 1, 0, "body"])],
                         ids=["not msgpack", "too few fields", "fields of the wrong kind"])
def test_a_message_that_cannot_be_decoded_is_counted_and_reported(hub, payload):
    receiver, session = hub
    with ZenohMessageLink.attach(receiver.name, session=session) as sender:
        connected(sender)
        session.put(f"{receiver.key}/message", payload)
        sender.send("good")
        reported, received = [], []

        def both_came() -> bool:
            try:
                message = receiver.receive(timeout=0)
            except MessageLinkError as exc:
                reported.append(str(exc))
            else:
                received.extend([] if message is None else [message.body])
            return bool(reported and received)

        until(both_came, "the malformed message reported and the good one received")
        assert reported == [f"message link '{receiver.name}' received 1 message(s) it cannot decode\n"
                            "  hint: do both ends run the same version of pbo-runtime?"]
        assert received == ["good"]


def test_a_receiver_that_restarts_gives_the_sender_a_fresh_window():
    port, name = free_port(), key("goals")
    first = ZenohMessageLink.create(name, capacity=2, port=port)
    with ZenohMessageLink.attach(name, port=port) as sender:
        connected(sender)
        sender.send("lost with the first receiver")
        sender.send("lost too")
        first.close()  # it took nothing: the sender's window is full, and no credit will come
        with ZenohMessageLink.create(name, capacity=2, port=port) as second:
            connected(sender)  # the sender never looked while the receiver was away: its ring of statuses did
            sender.send("a")
            sender.send("b")
            until(lambda: second.waiting == 2, "the messages at the new receiver")
            assert [second.receive(timeout=0).body for _ in range(2)] == ["a", "b"]


def test_messages_and_credits_are_decoded_in_the_callers_thread_never_in_zenohs(hub, monkeypatch):
    receiver, session = hub
    decoded_in: set[int] = set()
    unpackb = msgpack.unpackb

    def watched(*args, **kwargs):
        decoded_in.add(threading.get_ident())
        return unpackb(*args, **kwargs)

    monkeypatch.setattr(zenoh_message_link.msgpack, "unpackb", watched)
    with ZenohMessageLink.attach(receiver.name, session=session) as sender:
        connected(sender)
        for order in range(2 * receiver.capacity):
            sender.send(order, timeout=SAFETY_NET)  # takes credits once the window is full
            assert receiver.receive(timeout=SAFETY_NET).body == order
    assert decoded_in == {threading.get_ident()}


def _blocked_receive(receiver: ZenohMessageLink) -> tuple[threading.Thread, list]:
    """A thread blocked in `receive()` without a timeout; what it got (or raised) lands in the list."""
    outcome: list = []

    def wait() -> None:
        try:
            outcome.append(receiver.receive())
        except MessageLinkError as exc:
            outcome.append(exc)

    waiter = threading.Thread(target=wait)
    waiter.start()
    until(lambda: receiver._blocked == 1, "the receive to block in the channel")
    return waiter, outcome


@pytest.mark.parametrize("waker", ["a sender", "the receiver itself", "a close"])
def test_a_receive_without_a_timeout_blocks_in_the_channel_until_a_message_or_a_close(hub, waker):
    receiver, session = hub
    with ZenohMessageLink.attach(receiver.name, session=session) as sender:
        connected(sender)
        waiter, outcome = _blocked_receive(receiver)
        if waker == "a sender":
            sender.send("from a sender")
        elif waker == "the receiver itself":
            receiver.send("from itself")
        else:
            receiver.close()
        waiter.join(SAFETY_NET)
    assert not waiter.is_alive() and len(outcome) == 1
    if waker == "a close":
        assert str(outcome[0]) == f"message link '{receiver.name}' is closed"
    else:
        assert outcome[0].body == {"a sender": "from a sender", "the receiver itself": "from itself"}[waker]


def test_a_servers_relay_waits_in_the_channel_forwards_each_message_and_ends_at_close(hub):
    receiver, session = hub
    signals = messages.Queue(unique_name("signals-rtpu0"), create=True)
    try:
        relay = MessageRelay(receiver, signals.name, "goal")
        with ZenohMessageLink.attach(receiver.name, session=session) as sender:
            connected(sender)
            sender.send([1.0])
            sender.send([2.0], priority=3)
            got = [signals.receive(SAFETY_NET) for _ in range(2)]
        relay.close()
        relay._thread.join(SAFETY_NET)
        assert sorted(m[2][0] for m in got) == [[1.0], [2.0]]
        assert relay.forwarded == 2 and not relay._thread.is_alive() and receiver._session is None
    finally:
        signals.close()
