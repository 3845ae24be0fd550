"""The control queue: a supervisor serves operator requests between ticks; a client finds the run and asks.

Server and client run in one process over real POSIX queues; a thread plays the supervisor.
Fake live runs are table segments named with this test process's pid, which is alive.
"""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import posix_ipc
import pytest
from rich.console import Console

from pbo_runtime import PboError
from pbo_runtime.cli import operator
from pbo_runtime.cli.main import main
from pbo_runtime.config.loader import load_subsystem
from pbo_runtime.errors import InternalError
from pbo_runtime.ipc import messages, runs, shm
from pbo_runtime.ipc.control import (
    MAX_REQUESTS_PER_POLL,
    BadRequest,
    CommandRefused,
    ControlClient,
    ControlServer,
    control_queue_name,
    find_live_run,
    reply_queue_prefix,
)
from pbo_runtime.supervisor.commands import dispatch
from pbo_runtime.table.table import StateTable, TableLayout
from tests.fake_job_host import FakeJobHost
from tests.support import REPO, variables


def _queue_exists(name: str) -> bool:
    try:
        posix_ipc.MessageQueue(name).close()
        return True
    except posix_ipc.ExistentialError:
        return False


def new_run_id(pid: int | None = None) -> str:
    return f"{pid or os.getpid()}-{uuid.uuid4().hex[:6]}"


def new_subsystem() -> str:
    return f"ctl{uuid.uuid4().hex[:6]}"


@pytest.fixture
def fake_run() -> Iterator[Any]:
    """Make fake live runs: a small real table named like a run's, with this process's pid."""
    made: list[StateTable] = []

    def make(subsystem: str, run_id: str | None = None) -> tuple[str, str, StateTable]:
        run_id = run_id or new_run_id()
        layout = TableLayout.build(variables(("q_m", "float64", (3,)), ("n", "int32", ())), 2)
        table = StateTable.create(layout, messages.table_name(subsystem, run_id))
        made.append(table)
        return subsystem, run_id, table

    yield make
    for table in made:
        table.close()


@pytest.fixture
def server() -> Iterator[ControlServer]:
    control = ControlServer(new_subsystem(), new_run_id())
    yield control
    control.close()


