"""Links over eclipse-zenoh (issue 7, item 5): the triple buffer's and the message link's semantics on loopback.

What these tests check, with the two ends in separate processes where it matters:

* periodic: every item read is complete (never torn), counters never go back, a NEW item's
  `lost_in_last_read` is the gap since the previous item read, `new + lost` equals the counter's
  advance from the first item received, the reader reaches the newest item and never reads one
  the sender had not begun, a reader faster than its sender counts reused items, a second
  sender or another payload is refused with a clear error;
* messages: bodies round-trip with their priority and sending time, the highest priority comes
  first and equal priorities in order, a full window raises `LinkFullError` at the sender and
  frees up when the receiver takes messages;
* sessions stay on loopback (no scouting) and close with their link; `open_link` picks the
  transport.

What every transport promises is tested over shared memory and zenoh alike in
test_link_contract.py; here is what is zenoh's own.

Children are spawned, not forked: zenoh's runtime threads do not survive a fork. No test
asserts on time; SAFETY_NET only turns a hang into a failure.
"""

from __future__ import annotations

import multiprocessing
import os
import time

import numpy as np
import pytest

from pbo_runtime.links.ends import open_link, open_message_link
from pbo_runtime.links.message_link import MAX_PRIORITY, LinkFullError, MessageLink, MessageLinkError
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.links.triple_buffer import Freshness, LinkError, LinkLayout, LinkLayoutError, TripleBuffer
from pbo_runtime.links.zenoh_link import DELIVERIES, ITEM_FORMAT, ITEM_HEADER, ZenohLink, open_periodic
from pbo_runtime.links.zenoh_message_link import ZenohMessageLink
from pbo_runtime.links.zenoh_session import config_entries, free_port, link_key
from tests.support import assert_complete, fill, unique_name, until

SPAWN = multiprocessing.get_context("spawn")  # zenoh's threads do not survive a fork
SAFETY_NET = 30.0  # seconds: a broken link fails instead of hanging the suite (no test asserts on time)
VALUES = 512  # 4 KiB of float64 per item: large enough that a torn item would show
ITEM = np.dtype([("counter", "<i8"), ("values", "<f8", (VALUES,)), ("checksum", "<u8")])
ITEM_LAYOUT = LinkLayout(ITEM)
DONE, STARTED = 0, 1  # words of the sender's progress array


def key(part: str) -> str:
    return link_key(f"test-{os.getpid()}-{os.urandom(3).hex()}", part)


def read_until(reader: ZenohLink, counter: int, out: np.ndarray | None = None) -> Freshness:
    """Read until the item with `counter` (or a later one) is read; the last read's freshness."""
    result = [Freshness.NONE]

    def got() -> bool:
        result[0] = reader.read(out)
        return result[0] is not Freshness.NONE and reader.counter >= counter

    until(got, f"item {counter} on '{reader.name}' (read up to {reader.counter})")
    return result[0]


def wait_for_reader(sender: ZenohLink) -> None:
    until(lambda: sender._publisher.matching_status.matching, f"a reader of '{sender.name}'")


# --- one process: the reader's slot, step by step --------------------------------------------------


def item_bytes(layout: LinkLayout, counter: int, value: float, epoch: int = 7, stamp_ns: int = 0) -> bytes:
    payload = np.full(layout.shape, value, dtype=layout.dtype)
    return ITEM_HEADER.pack(ITEM_FORMAT, layout.layout_hash, epoch, counter, stamp_ns, 0) + payload.tobytes()


@pytest.fixture
def lone_reader():
    """A reader with no sender: items are handed to its callback's logic directly."""
    layout = LinkLayout("float64", (6,))
    with ZenohLink.create(key("a"), layout, "reader", port=free_port()) as reader:
        yield reader


def test_the_reader_keeps_only_the_newest_item_and_counts_the_ones_it_lost(lone_reader):
    layout = lone_reader.layout
    assert lone_reader.read() is Freshness.NONE
    for counter in (1, 2, 3):
        lone_reader._take_item(item_bytes(layout, counter, counter, stamp_ns=100 + counter), 0)
    assert lone_reader.read() is Freshness.NEW
    assert (lone_reader.counter, lone_reader.stamp_ns, lone_reader.lost_in_last_read) == (3, 103, 2)
    assert (lone_reader.value == 3.0).all()
    lone_reader._take_item(item_bytes(layout, 2, 2.0), 0)  # a duplicate of an older item changes nothing
    out = np.zeros(6)
    assert lone_reader.read(out) is Freshness.REUSED
    assert (out == 3.0).all()  # a reuse still copies: the caller's array always holds the item
    stats = lone_reader.statistics()
    assert (stats.new, stats.reused, stats.lost, stats.empty) == (1, 1, 2, 1)
    assert (lone_reader.lost, lone_reader.reused) == (stats.lost, stats.reused)  # as TripleBuffer's, for a cycle
    assert stats.new + stats.lost == 3  # the counter's advance from the first item received (1) to 3


