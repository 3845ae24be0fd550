"""What happened when in a run (marks, decisions, stable episodes, lock events) and the run's links,
typed from where they are made to report.json: report.json keeps the bytes it had when they were
dicts, and a link reads back from the command line as it was written."""

from __future__ import annotations

import json

import pytest

from pbo_runtime.links.run_link import RunLink, links_from_json, links_to_json
from pbo_runtime.reports.run_records import DecisionTaken, LockEvent, Mark, StableEpisode
from pbo_runtime.reports.run_result import RunResult
from pbo_runtime.supervisor.decisions import decision_lines
from pbo_runtime.supervisor.run_report import marked_episodes

LINKS = {
    "arm_state": RunLink("periodic", "shm", "float64", (6,), shm_name="/pbo.app.r1.link-arm_state"),
    "goal": RunLink("message", "shm", "float64", (6,), 4, shm_name="/pbo.app.r1.msg-goal"),
    "remote": RunLink("periodic", "zenoh", "int32", (2, 3), key="pbo/app/remote", endpoint="tcp/127.0.0.1:7447"),
    "asked": RunLink("message", "zenoh", "float64", (1,), 8, key="pbo/app/asked", endpoint="tcp/10.0.0.2:7448"),
}
DECISIONS = [
    DecisionTaken(0.5, "pick", "if", "then", "q_m[0] > 0.1", {"q_m": [0.2, 0.0]}),
    DecisionTaken(0.75, "pick > try", "try", "fallback", values={}, failure="job 'approach' timed out"),
    DecisionTaken(1.0, "pick", "repeat", turn=1, of=2),
    DecisionTaken(1.5, "pick", "repeat", "again", "x < 1", {"x": 3.0}, turn=2, of=3),
    DecisionTaken(2.5, "pick > wait", "wait", "holds", "x < 1", {"x": [0.5]}, waited=0.125),
]

# report.json's entries as the run wrote them before they were typed, keys in their order
WRITTEN_AS_DICTS = {
    "marks": [{"time": 1.25, "kind": "switch", "label": "to pd"}, {"time": 2.0, "kind": "decision", "label": "if: then"}],
    "decisions": [
        {"time": 0.5, "path": "pick", "kind": "if", "condition": "q_m[0] > 0.1", "values": {"q_m": [0.2, 0.0]},
         "taken": "then"},
        {"time": 0.75, "path": "pick > try", "kind": "try", "taken": "fallback", "failure": "job 'approach' timed out",
         "values": {}},
        {"time": 1.0, "path": "pick", "kind": "repeat", "turn": 1, "of": 2},
        {"time": 1.5, "path": "pick", "kind": "repeat", "turn": 2, "of": 3, "condition": "x < 1", "values": {"x": 3.0},
         "taken": "again"},
        {"time": 2.5, "path": "pick > wait", "kind": "wait", "condition": "x < 1", "values": {"x": [0.5]},
         "taken": "holds", "waited": 0.125},
    ],
    "stable_episodes": [
        {"task": "robot", "from": 1.0, "to": 1.5, "seconds": 0.5, "reason": "stale q_r", "cause": "stale",
         "while_starting": False, "brief": False},
        {"task": "robot", "from": 2.0, "to": None, "seconds": None, "reason": "", "cause": "illegal",
         "while_starting": False, "brief": False},
        {"task": "receive", "from": 0.25, "to": 0.5, "seconds": 0.25, "reason": "", "cause": "module"},
    ],
    "lock_events": [{"pid": 4242, "holder": "RTPU 'rtpu1' (pid 4242)", "role": "rtpu1", "state": "stopped",
                     "held_ms": 312.5, "bound_ms": 250.0, "action": "killed", "at": 3.5}],
    "links": {
        "arm_state": {"kind": "periodic", "transport": "shm", "dtype": "float64", "shape": [6],
                      "object": "/pbo.app.r1.link-arm_state"},
        "goal": {"kind": "message", "transport": "shm", "dtype": "float64", "shape": [6], "capacity": 4,
                 "object": "/pbo.app.r1.msg-goal"},
        "remote": {"kind": "periodic", "transport": "zenoh", "dtype": "int32", "shape": [2, 3], "key": "pbo/app/remote",
                   "endpoint": "tcp/127.0.0.1:7447"},
        "asked": {"kind": "message", "transport": "zenoh", "dtype": "float64", "shape": [1], "capacity": 8,
                  "key": "pbo/app/asked", "endpoint": "tcp/10.0.0.2:7448"},
    },
}


def typed_result() -> RunResult:
    result = RunResult("s", "c", links=dict(LINKS), decisions=list(DECISIONS),
                       marks=[Mark(1.25, "switch", "to pd"), Mark(2.0, "decision", "if: then")],
                       lock_events=[LockEvent(4242, "RTPU 'rtpu1' (pid 4242)", "rtpu1", "stopped", 312.5, 250.0,
                                              "killed", 3.5)])
    held = [StableEpisode("robot", 1.0, 1.5, "stale q_r", "stale"), StableEpisode("robot", 2.0, None, "", "illegal")]
    result.stable_episodes = [*marked_episodes(held, {"robot": 0.001}, 0.5),
                              StableEpisode("receive", 0.25, 0.5, "", "module")]  # (one not marked yet)
    return result


def test_report_json_keeps_the_bytes_it_had_when_the_records_were_dicts():
    written = RunResult("s", "c").to_json()
    written.update(WRITTEN_AS_DICTS)
    assert json.dumps(typed_result().to_json(), indent=2) == json.dumps(written, indent=2)


@pytest.mark.parametrize("name", list(LINKS))
def test_a_link_reads_back_from_the_command_line_as_it_was_written(name):
    assert links_from_json(links_to_json({name: LINKS[name]})) == {name: LINKS[name]}


def test_a_link_that_waits_keeps_its_wait_and_no_links_are_none():
    waiting = RunLink("periodic", "zenoh", "float64", (3,), key="pbo/a/b", endpoint="tcp/127.0.0.1:1", wait=0.5)
    assert links_from_json(links_to_json({"l": waiting})) == {"l": waiting}
    assert links_from_json("{}") == {} == links_from_json("")


def test_links_that_are_not_an_object_are_refused():
    with pytest.raises(ValueError, match=r"^--links takes a JSON object of links by name"):
        links_from_json("[1, 2]")


def test_a_mark_reads_back_from_the_report_as_the_plot_takes_it():
    assert Mark.from_json(Mark(1.5, "job", "approach").to_json()) == Mark(1.5, "job", "approach")


def test_each_kind_of_decision_has_its_summary_line():
    assert decision_lines(DECISIONS) == [
        "decision at 0.500 s (pick): if q_m[0] > 0.1: then (q_m = [0.2, 0.0])",
        "decision at 0.750 s (pick > try): try failed -> fallback: job 'approach' timed out",
        "decision at 1.000 s (pick): repeat 1/2",
        "decision at 1.500 s (pick): repeat 2/3 until x < 1: again (x = 3.0)",
        "decision at 2.500 s (pick > wait): wait x < 1: held after 0.125 s (x = [0.5])",
    ]


def test_an_episode_knows_how_long_it_lasted_and_one_open_at_the_stop_did_not_end():
    assert StableEpisode("robot", 1.0, 1.25, "", "stale").seconds == 0.25
    assert StableEpisode("robot", 1.0, None, "", "stale").seconds is None
