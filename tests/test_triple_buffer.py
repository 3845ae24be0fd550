"""The triple buffer of periodic links (TR §5.2, Figure 15): protocol, layout, and two processes hammering it.

What the protocol guarantees, and what these tests check:

* complete: an item read is exactly one item as the sender wrote it (never torn);
* newest: a read returns the item of the last publish whose swap preceded the read's swap; so
  between two processes, `done <= counter <= started`, where `done` is the last counter whose
  `publish` had returned before the read began and `started` the last counter whose `publish`
  had begun when the read ended;
* counters never go back; `new + lost` equals the counter's advance;
* neither side waits for the other's copy: a sender completes any number of writes while a read
  is held open, and a reader any number of reads while a write is held open.

What every transport promises (reads, reuses, losses, stamps, roles, payload mismatch) is tested
over this one and zenoh in test_link_contract.py; here are the protocol's own steps and processes.
"""

from __future__ import annotations

import multiprocessing
import os
import random
import stat
import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pbo_runtime.links.triple_buffer import (
    NO_SLOT,
    Freshness,
    LinkLayout,
    LinkLayoutError,
    TripleBuffer,
    Word,
)
from tests.support import assert_complete, checksum, fill, unique_name

FORK = multiprocessing.get_context("fork")  # children start in milliseconds; each attaches by name
VALUES = 2048  # 16 KiB of float64 per item: copies long enough for a protocol bug to tear one
ITEM = np.dtype([("counter", "<i8"), ("values", "<f8", (VALUES,)), ("checksum", "<u8")])
ITEM_LAYOUT = LinkLayout(ITEM)
DONE, STARTED = 0, 1  # words of the sender's progress array
SAFETY_NET = 60.0  # seconds: a broken protocol fails instead of hanging the suite (no test asserts on time)


@pytest.fixture
def link_pair():
    """A float64[6] link created by its sender, with a reader attached; both closed after the test."""
    name = unique_name("link")
    layout = LinkLayout("float64", (6,))
    sender = TripleBuffer.create(name, layout, "sender")
    reader = TripleBuffer.attach(name, layout, "reader")
    yield sender, reader
    reader.close()
    sender.close()


# --- one process: the protocol step by step ---------------------------------------------------


def test_a_reader_attached_late_does_not_count_earlier_items_as_lost():
    name = unique_name("link")
    layout = LinkLayout("int64", (2,))
    with TripleBuffer.create(name, layout, "sender") as sender:
        for k in range(1, 6):
            sender.write([k, k])
        with TripleBuffer.attach(name, layout, "reader") as reader:
            reader.read()
            assert (reader.counter, reader.lost_in_last_read) == (5, 0)
            sender.write([6, 6])
            sender.write([7, 7])
            reader.read()
            assert (reader.counter, reader.lost_in_last_read) == (7, 1)


def test_the_sender_never_fills_the_slot_a_read_holds_open(link_pair):
    sender, reader = link_pair
    sender.write(np.full(6, 1.0))
    slot = reader._take()  # the read's swap: from here on its copy needs no lock
    for k in range(2, 1002):  # the sender goes on at full speed, never waiting
        sender.write(np.full(6, float(k)))
    out = np.zeros(6)
    assert reader._copy_out(slot, out) is Freshness.NEW
    assert (out == 1.0).all() and reader.counter == 1
    assert reader.read() is Freshness.NEW and reader.counter == 1001
    assert sender.statistics().contended == reader.statistics().contended == 0