class FakeSupervisor:
    """Answers like job control would, serving the queue from a thread between short 'ticks'."""

    def __init__(self, server: ControlServer) -> None:
        self.server = server
        self.handled: list[tuple[str, dict[str, Any]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)

    def handle(self, command: str, arguments: dict[str, Any]) -> dict[str, Any]:
        self.handled.append((command, arguments))
        if command == "status":
            return {"subsystem": self.server.subsystem, "run_id": self.server.run_id, "configuration": "joint_pid",
                    "job": "move", "application": None, "elapsed": 12.5, "flags": [],
                    "tasks": [
                        {"task": "robot", "index": 0, "rtpu": "rtpu1", "state": "ON", "cycles": 12500, "rate": 1000.0,
                         "overruns": 0, "missed": 1, "jitter_p50": 5e-6, "jitter_p99": 40e-6, "jitter_max": 90e-6,
                         "exec_last": 12e-6, "exec_p50": 11e-6, "exec_p99": 20e-6, "error": ""},
                        {"task": "pid", "index": 1, "rtpu": "rtpu0", "state": "ERROR", "cycles": 300, "rate": 0.0,
                         "overruns": 2, "jitter_max": 1.5e-3, "exec_last": 30e-6, "error": "gain matrix is singular"},
                    ]}
        if command == "on":
            if arguments["task"] == "pid":
                raise PboError("task 'pid' is in ERROR: clear it first")
            return {"task": arguments["task"], "state": "ON"}
        if command == "job":
            return {"job": arguments["job"], "configuration": "joint_pid"}
        if command == "fail":
            raise ValueError("period must be > 0, got: -5 ms")
        if command == "missing":
            raise KeyError("no configuration 'fast' (configurations: joint_pid)")
        if command == "crash":
            raise RuntimeError("boom")
        if command == "numpy":
            import numpy as np

            return {"value": np.arange(3.0), "count": np.int64(3)}
        return {"echo": arguments}

    def _serve(self) -> None:
        while not self._stop.is_set():
            self.server.poll(self.handle)
            self._stop.wait(0.001)

    def __enter__(self) -> FakeSupervisor:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


def client_of(server: ControlServer) -> ControlClient:
    return ControlClient(server.subsystem, server.run_id)


# --- requests and replies -------------------------------------------------------------------


def test_a_request_gets_the_handlers_reply(server):
    with FakeSupervisor(server) as supervisor:
        reply = client_of(server).request("echo", {"task": "pid", "values": [0.3, -0.5]})
    assert reply == {"ok": True, "echo": {"task": "pid", "values": [0.3, -0.5]}}
    assert supervisor.handled == [("echo", {"task": "pid", "values": [0.3, -0.5]})]


def test_numpy_values_in_a_reply_travel_as_numbers_and_lists(server):
    with FakeSupervisor(server):
        assert client_of(server).request("numpy") == {"ok": True, "value": [0.0, 1.0, 2.0], "count": 3}


@pytest.mark.parametrize(("command", "message"), [
    ("fail", "period must be > 0, got: -5 ms"),
    ("missing", "no configuration 'fast' (configurations: joint_pid)"),
])
def test_a_handler_error_becomes_a_refusal_with_its_message(server, command, message):
    with FakeSupervisor(server):
        assert client_of(server).request(command) == {"ok": False, "error": message}


def test_an_unexpected_handler_exception_is_reported_and_does_not_escape_poll(server):
    with FakeSupervisor(server):
        client = client_of(server)
        reply = client.request("crash")
        assert reply["ok"] is False
        assert reply["error"] == "internal error in the supervisor serving 'crash' (please report this): RuntimeError: boom"
        assert client.request("echo") == {"ok": True, "echo": {}}  # still serving


def test_call_raises_the_supervisors_refusal(server):
    with (FakeSupervisor(server),
          pytest.raises(CommandRefused, match=r"^'ctl\w+' refused 'on': task 'pid' is in ERROR: clear it first$")):
        client_of(server).call("on", {"task": "pid"})


def test_a_malformed_request_does_not_crash_poll(server):
    control = posix_ipc.MessageQueue(server.name)
    reply_name = f"{reply_queue_prefix(server.subsystem, server.run_id)}{os.getpid()}-test"
    replies = posix_ipc.MessageQueue(reply_name, posix_ipc.O_CREX, mode=0o600, max_messages=1, max_message_size=8192)
    try:
        control.send(b"\xc1 not msgpack")
        control.send(msgpack.packb({"command": "status"}))
        control.send(msgpack.packb(["status", reply_name]))  # no arguments: answerable, so answered
        assert server.poll(FakeSupervisor(server).handle) == 3
        raw, _ = replies.receive(timeout=1.0)
        reply = msgpack.unpackb(raw)
        assert reply["ok"] is False
        assert reply["error"].startswith("malformed request: expected [command, reply queue, arguments], got a list of 2")
        with pytest.raises(posix_ipc.BusyError):
            replies.receive(timeout=0)  # the two unanswerable ones were dropped
        assert server.dropped == 2
    finally:
        control.close()
        replies.close()
        replies.unlink()


def test_the_server_answers_only_to_reply_queues_of_its_run(server):
    foreign = f"/pbo.{server.subsystem}.{server.run_id}.events"  # a queue of the run, but not a reply queue
    queue = posix_ipc.MessageQueue(foreign, posix_ipc.O_CREX, mode=0o600, max_messages=1, max_message_size=8192)
    control = posix_ipc.MessageQueue(server.name)
    try:
        control.send(msgpack.packb(["status", foreign, {}]))
        assert server.poll(FakeSupervisor(server).handle) == 1
        with pytest.raises(posix_ipc.BusyError):
            queue.receive(timeout=0)
    finally:
        control.close()
        queue.close()
        queue.unlink()


def test_poll_serves_a_few_requests_at_a_time_so_a_flood_cannot_stall_a_tick(server):
    control = posix_ipc.MessageQueue(server.name)
    gone = reply_queue_prefix(server.subsystem, server.run_id) + "1-gone"
    try:
        for _ in range(6):
            control.send(msgpack.packb(["status", gone, {}]))
    finally:
        control.close()
    handler = FakeSupervisor(server).handle
    assert server.poll(handler) == MAX_REQUESTS_PER_POLL
    assert server.poll(handler) == 6 - MAX_REQUESTS_PER_POLL


def test_poll_without_requests_returns_at_once(server):
    assert server.poll(FakeSupervisor(server).handle, budget=0.0) == 0


def test_a_reply_to_a_client_that_gave_up_is_dropped(server):
    control = posix_ipc.MessageQueue(server.name)
    try:
        control.send(msgpack.packb(["status", reply_queue_prefix(server.subsystem, server.run_id) + "1-gone", {}]))
    finally:
        control.close()
    assert server.poll(FakeSupervisor(server).handle) == 1
    assert server.dropped == 1


# --- timeouts and cleanup -------------------------------------------------------------------


def test_a_client_times_out_with_a_clear_message_when_nobody_serves(server):
    client = client_of(server)
    with pytest.raises(PboError, match=rf"^the supervisor of '{server.subsystem}' did not answer within 0.2 s$"):
        client.request("status", timeout=0.2)
    assert not _queue_exists(client.last_reply_queue)


def test_the_reply_queue_is_gone_after_a_request(server):
    with FakeSupervisor(server):
        client = client_of(server)
        client.request("echo")
    assert client.last_reply_queue.startswith(f"/pbo.{server.subsystem}.{server.run_id}.reply-{os.getpid()}-")
    assert not _queue_exists(client.last_reply_queue)


def test_a_request_to_a_run_without_a_control_queue_says_so():
    with pytest.raises(PboError, match=r"^the supervisor of 'nosuch' \(run 1-abc\) has no control queue"):
        ControlClient("nosuch", "1-abc").request("status")


@pytest.mark.skipif(not os.path.ismount("/dev/mqueue"), reason="/dev/mqueue is not mounted: queues cannot be stat'ed")
def test_the_control_queue_is_owner_only(server):
    assert stat.S_IMODE(os.stat("/dev/mqueue" + server.name).st_mode) == 0o600


def test_closing_the_server_unlinks_its_queue():
    control = ControlServer(new_subsystem(), new_run_id())
    assert control.name == control_queue_name(control.subsystem, control.run_id)
    assert _queue_exists(control.name)
    control.close()
    control.close()  # twice is harmless
    assert not _queue_exists(control.name)


# --- finding the run ------------------------------------------------------------------------


def test_connect_with_no_run_raises_a_clear_error(monkeypatch, tmp_path: Path):
    monkeypatch.setattr(shm, "SHM_DIR", tmp_path)  # an empty /dev/shm: no run, whatever else this machine runs
    with pytest.raises(PboError, match=r"^no subsystem is running \(no live state variable table of yours in /dev/shm\)"):
        ControlClient.connect()


def test_connect_to_a_subsystem_that_is_not_running_names_it(fake_run):
    sub, run_id, _ = fake_run(new_subsystem())
    with pytest.raises(PboError, match=rf"^subsystem 'nosuch' is not running \(running: .*'{sub}' run {run_id} \(pid "):
        ControlClient.connect("nosuch")


def test_connect_with_two_live_runs_and_no_name_lists_both(fake_run):
    first, first_id, _ = fake_run(new_subsystem())
    second, second_id, _ = fake_run(new_subsystem())
    with pytest.raises(PboError, match=r"^\d+ runs are alive: .*; pass --subsystem NAME or --run ID$") as caught:
        ControlClient.connect()
    assert f"'{first}' run {first_id} (pid {os.getpid()}, started " in str(caught.value)
    assert f"'{second}' run {second_id} (pid {os.getpid()}, started " in str(caught.value)


def test_connect_by_name_picks_that_run_among_several(fake_run):
    fake_run(new_subsystem())
    sub, run_id, table = fake_run(new_subsystem())
    client = ControlClient.connect(sub)
    assert (client.subsystem, client.run_id) == (sub, run_id)
    assert find_live_run(sub) == (sub, run_id, table.name)


def test_two_live_runs_of_one_subsystem_without_a_run_id_are_listed_with_the_hint_to_pass_one(fake_run):
    sub = new_subsystem()
    _, first_id, _ = fake_run(sub)
    _, second_id, _ = fake_run(sub)
    with pytest.raises(PboError, match=rf"^2 runs of subsystem '{sub}' are alive: '{sub}' run .*; "
                                       rf"pass --run ID \(pbo runs lists them\)$") as caught:
        find_live_run(sub)
    assert f"run {first_id} (pid" in str(caught.value) and f"run {second_id} (pid" in str(caught.value)


def test_two_live_runs_of_the_only_running_subsystem_ask_for_a_run_id_even_unnamed(fake_run, monkeypatch):
    sub = new_subsystem()
    fake_run(sub)
    fake_run(sub)
    every_run = runs.live_runs
    monkeypatch.setattr(runs, "live_runs", lambda subsystem=None: every_run(sub))  # as if nothing else ran on the machine
    with pytest.raises(PboError, match=rf"^2 runs of subsystem '{sub}' are alive: .*; pass --run ID \(pbo runs lists them\)$"):
        find_live_run()


@pytest.mark.parametrize("by_subsystem", [True, False])
def test_a_run_is_picked_by_its_id_or_a_unique_prefix_of_it(fake_run, by_subsystem):
    sub = new_subsystem()
    fake_run(sub, f"{os.getpid()}-aaaaaa")
    _, run_id, table = fake_run(sub, f"{os.getpid()}-abcdef")
    for given in (run_id, f"{os.getpid()}-ab"):
        assert find_live_run(sub if by_subsystem else None, given) == (sub, run_id, table.name)
        client = ControlClient.connect(sub if by_subsystem else None, given)
        assert (client.subsystem, client.run_id) == (sub, run_id)


def test_a_run_id_prefix_that_matches_several_runs_asks_for_more_of_it(fake_run):
    sub = new_subsystem()
    fake_run(sub, f"{os.getpid()}-aaaaaa")
    fake_run(sub, f"{os.getpid()}-abcdef")
    with pytest.raises(PboError, match=rf"^run id '{os.getpid()}-a' matches 2 live runs: .*; give more of the id$"):
        find_live_run(sub, f"{os.getpid()}-a")


def test_a_run_id_that_no_live_run_has_is_refused_with_the_live_runs(fake_run):
    sub, run_id, _ = fake_run(new_subsystem())
    with pytest.raises(PboError, match=rf"^no live run has run id '999999999' \(running: .*'{sub}' run {run_id} "):
        find_live_run(None, "999999999")
    with pytest.raises(PboError, match=rf"^no live run has run id '{run_id}' of subsystem 'nosuch' \(running: "):
        find_live_run("nosuch", run_id)


@pytest.mark.multiprocess
def test_a_dead_runs_table_is_not_a_live_run(fake_run):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    sub, _, _ = fake_run(new_subsystem(), new_run_id(int(dead.stdout)))
    with pytest.raises(PboError, match=rf"^subsystem '{sub}' is not running"):
        find_live_run(sub)


# --- the operator's commands over a real queue ----------------------------------------------


@pytest.fixture
def live(fake_run) -> Iterator[tuple[str, FakeSupervisor]]:
    """A fake live run with a control queue, served by a FakeSupervisor thread."""
    sub, run_id, _ = fake_run(new_subsystem())
    control = ControlServer(sub, run_id)
    try:
        with FakeSupervisor(control) as supervisor:
            yield sub, supervisor
    finally:
        control.close()


def recording_console() -> Console:
    return Console(record=True, width=200, force_terminal=False, color_system=None)


def test_status_prints_tasks_by_rtpu_with_configuration_and_job(live):
    sub, _ = live
    console = recording_console()
    assert operator.status(console, sub) == 0
    text = console.export_text()
    assert f"{sub} · run" in text and "configuration joint_pid" in text and "job move" in text
    assert text.index("rtpu0") < text.index("rtpu1")  # grouped by RTPU, in order
    robot = next(line for line in text.splitlines() if "robot" in line)
    cells = [cell.strip() for cell in robot.split("│")[1:-1]]
    assert cells == ["rtpu1", "robot", "ON", "12500", "1000", "5", "40", "90", "11", "20", "0", "1"]
    assert "task 'pid' (ERROR): gain matrix is singular" in text


def test_task_signal_sends_the_task_and_prints_its_new_state(live):
    sub, supervisor = live
    console = recording_console()
    assert operator.task_signal(console, "on", "robot", sub) == 0
    assert supervisor.handled[-1] == ("on", {"task": "robot"})
    assert "task 'robot' is ON" in console.export_text()


def test_a_refused_task_signal_raises_with_the_supervisors_reason(live):
    sub, _ = live
    with pytest.raises(CommandRefused, match=r"task 'pid' is in ERROR: clear it first$"):
        operator.task_signal(recording_console(), "on", "pid", sub)


def test_a_task_command_other_than_on_off_clear_is_refused_before_sending(live):
    sub, supervisor = live
    with pytest.raises(PboError, match=r"^a task command is one of on, off, clear, got: 'kill'$"):
        operator.task_signal(recording_console(), "kill", "pid", sub)
    assert supervisor.handled == []


def test_job_sends_its_object_values_as_floats(live):
    sub, supervisor = live
    console = recording_console()
    assert operator.job(console, "move", ["0.3", "-0.5", "0.5", "0", "0.4", "0.2"], sub) == 0
    assert supervisor.handled[-1] == ("job", {"job": "move", "object": [0.3, -0.5, 0.5, 0.0, 0.4, 0.2]})
    assert "job 'move' started (configuration 'joint_pid')" in console.export_text()


def test_a_job_without_values_sends_no_object(live):
    sub, supervisor = live
    operator.job(recording_console(), "move", None, sub)
    assert supervisor.handled[-1] == ("job", {"job": "move", "object": None})


@pytest.mark.parametrize("text", ["abc", "nan", "inf", "-inf", "1e999"])
def test_job_object_values_must_be_finite_numbers(text):
    with pytest.raises(BadRequest, match=r"^values must be (finite )?numbers, got: '[\w-]+' \(value 2\)$"):
        operator.parse_object_values(["0.1", text])


def test_command_line_values_keep_integers_as_integers_for_integer_variables():
    assert operator.parse_object_values(["3", "-1", "0.5", "1e3", str(2**64)]) == [3, -1, 0.5, 1000.0, float(2**64)]


def test_a_message_too_long_for_its_queue_is_named_as_our_bug_not_a_bare_value_error():
    queue = messages.Queue(f"/pbo-test-{uuid.uuid4().hex[:8]}", create=True)
    try:
        with pytest.raises(InternalError, match=r"^a 'stats' message of \d+ B does not fit queue .* please report this$"):
            queue.try_send("stats", "x" * messages.MESSAGE_BYTES)
        assert queue.try_send("stats", "small")
    finally:
        queue.close()


# --- issue 18: every shape a request can take is answered, with the supervisor's own verbs ------------


class DispatchingSupervisor(FakeSupervisor):
    """Serves the queue with the supervisor's real dispatch, on a fake run of configs/operator_goal.yaml."""

    def __init__(self, server: ControlServer, host: FakeJobHost) -> None:
        super().__init__(server)
        self.host = host

    def handle(self, command: str, arguments: dict[str, Any]) -> dict[str, Any]:
        self.handled.append((command, arguments))
        return dispatch(self.host, command, arguments)


@pytest.fixture
def goal_run(fake_run) -> Iterator[tuple[str, FakeJobHost]]:
    sub, run_id, _ = fake_run(new_subsystem())
    host = FakeJobHost(load_subsystem(str(REPO / "configs" / "operator_goal.yaml")), "operated")
    control = ControlServer(sub, run_id)
    try:
        with DispatchingSupervisor(control, host):
            yield sub, host
    finally:
        control.close()


def raw_request(server_name: str, reply_name: str, payload: bytes) -> dict[str, Any]:
    """Send bytes as they are to a control queue and wait for the answer, as a hostile client would."""
    control = posix_ipc.MessageQueue(server_name)
    replies = posix_ipc.MessageQueue(reply_name, posix_ipc.O_CREX, mode=0o600, max_messages=1, max_message_size=8192)
    try:
        control.send(payload)
        raw, _ = replies.receive(timeout=5.0)
        return msgpack.unpackb(raw)
    finally:
        control.close()
        replies.close()
        replies.unlink()


@pytest.mark.parametrize("request_, error", [
    (["on", {"task": [1, 2]}], r"^task must be named by text, got: a list \(tasks: robot, goal, traj, pid\)$"),
    (["event", {"task": "goal", "values": "abc"}],
     r"^the values of an event for 'goal' must be a list of numbers, got: the text 'abc'$"),
    (["event", {"task": "pid", "values": [1, 2, 3]}], r"^task 'pid' is periodic: .* \(goal\)$"),
    (["event", {"task": "goal", "values": [float("nan")] * 6}],
     r"values must be finite numbers, got: \.nan \(not a number\) \(value 1\)$"),
    (["job", {"job": "go", "object": [0.0] * 6}], r"^no job 'go' \(jobs: none\)$"),
    (["switch", {"configuration": {"a": 1}}],
     r"^configuration must be named by text, got: a mapping \(configurations: operated\)$"),
    (["stop", {"now": True}], r"^'stop' takes no argument 'now' \(its arguments: none\)$"),
    (["fly", {}], r"^unknown command 'fly' \(commands: "),
    (["status", [1, 2]],
     r"^malformed request: expected \[command, reply queue, arguments\], got a list of 3 \(str, str, list\)$"),
], ids=["task-list", "event-text", "event-periodic", "event-nan", "job-unknown", "switch-mapping", "stop-argument",
        "unknown", "arguments-list"])
def test_a_malformed_request_on_the_control_queue_is_refused_clearly_never_an_internal_error(goal_run, request_, error):
    sub, host = goal_run
    client = ControlClient(*find_live_run(sub)[:2])
    reply_name = f"{reply_queue_prefix(client.subsystem, client.run_id)}{os.getpid()}-raw"
    reply = raw_request(client.control_name, reply_name, msgpack.packb([request_[0], reply_name, request_[1]]))
    assert reply["ok"] is False and reply["bad_request"] is True and re.search(error, reply["error"]), reply
    assert host.events == [] and all(state == "ON" for state in host.task_states.values())


def test_pbo_event_to_a_periodic_task_is_refused_with_exit_status_1_and_a_hint(goal_run, capsys):
    sub, host = goal_run
    assert main(["event", "pid", "1", "2", "3", "--subsystem", sub]) == 1
    err = capsys.readouterr().err
    assert f"error: '{sub}' refused 'event': task 'pid' is periodic" in err and "send events to an aperiodic task (goal)" in err
    assert "event sent" not in err and host.events == []


def test_pbo_job_with_values_that_are_not_numbers_exits_1_before_sending(goal_run, capsys):
    sub, _host = goal_run
    assert main(["job", "reach", "0", "nan", "--subsystem", sub]) == 1
    assert "error: values must be finite numbers, got: 'nan' (value 2)" in capsys.readouterr().err


def test_pbo_event_to_the_aperiodic_task_is_sent(goal_run, capsys):
    sub, host = goal_run
    assert main(["event", "goal", "0.1", "-0.5", "0.5", "0", "0.3", "0.1", "--subsystem", sub]) == 0
    assert "event sent to 'goal'" in capsys.readouterr().out and host.events == [("goal", [0.1, -0.5, 0.5, 0, 0.3, 0.1])]