def test_items_before_the_first_one_received_are_not_lost(lone_reader):
    lone_reader._take_item(item_bytes(lone_reader.layout, 40, 1.0), 0)
    lone_reader._take_item(item_bytes(lone_reader.layout, 41, 1.0), 0)
    assert lone_reader.read() is Freshness.NEW
    assert (lone_reader.counter, lone_reader.lost_in_last_read) == (41, 1)


def test_a_new_sender_that_starts_over_is_renumbered_so_counters_never_go_back(lone_reader):
    layout = lone_reader.layout
    for counter in range(1, 6):
        lone_reader._take_item(item_bytes(layout, counter, counter, epoch=1), 0)
    lone_reader.read()
    lone_reader._take_item(item_bytes(layout, 1, 10.0, epoch=2), 0)  # a sender that could not ask where to go on from
    assert lone_reader.read() is Freshness.NEW
    assert (lone_reader.counter, lone_reader.lost_in_last_read) == (6, 0)
    lone_reader._take_item(item_bytes(layout, 3, 12.0, epoch=2), 0)
    assert lone_reader.read() is Freshness.NEW
    assert (lone_reader.counter, lone_reader.lost_in_last_read, lone_reader.value[0]) == (8, 1, 12.0)


def test_an_item_of_another_payload_makes_the_read_fail_clearly(lone_reader):
    lone_reader._take_item(item_bytes(LinkLayout("float32", (3,)), 1, 1.0), 0)
    with pytest.raises(LinkLayoutError, match=rf"^link '{lone_reader.name}' carries items of 12 bytes of another payload, "
                                              r"this process expects float64 \(6,\): do both ends declare the same payload\?$"):
        lone_reader.read()


def test_a_delivery_must_be_ring_or_callback():
    with pytest.raises(LinkError, match=r"^link 'pbo/a/b': delivery must be one of ring, callback, got: 'queue'$"):
        ZenohLink.create("pbo/a/b", LinkLayout.raw(8), "reader", port=free_port(), delivery="queue")


# --- one process, two or three sessions over loopback ---------------------------------------------


@pytest.mark.parametrize("delivery", DELIVERIES)
def test_the_creating_end_forwards_between_two_ends_that_attach_to_it(delivery):
    """As when a supervisor makes the link and its tasks attach: the creating session is their hub."""
    name, port, layout = key("hub"), free_port(), LinkLayout("int64", (2,))
    with (ZenohLink.create(name, layout, port=port),
          ZenohLink.attach(name, layout, "reader", port=port, delivery=delivery) as reader,
          ZenohLink.attach(name, layout, "sender", port=port) as sender):
        wait_for_reader(sender)
        assert sender.write([4, 2]) == 1
        read_until(reader, 1)
        assert reader.value.tolist() == [4, 2]


def test_sessions_stay_on_loopback_and_close_with_their_link():
    entries = config_entries(["tcp/127.0.0.1:7000"], [])
    assert entries["scouting/multicast/enabled"] is False and entries["scouting/gossip/enabled"] is False
    assert entries["transport/shared_memory/enabled"] is False
    assert entries["listen/endpoints"] == ["tcp/127.0.0.1:7000"] and entries["connect/endpoints"] == []
    port = free_port()
    link = ZenohLink.create(key("close"), LinkLayout.raw(8), "sender", port=port)
    session = link._session
    assert not session.is_closed()
    link.close()
    assert session.is_closed()
    link.close()  # twice is harmless
    with ZenohLink.create(key("again"), LinkLayout.raw(8), port=port):  # the port is free again
        pass


def test_open_link_chooses_the_transport():
    layout = LinkLayout("float64", (3,))
    name = unique_name("link")
    with open_link("shm", name, layout, "sender", create=True) as shm:
        assert isinstance(shm, TripleBuffer)
    with open_link("zenoh", key("factory"), layout, "sender", create=True, port=free_port()) as over_zenoh:
        assert isinstance(over_zenoh, ZenohLink)
    with open_message_link("shm", unique_name("msg"), create=True, capacity=2) as queue:
        assert isinstance(queue, MessageLink)
    with open_message_link("zenoh", key("msgs"), create=True, port=free_port()) as messages:
        assert isinstance(messages, ZenohMessageLink)
    with pytest.raises(LinkError, match=r"^transport must be one of shm, zenoh, got: 'udp'$"):
        open_link("udp", name, layout, create=True)
    with pytest.raises(LinkError,
                       match=r"^link '.*' uses transport 'shm', which takes no port \(those are for transport 'zenoh'\)$"):
        open_link("shm", name, layout, create=True, port=7447)
    with pytest.raises(LinkError, match=r"^link 'pbo/a/b' uses transport 'zenoh' and needs a port"):
        open_link("zenoh", "pbo/a/b", layout, create=True)