def test_the_torn_item_check_catches_a_half_written_item():
    item = np.zeros((), dtype=ITEM)
    fill(item, 5)
    item["values"][VALUES // 2 :] = 6
    with pytest.raises(AssertionError, match=r"^torn item"):
        assert_complete(item, 5)


class _Model:
    """What the protocol promises, for an interleaving of the sender's and the reader's steps."""

    def __init__(self) -> None:
        self.next_counter = 1
        self.chunks_filled = 0
        self.newest = 0  # counter of the newest published item
        self.taken: int | None = None  # counter that was newest at the reader's last swap
        self.last_read = 0


CHUNKS = 4
CHUNK = 16


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(steps=st.lists(st.sampled_from(["fill", "publish", "take", "copy", "read"]), max_size=120))
def test_any_interleaving_of_the_two_sides_reads_complete_newest_items(steps):
    """Each side's steps are atomic here; the interleaving between them is hypothesis's to choose.

    The sender fills its slot in chunks (a copy in progress) and publishes it; the reader's swap (`take`) and its
    copy are separate steps: whatever comes between them, the copy gets the complete item that
    was newest at the swap, and the slot indices keep their invariant.
    """
    name = unique_name("link")
    layout = LinkLayout("int64", (CHUNKS * CHUNK,))
    model = _Model()
    out = np.zeros(CHUNKS * CHUNK, dtype=np.int64)
    with TripleBuffer.create(name, layout, "sender") as sender, TripleBuffer.attach(name, layout, "reader") as reader:
        slot = NO_SLOT
        for step in steps:
            if step == "fill" and model.chunks_filled < CHUNKS:
                view = sender.begin_write()
                start = model.chunks_filled * CHUNK
                view[start : start + CHUNK] = model.next_counter
                del view
                model.chunks_filled += 1
            elif step == "publish":  # the rest of the copy, then the swap
                sender.begin_write()[model.chunks_filled * CHUNK :] = model.next_counter
                assert sender.publish() == model.next_counter
                model.newest = model.next_counter
                model.next_counter += 1
                model.chunks_filled = 0
            elif step == "take":
                slot = reader._take()
                model.taken = model.newest
                assert (slot == NO_SLOT) == (model.newest == 0)
            elif step in ("copy", "read"):
                if step == "read":
                    slot = reader._take()
                    model.taken = model.newest
                if model.taken is None or slot == NO_SLOT:
                    continue
                freshness = reader._copy_out(slot, out)
                expected = model.taken
                assert (out == expected).all(), f"read {out.min()}..{out.max()}, expected {expected}"
                assert reader.counter == expected >= model.last_read
                if expected == model.last_read:
                    assert freshness is Freshness.REUSED
                else:
                    assert freshness is Freshness.NEW
                    assert reader.lost_in_last_read == expected - model.last_read - 1
                    model.last_read = expected
                model.taken = None
            h = sender._header
            assert h[Word.WRITING] not in (h[Word.NEWEST], h[Word.READING])
            assert h[Word.WRITING] == sender._writing
        stats = reader.statistics()
        assert stats.new + stats.lost == model.last_read


# --- layouts, names, roles ----------------------------------------------------------------------

LAYOUTS = st.builds(
    LinkLayout,
    st.sampled_from(["float64", "float32", "int64", "uint8", "int16", "<f8", ">f8", "bool"]),
    st.lists(st.integers(1, 5), max_size=3).map(tuple),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(created=LAYOUTS, expected=LAYOUTS)
def test_attaching_with_another_payload_fails_clearly_and_the_same_one_round_trips(created, expected):
    name = unique_name("link")
    with TripleBuffer.create(name, created, "sender") as sender:
        value = np.arange(created.size).reshape(created.shape).astype(created.dtype)
        sender.write(value)
        if created.layout_hash != expected.layout_hash:
            with pytest.raises(LinkLayoutError, match=rf"^link '{name}' carries .*, this process expects .*: do both ends"):
                TripleBuffer.attach(name, expected, "reader")
            return
        with TripleBuffer.attach(name, expected, "reader") as reader:
            assert reader.read() is Freshness.NEW
            assert reader.value.dtype == created.dtype and reader.value.shape == created.shape
            assert (reader.value == value).all()


def test_a_payload_of_python_objects_or_no_bytes_is_refused():
    with pytest.raises(LinkLayoutError, match=r"holds Python objects"):
        LinkLayout(object, (3,))
    with pytest.raises(LinkLayoutError, match=r"^payload must have at least one byte, got: float64 \(0,\)$"):
        LinkLayout("float64", (0,))


def test_the_segment_and_its_lock_are_private_and_the_creator_removes_them():
    name = unique_name("link")
    segment, lock = f"/dev/shm/{name[1:]}", f"/dev/shm/sem.{name[1:]}.lock"
    link = TripleBuffer.create(name, LinkLayout.raw(48))
    assert stat.S_IMODE(os.stat(segment).st_mode) == 0o600
    assert stat.S_IMODE(os.stat(lock).st_mode) == 0o600
    other = TripleBuffer.attach(name, LinkLayout.raw(48))
    other.close()  # an attached end leaves the link in place
    assert os.path.exists(segment) and os.path.exists(lock)
    link.close()
    assert not os.path.exists(segment) and not os.path.exists(lock)
    link.close()  # twice is harmless


# --- two processes ------------------------------------------------------------------------------


def _exit_holding(name: str, layout: LinkLayout, role: str | None, hold_lock: bool) -> None:
    """Child: take a role (and perhaps the lock), then die without releasing anything."""
    link = TripleBuffer.attach(name, layout, role)
    if role == "sender":
        link.write(np.full(layout.shape, 2, dtype=layout.dtype))
    if hold_lock:
        link._acquire()
    os._exit(0)


def _run_child(target, *args) -> None:
    child = FORK.Process(target=target, args=args)
    child.start()
    child.join(SAFETY_NET)
    assert child.exitcode == 0


@pytest.mark.multiprocess
def test_a_lock_whose_holder_died_is_recovered_by_the_other_side():
    name = unique_name("link")
    layout = LinkLayout("int64", (4,))
    with TripleBuffer.create(name, layout, "reader") as reader:
        _run_child(_exit_holding, name, layout, "sender", True)
        assert reader.read() is Freshness.NEW  # waits, finds the holder dead, releases its lock
        assert (reader.value == 2).all()
        stats = reader.statistics()
        assert stats.lock_recoveries == 1 and stats.contended == 1
        with TripleBuffer.attach(name, layout, "sender") as sender:  # the dead sender's role is free
            sender.write(np.full(4, 3))
            assert reader.read() is Freshness.NEW and reader.counter == 2


@pytest.mark.multiprocess
def test_a_sender_taking_over_from_one_that_died_mid_swap_picks_a_free_slot():
    name = unique_name("link")
    layout = LinkLayout("int64", (4,))
    with TripleBuffer.create(name, layout, "reader") as reader:
        _run_child(_exit_holding, name, layout, "sender", False)
        reader.read()
        h = reader._header
        h[Word.WRITING] = h[Word.NEWEST]  # as if it died after half of its swap
        with TripleBuffer.attach(name, layout, "sender") as sender:
            assert sender._writing not in (h[Word.NEWEST], h[Word.READING])
            assert sender.write(np.full(4, 5)) == 2  # it goes on from the dead sender's counter
        assert reader.read() is Freshness.NEW and (reader.value == 5).all()


@pytest.mark.multiprocess
def test_a_lock_whose_holder_is_a_zombie_is_recovered_by_the_other_side():
    # Regression (issue 17): ipc.shm.pid_alive counted a zombie (dead, not yet reaped) as alive, so
    # the reader waited for ever on the lock of a sender whose parent had not reaped it yet.
    name = unique_name("link")
    layout = LinkLayout("int64", (4,))
    with TripleBuffer.create(name, layout, "reader") as reader:
        child = FORK.Process(target=_exit_holding, args=(name, layout, "sender", True))
        child.start()
        try:
            os.waitid(os.P_PID, child.pid, os.WEXITED | os.WNOWAIT)  # it has died; nobody reaps it yet
            got: list[Freshness] = []
            reading = threading.Thread(target=lambda: got.append(reader.read()), daemon=True)
            reading.start()
            reading.join(SAFETY_NET)
            assert got == [Freshness.NEW] and (reader.value == 2).all()
            assert reader.statistics().lock_recoveries == 1
            with TripleBuffer.attach(name, layout, "sender") as sender:  # the zombie's role is free as well
                sender.write(np.full(4, 3))
        finally:
            child.join(SAFETY_NET)


def _hammer_sender(name: str, n_items: int, pause_probability: float, max_pause: float, seed: int, progress) -> None:
    rng = random.Random(seed)
    link = TripleBuffer.attach(name, ITEM_LAYOUT, "sender")
    try:
        for counter in range(1, n_items + 1):
            fill(link.begin_write(), counter)
            progress[STARTED] = counter
            link.publish()
            progress[DONE] = counter
            if pause_probability and rng.random() < pause_probability:
                time.sleep(rng.uniform(0, max_pause))
    finally:
        link.close()


PROFILES = {
    # name: (items, sender pause probability, sender max pause s, reader pause probability, reader max pause s)
    "both_at_full_speed": (20000, 0.0, 0.0, 0.0, 0.0),
    "reader_much_slower": (20000, 0.0, 0.0, 1.0, 0.002),
    "sender_much_slower": (200, 1.0, 0.002, 0.0, 0.0),
    "random_pauses_on_both_sides": (5000, 0.02, 0.002, 0.02, 0.002),
}


@pytest.mark.multiprocess
@pytest.mark.parametrize("profile", PROFILES)
def test_two_processes_hammering_a_link_read_only_complete_newest_items(profile):
    n_items, send_p, send_pause, read_p, read_pause = PROFILES[profile]
    rng = random.Random(profile)
    name = unique_name("link")
    progress = FORK.RawArray("q", 2)
    out = np.zeros((), dtype=ITEM)
    with TripleBuffer.create(name, ITEM_LAYOUT, "reader") as reader:
        child = FORK.Process(target=_hammer_sender, args=(name, n_items, send_p, send_pause, rng.randrange(1 << 30), progress))
        child.start()
        try:
            reads = new = lost_seen = previous = 0
            previous_stamp = 0
            give_up = time.monotonic() + SAFETY_NET
            while previous < n_items:
                done = progress[DONE]
                freshness = reader.read(out)
                started = progress[STARTED]
                reads += 1
                if freshness is Freshness.NONE:
                    assert done == 0, f"nothing read although item {done} was published before the read"
                else:
                    counter = reader.counter
                    assert_complete(out, counter)
                    assert done <= counter <= started, f"read {counter}: newest done before it was {done}, started {started}"
                    assert counter >= previous
                    assert (freshness is Freshness.NEW) == (counter > previous)
                    if freshness is Freshness.NEW:
                        assert reader.lost_in_last_read == counter - previous - 1
                        assert reader.stamp_ns >= previous_stamp
                        new += 1
                        lost_seen += reader.lost_in_last_read
                        previous, previous_stamp = counter, reader.stamp_ns
                if read_p and rng.random() < read_p:
                    time.sleep(rng.uniform(0, read_pause))
                if time.monotonic() > give_up or (not child.is_alive() and child.exitcode != 0):
                    pytest.fail(f"the sender stopped (exit code {child.exitcode}) after item {progress[DONE]}")
        finally:
            child.join(SAFETY_NET)
        assert child.exitcode == 0
        stats = reader.statistics()
        assert stats.new == new and stats.lost == lost_seen
        assert stats.new + stats.lost == n_items  # every item was either read or counted lost
        assert stats.new + stats.reused + stats.empty == reads


def _writes_while_read_is_open(name: str, n_items: int, read_open, finished, written) -> None:
    link = TripleBuffer.attach(name, ITEM_LAYOUT, "sender")
    try:
        fill(link.begin_write(), 1)
        link.publish()
        read_open.wait(SAFETY_NET)
        for counter in range(2, n_items + 2):
            fill(link.begin_write(), counter)
            link.publish()
            written.value = counter
        finished.set()
    finally:
        link.close()


@pytest.mark.multiprocess
def test_a_sender_process_completes_its_writes_while_the_reader_holds_a_read_open():
    """The bound on the sender's write time, structurally: no write of it waits for the reader's copy."""
    name = unique_name("link")
    n_items = 2000
    read_open, finished = FORK.Event(), FORK.Event()
    written = FORK.RawValue("q", 0)
    out = np.zeros((), dtype=ITEM)
    with TripleBuffer.create(name, ITEM_LAYOUT, "reader") as reader:
        child = FORK.Process(target=_writes_while_read_is_open, args=(name, n_items, read_open, finished, written))
        child.start()
        try:
            while (slot := reader._take()) == NO_SLOT:
                time.sleep(0.001)
            read_open.set()  # the reader is now "copying" item 1, for as long as the sender needs
            assert finished.wait(SAFETY_NET), f"the sender stopped at item {written.value} while a read was open"
            assert written.value == n_items + 1
            assert reader._copy_out(slot, out) is Freshness.NEW
            assert_complete(out, 1)  # the slot held open was never touched by 2000 writes
            assert reader.read(out) is Freshness.NEW
            assert_complete(out, n_items + 1)
            assert reader.lost_in_last_read == n_items - 1
        finally:
            child.join(SAFETY_NET)
        assert child.exitcode == 0


def _holds_a_write_open(name: str, write_open, go_on) -> None:
    link = TripleBuffer.attach(name, ITEM_LAYOUT, "sender")
    try:
        fill(link.begin_write(), 1)
        link.publish()
        item = link.begin_write()
        item["counter"] = 2
        item["values"][: VALUES // 2] = 2  # half of item 2 is written...
        write_open.set()
        go_on.wait(SAFETY_NET)  # ...and the sender stalls in the middle of its copy
        item["values"][VALUES // 2 :] = 2
        item["checksum"] = checksum(2)
        del item
        link.publish()
    finally:
        link.close()


@pytest.mark.multiprocess
def test_a_reader_process_completes_its_reads_while_the_sender_holds_a_write_open():
    name = unique_name("link")
    write_open, go_on = FORK.Event(), FORK.Event()
    out = np.zeros((), dtype=ITEM)
    with TripleBuffer.create(name, ITEM_LAYOUT, "reader") as reader:
        child = FORK.Process(target=_holds_a_write_open, args=(name, write_open, go_on))
        child.start()
        try:
            assert write_open.wait(SAFETY_NET)
            for _ in range(1000):
                assert reader.read(out) in (Freshness.NEW, Freshness.REUSED)
                assert_complete(out, 1)
            go_on.set()
            child.join(SAFETY_NET)
            assert reader.read(out) is Freshness.NEW
            assert_complete(out, 2)
        finally:
            go_on.set()
            child.join(SAFETY_NET)
        assert child.exitcode == 0
        assert reader.statistics().reused == 999
