"""Typed signals and events: each kind survives its trip over the wire, and the wire stays [kind, (source,) *fields]."""

from __future__ import annotations

import msgpack
import pytest

from pbo_runtime.errors import InternalError
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.limits import QueueSize
from pbo_runtime.ipc.local_queue import CountedQueue
from pbo_runtime.ipc.task_statistics import TaskStatistics
from tests.support import unique_name

SIGNALS = [messages.Spawn("pid"), messages.TurnOn("pid", 0.25, 1), messages.TurnOff("pid"), messages.Kill("pid"),
           messages.Clear("pid"), messages.OperatorEvent("server", [1.0, 2.0]), messages.LinkMessage("server", [[0.5], 3]),
           messages.Watch("robot", 1), messages.StopRtpu(), messages.SendStats(), messages.PlanPosted(),
           messages.LiveUpdate(3)]
EVENTS = [messages.Ready({"cpu": "any"}), messages.Ready(), messages.StateChanged("pid", "ERROR", "boom"),
          messages.Switched(3, "pd", 1.002, 1.002, 1.0021, ["pid"], ["pd"]), messages.Window(3, "robot", 0, 2),
          messages.FirstCycle(3, "pd", 1.002), messages.Stable("robot", True, 2.5, "in-var 'tau_u' is 2.5 ms old", "stale"),
          messages.Stats("pid", TaskStatistics(cycles=7, devices={"spp0": {"items": 3}})),
          messages.PlantStats({"steps": 10, "late": 0}), messages.PlantStalled(2.003, 1.271),
          messages.Refused("pid", "kill: boom"),
          messages.Staged(3), messages.Staged(4, "KeyError: 'nope'"),
          messages.Crashed("RuntimeError: boom", "Traceback ..."), messages.ChildExited("rtpu0", 4242)]


def test_every_signal_and_event_kind_is_in_a_test():
    assert {type(s) for s in SIGNALS} == set(messages.SIGNAL_TYPES.values())
    assert {type(e) for e in EVENTS} == set(messages.EVENT_TYPES.values())


@pytest.mark.parametrize("signal", SIGNALS, ids=lambda s: s.KIND)
def test_a_signal_comes_off_the_wire_as_it_was_sent(signal):
    wire = msgpack.unpackb(msgpack.packb(messages.signal_to_wire(signal)))
    assert wire[0] == signal.KIND and messages.signal_from_wire(wire) == signal


@pytest.mark.parametrize("event", EVENTS, ids=lambda e: e.KIND)
def test_an_event_comes_off_the_wire_with_its_source_as_it_was_sent(event):
    wire = msgpack.unpackb(msgpack.packb(messages.event_to_wire("rtpu1", event)))
    assert wire[:2] == [event.KIND, "rtpu1"] and messages.event_from_wire(wire) == ("rtpu1", event)


def test_trailing_fields_with_a_default_may_be_left_out_on_the_wire():
    assert messages.signal_from_wire(["on", "pid"]) == messages.TurnOn("pid", None, None)
    assert messages.event_from_wire(["ready", "plant"]) == ("plant", messages.Ready(None))


def test_an_unknown_signal_is_left_to_the_rtpu_to_refuse_and_an_unknown_event_is_our_bug():
    assert messages.signal_from_wire(["launch", "pid"]) is None
    with pytest.raises(InternalError, match=r"^an event that is not one of ready, state, .* please report this$"):
        messages.event_from_wire(["launched", "rtpu0"])
    with pytest.raises(InternalError, match=r"^a malformed 'state' event came on the event queue"):
        messages.event_from_wire(["state", "rtpu0"])


def test_a_counted_queue_says_a_signal_waits_for_whichever_of_its_ends_sent_it():
    """`--one-process`: job control's end, the RTPU's and a relay's share one count of what waits."""
    size = QueueSize(unique_name("signals"), 2, 256)
    job_control = CountedQueue(size.name, create=True, size=size)
    rtpu, relay = job_control.another_end(), job_control.another_end()
    try:
        assert not rtpu.pending()
        job_control.signal(messages.Spawn("pid"))
        assert relay.try_send("message", "server", [[0.5], 3], timeout=0.0)
        assert rtpu.pending()
        assert not relay.try_send("message", "server", [[0.5], 4], timeout=0.0)  # full: not sent, not counted
        assert messages.signal_from_wire(rtpu.receive(0)) == messages.Spawn("pid")
        assert rtpu.pending()
        assert rtpu.receive(0) == ["message", "server", [[0.5], 3]]
        assert not rtpu.pending() and rtpu.receive(0) is None
    finally:
        for end in (relay, rtpu, job_control):
            end.close()