def test_an_application_links_spec_opens_the_sender_listening_and_the_reader_connecting():
    spec = RunLink("periodic", "zenoh", "float64", (3,), key=key("spec"), endpoint=f"tcp/127.0.0.1:{free_port()}")
    layout = LinkLayout("float64", (3,))
    with open_periodic(spec, layout, "sender") as sender, open_periodic(spec, layout, "reader") as reader:
        assert (sender.owner, reader.owner) == (True, False)
        wait_for_reader(sender)
        sender.write([1.0, 2.0, 3.0])
        read_until(reader, 1)
        assert reader.value.tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(LinkError, match=r"^a zenoh link's spec needs 'key' and 'endpoint' \('tcp/<host>:<port>'\), got: "):
        open_periodic(RunLink("periodic", "zenoh", "float64", (3,), key="pbo/a/b", endpoint="udp/127.0.0.1:1"), layout, "reader")


def test_a_message_to_a_receiver_that_left_is_refused_not_lost():
    name, port = key("goals"), free_port()
    receiver = ZenohMessageLink.create(name, port=port)
    with ZenohMessageLink.attach(name, port=port) as sender:
        until(lambda: sender._publisher.matching_status.matching, "the receiver's subscription")
        receiver.close()
        until(lambda: not sender._publisher.matching_status.matching, "the receiver to leave")
        with pytest.raises(MessageLinkError,
                           match=rf"^message link '{name}' has no receiver connected: the message was not sent\n  hint: "):
            sender.send({"x": 1})


# --- two processes ----------------------------------------------------------------------------------


def _hammering_sender(name: str, port: int, n_items: int, progress, control) -> None:
    """Child: items 1..n at full speed, then one more every few ms until told to stop (a DROP may lose the last)."""
    with ZenohLink.attach(name, ITEM_LAYOUT, "sender", port=port) as link:
        until(lambda: link._publisher.matching_status.matching, "the reader")
        counter = 0
        while counter < n_items or not control.poll():
            counter += 1
            fill(link.begin_write(), counter)
            progress[STARTED] = counter
            assert link.publish() == counter
            progress[DONE] = counter
            if counter >= n_items:
                time.sleep(0.005)


@pytest.mark.multiprocess
@pytest.mark.parametrize("delivery", DELIVERIES)
def test_items_from_another_process_arrive_complete_and_the_newest_is_read(delivery):
    name, port, n_items = key("state"), free_port(), 3000
    progress = SPAWN.RawArray("q", 2)
    stop, control = SPAWN.Pipe()
    out = np.zeros((), dtype=ITEM)
    with ZenohLink.create(name, ITEM_LAYOUT, "reader", port=port, delivery=delivery) as reader:
        child = SPAWN.Process(target=_hammering_sender, args=(name, port, n_items, progress, control))
        child.start()
        try:
            previous = previous_stamp = first = 0
            new = lost = reads = 0
            give_up = time.monotonic() + SAFETY_NET
            while previous < n_items:
                freshness = reader.read(out)
                started = progress[STARTED]
                reads += 1
                if freshness is not Freshness.NONE:
                    counter = reader.counter
                    assert_complete(out, counter)
                    assert counter <= started, f"read item {counter}, but the sender had begun only {started}"
                    assert counter >= previous
                    assert (freshness is Freshness.NEW) == (counter > previous)
                    if freshness is Freshness.NEW:
                        if not first:
                            first = counter - reader.lost_in_last_read  # the first item this reader received
                        else:
                            assert reader.lost_in_last_read == counter - previous - 1
                        assert reader.stamp_ns >= previous_stamp
                        new += 1
                        lost += reader.lost_in_last_read
                        previous, previous_stamp = counter, reader.stamp_ns
                assert time.monotonic() < give_up and (child.is_alive() or child.exitcode == 0), (
                    f"the sender stopped (exit code {child.exitcode}) at item {progress[DONE]}, read up to {previous}")
        finally:
            stop.send("stop")
            child.join(SAFETY_NET)
        assert child.exitcode == 0
        stats = reader.statistics()
        assert (stats.new, stats.lost) == (new, lost)
        assert stats.new + stats.lost == previous - first + 1  # every item from the first received was read or counted lost
        assert stats.new + stats.reused + stats.empty == reads


