"""Messages between subsystems (TR §5.1): the sending module, the relay that wakes a server, the server.

Real POSIX queues and a real table throughout; the task runs in this process (no RTPU), so
its cycles are called by hand.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from modules.message_sender import MessageSender
from modules.message_server import MessageServer
from pbo_runtime.ipc import messages
from pbo_runtime.links.message_link import MessageLink
from pbo_runtime.links.relay import MessageRelay
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.table.table import TaskState
from pbo_runtime.task.background import process_background
from tests.support import make_task, unique_name, variables


@pytest.fixture
def goal_link():
    link = MessageLink.create(unique_name("msg-goal"), capacity=3)
    yield link
    link.close()


def link_spec(link: MessageLink) -> RunLink:
    return RunLink("message", "shm", "float64", (3,), 3, shm_name=link.name)


@pytest.fixture
def sender(make_table, goal_link):
    table = make_table(variables(("goal", "float64", (3,)), ("message_counts", "float64", (2,))))
    task = make_task(table, MessageSender, "console", {"value": ("goal", (3,)), "counts": ("message_counts", (2,))},
                     {"goal": link_spec(goal_link)})
    task.spawn(0.0)
    task.turn_on(0.0)
    yield table, task
    if task.state != TaskState.KILLED:
        task.kill()


def test_the_sender_sends_its_value_at_the_first_cycle_and_then_only_when_it_changes(sender, goal_link):
    table, task = sender
    for step in range(3):
        task.run_cycle(0.01 * step)
    table.write("goal", np.array([0.3, -0.5, 0.5]), when=0.03, writer=-1)
    task.run_cycle(0.03)
    task.run_cycle(0.04)
    bodies = [goal_link.receive(0).body for _ in range(goal_link.waiting)]
    assert bodies == [[0.0, 0.0, 0.0], [0.3, -0.5, 0.5]]
    assert list(table.read("message_counts")[0]) == [2.0, 0.0]


def test_a_full_queue_puts_the_send_off_and_counts_it_and_the_value_goes_later(sender, goal_link):
    table, task = sender
    for k in range(5):  # 5 changes into a queue of 3: two are put off, nothing raises
        table.write("goal", np.full(3, float(k + 1)), when=0.01 * k, writer=-1)
        task.run_cycle(0.01 * k)
    assert task.state == TaskState.ON and list(table.read("message_counts")[0]) == [3.0, 2.0]
    assert [goal_link.receive(0).body[0] for _ in range(3)] == [1.0, 2.0, 3.0]
    task.run_cycle(0.05)  # room again: the pending value goes, the newest one
    assert goal_link.receive(0).body == [5.0, 5.0, 5.0]
    assert list(table.read("message_counts")[0]) == [4.0, 2.0]


def test_a_message_link_without_its_application_names_what_to_run(make_table, goal_link):
    table = make_table(variables(("goal", "float64", (3,)), ("message_counts", "float64", (2,))))
    task = make_task(table, MessageSender, "console", {"value": ("goal", (3,)), "counts": ("message_counts", (2,))}, {})
    assert not task.spawn(0.0)
    assert "opens link 'goal', but the application provides no such link" in task.last_error


def test_the_relay_forwards_each_message_to_the_rtpu_signal_queue_highest_priority_first(goal_link):
    signals = messages.Queue(unique_name("signals-rtpu0"), create=True)
    try:
        goal_link.send([1.0], priority=0)
        goal_link.send([9.0], priority=5)
        relay = MessageRelay(MessageLink.attach(goal_link.name), signals.name, "goal")
        received = [signals.receive(2.0) for _ in range(2)]
        goal_link.send([2.0])
        received.append(signals.receive(2.0))
        relay.close()
        assert [m[:2] for m in received] == [["message", "goal"]] * 3
        assert [m[2][0] for m in received] == [[9.0], [1.0], [2.0]]
        assert all(isinstance(m[2][1], int) and m[2][1] > 0 for m in received)  # the sending time stamp, ns
        assert relay.forwarded == 3 and not relay._thread.is_alive()
    finally:
        signals.close()


def test_the_simulated_clocks_relay_forwards_what_the_link_holds_only_when_pumped(goal_link):
    signals = messages.Queue(unique_name("signals-rtpu0"), create=True)
    try:
        relay = MessageRelay(MessageLink.attach(goal_link.name), signals.name, "goal", threaded=False)
        goal_link.send([1.0])
        goal_link.send([2.0])
        assert signals.receive(0.2) is None  # no thread: nothing moves between steps
        relay.pump()
        assert [signals.receive(0)[2][0] for _ in range(2)] == [[1.0], [2.0]] and relay.forwarded == 2
        relay.close()
        goal_link.send([3.0])
        relay.pump()  # closed: its task was killed
        assert signals.receive(0) is None and relay.forwarded == 2
    finally:
        signals.close()


def test_a_server_needs_an_rtpu_to_wake_it(make_table, goal_link):
    table = make_table(variables(("q_d", "float64", (3,))))
    task = make_task(table, MessageServer, "goal", {"value": ("q_d", (3,))}, {"goal": link_spec(goal_link)}, aperiodic=True)
    assert not task.spawn(0.0)
    assert "serves link 'goal', but no RTPU hosts it to wake it" in task.last_error


class RecordingRelay:
    """Fake relay for a unit test: records what the task asked to be woken for; the real one is tested above."""

    def __init__(self, task: str, end) -> None:
        self.task, self.end, self.closed = task, end, False

    def close(self) -> None:
        self.closed = True
        self.end.close()


def test_the_server_writes_each_message_and_a_malformed_one_is_a_fault_that_keeps_the_last_good_value(make_table, goal_link):
    table = make_table(variables(("q_d", "float64", (3,))))
    relays: list[RecordingRelay] = []
    task = make_task(table, MessageServer, "goal", {"value": ("q_d", (3,))}, {"goal": link_spec(goal_link)},
                     relay=lambda name, end: relays.append(RecordingRelay(name, end)) or relays[-1], aperiodic=True)
    assert task.spawn(0.0) and task.turn_on(0.0)
    assert relays[0].task == "goal" and isinstance(relays[0].end, MessageLink)
    task.context.event = [[0.3, -0.5, 0.5], 123]
    task.run_cycle(0.01)
    assert list(table.read("q_d")[0]) == [0.3, -0.5, 0.5]
    task.context.event = [[1.0, 2.0], 124]
    task.run_cycle(0.02)
    assert task.state == TaskState.ERROR and "must hold 3 finite numbers, got: [1.0, 2.0]" in task.last_error
    assert list(table.read("q_d")[0]) == [0.3, -0.5, 0.5]
    task.kill()
    assert relays[0].closed


def test_a_relay_stops_promptly_while_its_link_is_quiet(goal_link):
    signals = messages.Queue(unique_name("signals-rtpu0"), create=True)
    try:
        relay = MessageRelay(MessageLink.attach(goal_link.name), signals.name, "goal")
        closing = threading.Thread(target=relay.close)
        closing.start()
        closing.join(timeout=5)
        assert not closing.is_alive() and not relay._thread.is_alive() and relay.forwarded == 0
    finally:
        signals.close()


def test_a_killed_servers_relay_is_joined_and_closed_in_the_background_thread_not_by_the_kill(make_table, goal_link):
    table = make_table(variables(("q_d", "float64", (3,))))
    signals = messages.Queue(unique_name("signals-rtpu0"), create=True)
    relays: list[MessageRelay] = []
    try:
        task = make_task(table, MessageServer, "goal", {"value": ("q_d", (3,))}, {"goal": link_spec(goal_link)},
                         relay=lambda name, end: relays.append(MessageRelay(end, signals.name, name)) or relays[-1],
                         aperiodic=True)
        assert task.spawn(0.0) and task.turn_on(0.0)
        gate = threading.Event()
        process_background().hand_off(gate.wait, "test", "holding the background thread")
        task.kill()  # returns though the relay's thread still forwards: its join waits behind the gate
        assert task.state == TaskState.KILLED and relays[0]._thread.is_alive() and not relays[0].closed
        gate.set()
        assert process_background().drain()
        assert relays[0].closed and not relays[0]._thread.is_alive()
    finally:
        signals.close()
