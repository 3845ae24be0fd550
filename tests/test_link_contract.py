"""What a link promises, whatever carries it: each test runs over shared memory and over zenoh on loopback.

Periodic links (a triple buffer, or zenoh): a read gets the newest complete item or nothing, a
read before the next item reuses the last one and says so, counters never go back and the items
a slow reader skipped are counted lost, the sender's stamp arrives with the item, a write held
open never holds up the reader, one sender and one reader at a time, another payload is refused
at attach, naming both.

Message links (a POSIX queue, or zenoh): messages round-trip with their priority and sending time,
the highest priority first and equal priorities in order; a full link, a message too large or
one msgpack cannot encode, and a priority out of range are refused before anything is sent.

What only one transport has stays with it: the triple buffer's protocol steps and its processes
hammering one link (test_triple_buffer.py), the POSIX queue's limits and permissions
(test_link_messages.py), zenoh's sessions, deliveries and renumbering (test_zenoh_link.py).
Where a reader that comes late starts counting differs too: from the item newest at its attach
in shared memory, from the first item it receives over zenoh; each file tests its own.
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pbo_runtime.links.message_link import MAX_PRIORITY, SYSTEM_CAPACITY, LinkFullError, Message, MessageLink, MessageLinkError
from pbo_runtime.links.triple_buffer import Freshness, LinkError, LinkLayout, LinkLayoutError, TripleBuffer
from pbo_runtime.links.zenoh_link import ZenohLink
from pbo_runtime.links.zenoh_message_link import ZenohMessageLink
from pbo_runtime.links.zenoh_session import free_port, link_key
from tests.support import assert_complete, fill, unique_name, until

ARM = LinkLayout("float64", (6,))
ITEM_LAYOUT = LinkLayout(np.dtype([("counter", "<i8"), ("values", "<f8", (64,)), ("checksum", "<u8")]))


class SharedMemory:
    """A triple buffer and a POSIX message queue: what a sender publishes is there for the reader at once."""

    def __init__(self) -> None:
        self.name = unique_name("link")

    def create(self, layout: LinkLayout, role: str | None = None) -> TripleBuffer:
        return TripleBuffer.create(self.name, layout, role)

    def attach(self, layout: LinkLayout, role: str | None = None, wait: float | None = None) -> TripleBuffer:
        return TripleBuffer.attach(self.name, layout, role)  # nothing to wait for: the segment is there or not

    def connected(self, sender) -> None:
        pass

    def arrived(self, reader, counter: int) -> None:
        pass

    def messages(self, **options) -> MessageLink:
        return MessageLink.create(unique_name("msg"), **options)

    def attach_messages(self, name: str, wait: float | None = None) -> MessageLink:
        return MessageLink.attach(name)


class Zenoh:
    """Zenoh sessions on loopback: the creating end listens on a free port, the attaching end connects.

    Items travel: a test waits for the item it wrote to arrive before it reads. The reader takes
    every sample in zenoh's callback ("callback" delivery), so a test can wait for an item to
    arrive without reading it (as a slow reader would).
    """

    def __init__(self) -> None:
        self.name = link_key(f"test-{os.getpid()}-{os.urandom(3).hex()}", "link")
        self.port = free_port()

    def create(self, layout: LinkLayout, role: str | None = None) -> ZenohLink:
        return ZenohLink.create(self.name, layout, role, port=self.port, delivery="callback")

    def attach(self, layout: LinkLayout, role: str | None = None, wait: float | None = None) -> ZenohLink:
        options = {} if wait is None else {"wait": wait}
        return ZenohLink.attach(self.name, layout, role, port=self.port, delivery="callback", **options)

    def connected(self, sender: ZenohLink) -> None:
        until(lambda: sender._publisher.matching_status.matching, f"a reader of '{sender.name}'")

    def arrived(self, reader: ZenohLink, counter: int) -> None:
        def held() -> bool:
            newest = reader._newest
            return newest is not None and newest[1] >= counter

        until(held, f"item {counter} on '{reader.name}'")

    def messages(self, **options) -> ZenohMessageLink:
        return ZenohMessageLink.create(link_key(f"test-{os.getpid()}-{os.urandom(3).hex()}", "msg"), port=free_port(), **options)

    def attach_messages(self, name: str, wait: float | None = None) -> ZenohMessageLink:
        options = {} if wait is None else {"wait": wait}
        return ZenohMessageLink.attach(name, port=self.port, **options)


TRANSPORTS = {"shm": SharedMemory, "zenoh": Zenoh}


@pytest.fixture(params=TRANSPORTS)
def transport(request):
    return TRANSPORTS[request.param]()


@pytest.fixture
def link_pair(transport):
    """A float64[6] link created by its sender, with a reader attached and connected; both closed after the test."""
    with transport.create(ARM, "sender") as sender, transport.attach(ARM, "reader") as reader:
        transport.connected(sender)
        yield sender, reader


def sent(transport, sender, reader, value, stamp_ns: int | None = None) -> int:
    """Write `value` and wait until the reader could read it; its counter."""
    counter = sender.write(value, stamp_ns=stamp_ns)
    transport.arrived(reader, counter)
    return counter


# --- periodic links -------------------------------------------------------------------------------


def test_a_read_before_any_write_gets_nothing_and_leaves_the_array(link_pair):
    _, reader = link_pair
    out = np.full(6, 7.0)
    assert reader.read(out) is Freshness.NONE
    assert (out == 7.0).all()
    assert reader.counter == 0
    assert reader.statistics().empty == 1


def test_a_write_is_read_back_with_its_counter_and_time_stamp(transport, link_pair):
    sender, reader = link_pair
    before = time.monotonic_ns()
    assert sent(transport, sender, reader, np.arange(6.0)) == 1
    assert reader.read() is Freshness.NEW
    assert reader.value.tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert reader.counter == 1
    assert before <= reader.stamp_ns <= time.monotonic_ns()
    assert reader.lost_in_last_read == 0


def test_the_sender_can_stamp_an_item_with_when_its_data_was_generated(transport, link_pair):
    sender, reader = link_pair
    sent(transport, sender, reader, np.zeros(6), stamp_ns=123_456)
    reader.read()
    assert reader.stamp_ns == 123_456


def test_reading_again_before_a_new_write_reuses_the_item(transport, link_pair):
    sender, reader = link_pair
    sent(transport, sender, reader, np.ones(6))
    reader.read()
    out = np.zeros(6)
    assert reader.read(out) is Freshness.REUSED
    assert (out == 1.0).all()  # a reuse still copies: the caller's array always holds the item
    stats = reader.statistics()
    assert (stats.new, stats.reused, stats.lost) == (1, 1, 0)
    assert (reader.lost, reader.reused) == (stats.lost, stats.reused)  # what a receiving module publishes each cycle


def test_a_slow_reader_gets_the_newest_item_and_counts_the_ones_it_lost(transport, link_pair):
    sender, reader = link_pair
    for k in range(1, 8):
        sender.write(np.full(6, float(k)))
    transport.arrived(reader, 7)
    assert reader.read() is Freshness.NEW
    assert reader.counter == 7 and (reader.value == 7.0).all()
    assert reader.lost_in_last_read == 6
    sender.write(np.full(6, 8.0))
    sent(transport, sender, reader, np.full(6, 9.0))
    reader.read()
    assert reader.lost_in_last_read == 1
    stats = reader.statistics()
    assert stats.new + stats.lost == 9


def test_a_reader_never_waits_for_a_write_held_open(transport, link_pair):
    sender, reader = link_pair
    sent(transport, sender, reader, np.full(6, 1.0))
    half_written = sender.begin_write()
    half_written[:3] = 2.0  # the sender is in the middle of its copy
    assert reader.read() is Freshness.NEW
    for _ in range(100):
        assert reader.read() is Freshness.REUSED
        assert (reader.value == 1.0).all() and reader.counter == 1
    half_written[3:] = 2.0
    del half_written
    transport.arrived(reader, sender.publish())
    assert reader.read() is Freshness.NEW and (reader.value == 2.0).all()


def test_a_structured_payload_round_trips_field_by_field(transport):
    with transport.create(ITEM_LAYOUT, "sender") as sender, transport.attach(ITEM_LAYOUT, "reader") as reader:
        transport.connected(sender)
        fill(sender.begin_write(), 1)
        transport.arrived(reader, sender.publish())
        reader.read()
        assert_complete(reader.value, 1)


def test_another_payload_is_refused_at_attach_and_the_error_names_both(transport):
    with (transport.create(ARM, "reader"),
          pytest.raises(LinkLayoutError, match=rf"^link '{transport.name}' carries float64 \(6,\), this process expects "
                                               r"float32 \(3,\): do both ends declare the same payload\?$")):
        transport.attach(LinkLayout("float32", (3,)), "sender")


def test_attaching_to_a_missing_link_names_it(transport):
    port = getattr(transport, "port", None)  # zenoh names the endpoint it tried
    with pytest.raises(LinkError, match=rf"^no link '{transport.name}': (nothing answered on tcp/127\.0\.0\.1:{port}: )?"
                                        r"has the subsystem that creates it started\?$"):
        transport.attach(LinkLayout.raw(8), "reader", wait=0)


def test_a_link_has_one_live_sender_and_one_live_reader_and_each_keeps_to_its_role(transport, link_pair):
    sender, reader = link_pair
    with pytest.raises(LinkError, match=rf"^link '{transport.name}' already has a sender: pid {os.getpid()} "):
        transport.attach(ARM, "sender")
    with pytest.raises(LinkError, match=rf"^link '{transport.name}' already has a reader: pid {os.getpid()} "):
        transport.attach(ARM, "reader")
    with pytest.raises(LinkError, match=r"^cannot write link '.*': this process opened it as its reader; only its sender may$"):
        reader.write(np.zeros(6))
    with pytest.raises(LinkError, match=r"^cannot read link '.*': this process opened it as its sender; only its reader may$"):
        sender.read()
    reader.close()
    with transport.attach(ARM, "reader"):  # the first reader closed: its role is free again
        pass


def test_a_sender_taking_over_goes_on_from_the_readers_counter(transport):
    layout = LinkLayout("int64", (2,))
    with transport.create(layout, "reader") as reader:
        with transport.attach(layout, "sender") as first:
            transport.connected(first)
            for k in range(1, 5):
                first.write([k, k])
            sent(transport, first, reader, [5, 5])
            reader.read()
        with transport.attach(layout, "sender") as second:  # the first one's role is free again
            transport.connected(second)
            assert sent(transport, second, reader, [6, 6]) == 6
        assert reader.read() is Freshness.NEW
        assert (reader.counter, reader.lost_in_last_read, reader.value.tolist()) == (6, 0, [6, 6])


def test_a_role_must_be_sender_or_reader(transport):
    with pytest.raises(LinkError, match=r"^role must be one of sender, reader \(or None\), got: 'writer'$"):
        transport.create(LinkLayout.raw(8), "writer")


# --- message links ----------------------------------------------------------------------------------
# The creating end: it may send to its own queue, so one end is enough for what a link refuses or keeps.


@pytest.fixture
def messages(transport):
    with transport.messages(capacity=SYSTEM_CAPACITY) as made:
        yield made


BODIES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats(allow_nan=False)
    | st.text(max_size=20)
    | st.binary(max_size=20),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=BODIES, priority=st.integers(0, MAX_PRIORITY))
def test_a_message_round_trips_with_its_priority_and_sending_time(messages, body, priority):
    before = time.monotonic_ns()
    messages.send(body, priority=priority)
    message = messages.receive(timeout=0)
    assert message == Message(body, priority, message.sent_ns)
    assert before <= message.sent_ns <= time.monotonic_ns()
    assert messages.receive(timeout=0) is None


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(priorities=st.lists(st.integers(0, 5), min_size=1, max_size=SYSTEM_CAPACITY))
def test_the_highest_priority_comes_first_and_equal_priorities_in_order(messages, priorities):
    for order, priority in enumerate(priorities):
        messages.send({"order": order}, priority=priority)
    received = [messages.receive(timeout=0) for _ in priorities]
    expected = sorted(enumerate(priorities), key=lambda pair: (-pair[1], pair[0]))
    assert [(m.body["order"], m.priority) for m in received] == expected


def test_a_full_link_refuses_a_sender_that_asks_not_to_wait_and_loses_nothing(transport):
    with transport.messages(capacity=2) as small:
        small.send(1)
        small.send(2)
        with pytest.raises(LinkFullError, match=rf"^message link '{small.name}' is full: 2 of 2 messages waiting \(the sender "
                                                r"asked not to wait\)\n  hint: the receiver is not keeping up: ") as raised:
            small.send(3)
        assert (raised.value.name, raised.value.capacity) == (small.name, 2)
        assert [small.receive(timeout=0).body for _ in range(2)] == [1, 2]
        assert small.receive(timeout=0) is None


def test_a_sender_that_waits_gets_the_error_once_the_link_stayed_full(transport):
    with transport.messages(capacity=2) as small:
        small.send(1)
        small.send(2)
        with pytest.raises(LinkFullError,
                           match=r"^message link '.*' is full: 2 of 2 messages waiting \(it stayed full for 0\.01 s\)\n  hint: "):
            small.send(3, timeout=0.01)


def test_a_message_too_large_for_the_link_is_refused_before_it_is_sent(transport):
    with transport.messages(max_message_bytes=64) as small:
        with pytest.raises(MessageLinkError,
                           match=r"^message link '.*': a message of \d+ bytes \(encoded\) exceeds its 64 bytes\n"
                                 r"  hint: send bulk data through a triple buffer"):
            small.send("x" * 100)
        assert small.waiting == 0


def test_a_message_msgpack_cannot_encode_is_refused_with_a_hint(messages):
    with pytest.raises(MessageLinkError, match=r"cannot encode the message: .*\n  hint: send dicts, lists, str, bytes, numbers"):
        messages.send({"goal": object()})


def test_a_priority_out_of_range_is_refused(messages):
    with pytest.raises(MessageLinkError, match=rf"^message link '.*': priority must be in 0\.\.{MAX_PRIORITY}, got: -1$"):
        messages.send("x", priority=-1)


def test_a_bad_capacity_is_refused(transport):
    with pytest.raises(MessageLinkError, match=r"^message link '.*': capacity must be >= 1, got: 0$"):
        transport.messages(capacity=0)


def test_attaching_to_a_missing_message_link_names_it(transport):
    port = getattr(transport, "port", None)
    with pytest.raises(MessageLinkError,
                       match=rf"^no message link '{transport.name}': (nothing answered on tcp/127\.0\.0\.1:{port}: )?"
                             r"has the subsystem that creates it started\?$"):
        transport.attach_messages(transport.name, wait=0)