def _lockstep_sender(name: str, port: int, rounds: int, talk) -> None:
    """Child: one item per round, the next only after the reader said it read the previous one twice."""
    with ZenohLink.attach(name, LinkLayout("float64", (6,)), "sender", port=port) as link:
        until(lambda: link._publisher.matching_status.matching, "the reader")
        for counter in range(1, rounds + 1):
            assert link.write(np.full(6, float(counter)), stamp_ns=1000 * counter) == counter
            talk.send(counter)
            assert talk.recv() == counter


@pytest.mark.multiprocess
def test_a_reader_faster_than_its_sender_counts_reused_items():
    name, port, rounds = key("slow"), free_port(), 20
    mine, theirs = SPAWN.Pipe()
    with ZenohLink.create(name, LinkLayout("float64", (6,)), "reader", port=port) as reader:
        child = SPAWN.Process(target=_lockstep_sender, args=(name, port, rounds, theirs))
        child.start()
        try:
            for counter in range(1, rounds + 1):
                assert mine.poll(SAFETY_NET)
                assert mine.recv() == counter
                assert read_until(reader, counter) is Freshness.NEW
                assert (reader.counter, reader.stamp_ns, reader.lost_in_last_read) == (counter, 1000 * counter, 0)
                assert reader.read() is Freshness.REUSED  # the sender has not written again: the same item
                assert (reader.value == counter).all() and reader.counter == counter
                mine.send(counter)
        finally:
            child.join(SAFETY_NET)
        assert child.exitcode == 0
        stats = reader.statistics()
        assert (stats.new, stats.lost) == (rounds, 0)
        assert stats.reused >= rounds


def _attach_with(name: str, port: int, layout: LinkLayout, report) -> None:
    try:
        ZenohLink.attach(name, layout, "sender", port=port).close()
        report.send("attached")
    except (LinkError, LinkLayoutError) as exc:
        report.send(f"{type(exc).__name__}: {exc}")


@pytest.mark.multiprocess
def test_a_sender_in_another_process_with_another_payload_is_refused_clearly():
    name, port = key("mismatch"), free_port()
    mine, theirs = SPAWN.Pipe()
    with ZenohLink.create(name, LinkLayout("float64", (6,)), "reader", port=port):
        child = SPAWN.Process(target=_attach_with, args=(name, port, LinkLayout("float32", (3,)), theirs))
        child.start()
        try:
            assert mine.poll(SAFETY_NET)
            assert mine.recv() == (f"LinkLayoutError: link '{name}' carries float64 (6,), this process expects float32 (3,): "
                                   "do both ends declare the same payload?")
        finally:
            child.join(SAFETY_NET)


BODIES = [{"goal": [0.4, 0.0, 0.3]}, "stop", b"\x00\xff", None, 7, -2.5, [1, [2, {"k": True}]], {"x": 1}]
PRIORITIES = [0, 5, 5, MAX_PRIORITY, 1, 0, 5, 1]


def _message_sender(name: str, port: int, talk) -> None:
    with ZenohMessageLink.attach(name, port=port) as link:
        until(lambda: link._publisher.matching_status.matching, "the receiver")
        for order, (body, priority) in enumerate(zip(BODIES, PRIORITIES, strict=True)):
            link.send({"order": order, "body": body}, priority=priority)
        try:
            link.send("one too many")
            talk.send("sent past the capacity")
        except LinkFullError as exc:
            talk.send(f"{exc.capacity} {exc.message}")
        assert talk.recv() == "go"  # the receiver has taken every message: credits are on their way
        link.send({"order": len(BODIES), "body": "after room"}, priority=2, timeout=SAFETY_NET)  # waits for a credit
        talk.send("sent")
        assert talk.poll(SAFETY_NET)  # stay connected until the receiver has it


