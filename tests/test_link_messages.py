"""Messages between subsystems (TR §5.1): round trips, priorities, a bounded queue's overflow, cleanup."""

from __future__ import annotations

import multiprocessing
import os
import stat
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pbo_runtime.links.message_link import (
    MAX_PRIORITY,
    SYSTEM_CAPACITY,
    LinkFullError,
    Message,
    MessageLink,
    MessageLinkError,
)
from tests.support import unique_name

FORK = multiprocessing.get_context("fork")
SAFETY_NET = 60.0  # seconds: a broken link fails instead of hanging the suite


@pytest.fixture
def link():
    with MessageLink.create(unique_name("msg")) as made:
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
def test_a_message_round_trips_with_its_priority_and_sending_time(link, body, priority):
    before = time.monotonic_ns()
    link.send(body, priority=priority)
    message = link.receive(timeout=0)
    assert message == Message(body, priority, message.sent_ns)
    assert before <= message.sent_ns <= time.monotonic_ns()
    assert link.receive(timeout=0) is None


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(priorities=st.lists(st.integers(0, 5), min_size=1, max_size=SYSTEM_CAPACITY))
def test_the_highest_priority_comes_first_and_equal_priorities_in_order(link, priorities):
    for order, priority in enumerate(priorities):
        link.send({"order": order}, priority=priority)
    received = [link.receive(timeout=0) for _ in priorities]
    expected = sorted(enumerate(priorities), key=lambda pair: (-pair[1], pair[0]))
    assert [(m.body["order"], m.priority) for m in received] == expected


def test_a_full_link_refuses_a_sender_that_asks_not_to_wait(link):
    for k in range(link.capacity):
        link.send(k)
    assert link.waiting == link.capacity == SYSTEM_CAPACITY
    with pytest.raises(LinkFullError) as raised:
        link.send("one too many")
    assert str(raised.value) == (
        f"message link '{link.name}' is full: {link.capacity} of {link.capacity} messages waiting (the sender asked not to wait)\n"
        "  hint: the receiver is not keeping up: receive more often, send with a timeout to wait for room, "
        f"or create the link with a larger capacity (at most fs.mqueue.msg_max = {SYSTEM_CAPACITY})"
    )
    assert (raised.value.name, raised.value.capacity) == (link.name, link.capacity)
    assert [link.receive(timeout=0).body for _ in range(link.capacity)] == list(range(link.capacity))  # nothing was lost


def test_a_sender_that_waits_gets_the_error_once_the_link_stayed_full():
    with MessageLink.create(unique_name("msg"), capacity=2) as small:
        small.send(1)
        small.send(2)
        with pytest.raises(LinkFullError, match=r"^message link '.*' is full: 2 of 2 messages waiting \(it stayed full for 0\.01 s\)\n  hint: "):
            small.send(3, timeout=0.01)


def test_a_message_too_large_for_the_link_is_refused_before_it_is_sent():
    with MessageLink.create(unique_name("msg"), max_message_bytes=64) as small:
        with pytest.raises(MessageLinkError, match=r"^message link '.*': a message of \d+ bytes \(encoded\) exceeds its 64 bytes\n  hint: send bulk data through a triple buffer"):
            small.send("x" * 100)
        assert small.waiting == 0


def test_a_message_msgpack_cannot_encode_is_refused_with_a_hint(link):
    with pytest.raises(MessageLinkError, match=r"cannot encode the message: .*\n  hint: send dicts, lists, str, bytes, numbers"):
        link.send({"goal": object()})


def test_a_priority_out_of_range_is_refused(link):
    with pytest.raises(MessageLinkError, match=rf"^message link '.*': priority must be in 0\.\.{MAX_PRIORITY}, got: -1$"):
        link.send("x", priority=-1)


def test_a_link_longer_than_the_system_allows_fails_with_the_limits():
    if os.geteuid() == 0 and _can_exceed_msg_max():
        pytest.skip("this process may exceed fs.mqueue.msg_max (CAP_SYS_RESOURCE)")
    with pytest.raises(MessageLinkError, match=rf"refused a queue of {SYSTEM_CAPACITY + 1} messages .*\n  hint: at most fs\.mqueue\.msg_max"):
        MessageLink.create(unique_name("msg"), capacity=SYSTEM_CAPACITY + 1)


def _can_exceed_msg_max() -> bool:
    with open("/proc/self/status") as status:
        caps = int(next(line for line in status if line.startswith("CapEff:")).split()[1], 16)
    return bool(caps & (1 << 24))  # CAP_SYS_RESOURCE


def test_a_bad_capacity_is_refused():
    with pytest.raises(MessageLinkError, match=r"^message link '.*': capacity must be >= 1, got: 0$"):
        MessageLink.create(unique_name("msg"), capacity=0)


def test_attaching_to_a_missing_link_names_it():
    name = unique_name("msg")
    with pytest.raises(MessageLinkError, match=rf"^no message link '{name}': has the subsystem that creates it started\?$"):
        MessageLink.attach(name)


def test_the_queue_is_private_and_the_creator_removes_it():
    name = unique_name("msg")
    path = f"/dev/mqueue/{name[1:]}"
    if not os.path.isdir("/dev/mqueue"):
        pytest.skip("/dev/mqueue is not mounted")
    made = MessageLink.create(name)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    other = MessageLink.attach(name)
    assert (other.capacity, other.max_message_bytes) == (made.capacity, made.max_message_bytes)
    other.close()  # an attached end leaves the queue in place
    assert os.path.exists(path)
    made.close()
    assert not os.path.exists(path)
    made.close()  # twice is harmless


def _echo(requests_name: str, replies_name: str, count: int) -> None:
    """Child: send back each request with twice its priority, until `count` were echoed."""
    with MessageLink.attach(requests_name) as requests, MessageLink.attach(replies_name) as replies:
        for _ in range(count):
            message = requests.receive(timeout=SAFETY_NET)
            replies.send({"echo": message.body, "sent_ns": message.sent_ns}, priority=2 * message.priority, timeout=SAFETY_NET)


@pytest.mark.multiprocess
def test_messages_round_trip_between_two_processes():
    bodies = [None, True, -3, 2.5, "goal", b"\x00\xff", [1, [2, 3]], {"x": [0.1, 0.2, 0.3], "frame": "base"}]
    with MessageLink.create(unique_name("req")) as requests, MessageLink.create(unique_name("rep")) as replies:
        child = FORK.Process(target=_echo, args=(requests.name, replies.name, len(bodies)))
        child.start()
        try:
            for priority, body in enumerate(bodies):
                requests.send(body, priority=priority, timeout=SAFETY_NET)
                reply = replies.receive(timeout=SAFETY_NET)
                assert reply is not None and reply.priority == 2 * priority
                assert reply.body["echo"] == body
                assert reply.body["sent_ns"] <= reply.sent_ns  # one clock for both processes
        finally:
            child.join(SAFETY_NET)
        assert child.exitcode == 0
