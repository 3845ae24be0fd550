"""Messages between subsystems (TR §5.1) over a POSIX queue: its limits, its permissions, two processes.

Round trips, priorities and what a link refuses are tested over this transport and zenoh alike in
test_link_contract.py.
"""

from __future__ import annotations

import multiprocessing
import os
import stat

import pytest

from pbo_runtime.links.message_link import (
    SYSTEM_CAPACITY,
    LinkFullError,
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


def test_a_full_link_refuses_a_sender_that_asks_not_to_wait(link):
    for k in range(link.capacity):
        link.send(k)
    assert link.waiting == link.capacity == SYSTEM_CAPACITY
    with pytest.raises(LinkFullError) as raised:
        link.send("one too many")
    assert str(raised.value) == (
        f"message link '{link.name}' is full: {link.capacity} of {link.capacity} messages waiting "
        "(the sender asked not to wait)\n"
        "  hint: the receiver is not keeping up: receive more often, send with a timeout to wait for room, "
        f"or create the link with a larger capacity (at most fs.mqueue.msg_max = {SYSTEM_CAPACITY})"
    )
    assert (raised.value.name, raised.value.capacity) == (link.name, link.capacity)
    assert [link.receive(timeout=0).body for _ in range(link.capacity)] == list(range(link.capacity))  # nothing was lost


def test_a_link_longer_than_the_system_allows_fails_with_the_limits():
    if os.geteuid() == 0 and _can_exceed_msg_max():
        pytest.skip("this process may exceed fs.mqueue.msg_max (CAP_SYS_RESOURCE)")
    with pytest.raises(MessageLinkError,
                       match=rf"refused a queue of {SYSTEM_CAPACITY + 1} messages .*\n  hint: at most fs\.mqueue\.msg_max"):
        MessageLink.create(unique_name("msg"), capacity=SYSTEM_CAPACITY + 1)


def _can_exceed_msg_max() -> bool:
    with open("/proc/self/status") as status:
        caps = int(next(line for line in status if line.startswith("CapEff:")).split()[1], 16)
    return bool(caps & (1 << 24))  # CAP_SYS_RESOURCE


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