@pytest.mark.multiprocess
def test_messages_from_another_process_round_trip_highest_priority_first_and_a_full_window_refuses():
    name, port = key("goals"), free_port()
    mine, theirs = SPAWN.Pipe()
    with ZenohMessageLink.create(name, capacity=len(BODIES), port=port) as receiver:
        child = SPAWN.Process(target=_message_sender, args=(name, port, theirs))
        child.start()
        try:
            assert mine.poll(SAFETY_NET)
            assert mine.recv() == (f"{len(BODIES)} message link '{name}' is full: "
                                   f"{len(BODIES)} of {len(BODIES)} messages waiting (the sender asked not to wait)")
            until(lambda: receiver.waiting == len(BODIES), "every message in the receiver's queue")
            before = time.monotonic_ns()
            received = [receiver.receive(timeout=0) for _ in BODIES]
            expected = sorted(enumerate(PRIORITIES), key=lambda pair: (-pair[1], pair[0]))
            assert [(m.body["order"], m.priority) for m in received] == expected
            assert all(m.body["body"] == BODIES[m.body["order"]] for m in received)
            assert all(m.sent_ns <= before for m in received)
            mine.send("go")
            last = receiver.receive(timeout=SAFETY_NET)  # the sender's window had room again
            assert mine.recv() == "sent"
            assert (last.body, last.priority) == ({"order": len(BODIES), "body": "after room"}, 2)
            assert receiver.receive(timeout=0) is None
            mine.send("done")
        finally:
            child.join(SAFETY_NET)
        assert child.exitcode == 0


# --- clocks of two machines -------------------------------------------------------------------------

SENDER_AHEAD_NS = 1_000 * 10**9  # the sender's CLOCK_MONOTONIC reads 1000 s more than the reader's


@pytest.mark.parametrize("sender_clock_offset_ns", [SENDER_AHEAD_NS, -SENDER_AHEAD_NS, 0])
def test_an_items_local_stamp_is_on_the_readers_clock_whatever_the_senders_clock_reads(lone_reader, sender_clock_offset_ns):
    # Items sent every 2 ms (sender's clock) arrive 0.3 ms, then 0.1 ms, then 5 ms later (reader's clock): the
    # stamps are moved by the smallest (arrival - stamp), so the quickest item's local stamp is its arrival and
    # the late one shows its lateness; the sender's clock offset never makes an item older or younger.
    layout = lone_reader.layout
    arrivals = []
    for counter, (sent_at, transfer) in enumerate([(0, 300_000), (2_000_000, 100_000), (4_000_000, 5_000_000)], start=1):
        arrived = 50 * 10**9 + sent_at + transfer  # the reader's clock
        lone_reader._take_item(item_bytes(layout, counter, counter, stamp_ns=sent_at + 50 * 10**9 + sender_clock_offset_ns),
                               arrived)
        arrivals.append(arrived)
        assert lone_reader.read() is Freshness.NEW
        assert lone_reader.stamp_ns == sent_at + 50 * 10**9 + sender_clock_offset_ns  # the sender's, kept as sent
    # the last item: sent 4 ms after the first, the quickest transfer seen was 0.1 ms
    assert lone_reader.local_stamp_ns == 50 * 10**9 + 4_000_000 + 100_000
    age_at_arrival = (arrivals[-1] - lone_reader.local_stamp_ns) * 1e-9
    assert age_at_arrival == pytest.approx(0.0049)  # 5 ms in transit, less the 0.1 ms any item takes


def test_a_new_sender_brings_a_new_clock_and_its_offset_is_estimated_afresh(lone_reader):
    layout = lone_reader.layout
    lone_reader._take_item(item_bytes(layout, 1, 1.0, epoch=7, stamp_ns=SENDER_AHEAD_NS), 10**9)
    lone_reader.read()
    lone_reader._take_item(item_bytes(layout, 1, 2.0, epoch=8, stamp_ns=5 * 10**9), 2 * 10**9)  # restarted elsewhere
    assert lone_reader.read() is Freshness.NEW
    assert lone_reader.local_stamp_ns == 2 * 10**9  # its own arrival, not the first sender's offset


@pytest.mark.multiprocess
def test_a_reader_that_does_not_wait_opens_before_its_sender_and_reads_once_it_appears():
    name, port, layout = key("later"), free_port(), LinkLayout("float64", (6,))
    with ZenohLink.attach(name, layout, "reader", port=port, wait=None) as reader:  # nothing listens yet
        assert reader.read() is Freshness.NONE
        with ZenohLink.create(name, layout, "sender", port=port) as sender:
            def arrived() -> bool:
                sender.write(np.full(6, 3.0))
                return reader.read() is Freshness.NEW
            until(arrived, "an item from the sender that started after the reader")
            assert (reader.value == 3.0).all()


def test_a_session_that_connects_in_the_background_is_a_peer_that_keeps_trying():
    entries = config_entries([], ["tcp/10.0.0.1:7447"], background=True)
    assert entries["mode"] == "peer" and entries["connect/exit_on_failure"] is False
    assert entries["connect/timeout_ms"] == -1 and entries["scouting/multicast/enabled"] is False
