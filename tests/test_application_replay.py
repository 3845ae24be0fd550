"""An application on the simulated clock (`pbo run APP.yaml --clock sim`): one master, turns in time order, replay.

The master is tested in-process, with threads standing in for the subsystems' supervisors (fakes,
named as such); the rest runs configs/leader_follower.yaml's three subsystems for real. Nothing
here asserts a wall-clock time.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

from pbo_runtime import read_log
from pbo_runtime.cli.main import main
from pbo_runtime.clock.application_lockstep import ApplicationLockstep, TurnGate, TurnStalled
from pbo_runtime.clock.run_clock import SimRunClock
from pbo_runtime.config.application import check_application
from pbo_runtime.ipc import shm
from pbo_runtime.supervisor.application_runner import unreplayable_links
from pbo_runtime.supervisor.cleanup import remove_dead_runs
from pbo_runtime.table.table import HEADER_WORDS
from tests.support import (
    PBO,
    REPO,
    application_copy,
    assert_nothing_left,
    children_of,
    dead_pid,
    killed_on_failure,
    read_until,
    run_output,
)

GOAL_A = np.array([0.3, -0.5, 0.5, 0.2, 0.4, 0.2])  # the operator's goals (configs/leader_follower.yaml)
GOAL_B = np.array([-0.2, -0.3, 0.3, -0.2, 0.2, 0.4])
LOGS = ("leader/leader.mcap", "follower/follower.mcap", "operator/operator.mcap")


# --- the master, with threads as fake subsystems -----------------------------------------------


class FakeSubsystem(threading.Thread):
    """A fake subsystem's supervisor: takes `turns` turns (one tick each, logged with its time), then ends."""

    def __init__(self, key: str, base: str, tick: float, turns: int, log: list[tuple[float, str]]) -> None:
        super().__init__(daemon=True)
        self.key, self.tick, self.turns, self.log = key, tick, turns, log
        self.gate = TurnGate(base)

    def run(self) -> None:
        for tick in range(self.turns):
            self.gate.take(lambda: None)
            self.log.append((round(tick * self.tick, 9), self.key))
            if tick < self.turns - 1:
                self.gate.give()
        self.gate.close()  # the last turn is kept: the master sees the "process" end


def take_turns(ticks: dict[str, float], turns: dict[str, int]) -> list[tuple[float, str]]:
    """Run the master over fake subsystems until every one has ended; the (time, key) of each tick, in order."""
    lockstep = ApplicationLockstep("locktest", shm.new_run_id(), ticks)
    log: list[tuple[float, str]] = []
    fakes = {key: FakeSubsystem(key, lockstep.bases[key], tick, turns[key], log) for key, tick in ticks.items()}
    try:
        for fake in fakes.values():
            fake.start()
        while lockstep.rotation:
            lockstep.give_turn(lockstep.next_turn(), lambda key: not fakes[key].is_alive(), lambda: None)
    finally:
        lockstep.close()
    return log


def test_subsystems_with_different_ticks_take_turns_in_order_of_simulated_time_ties_in_the_files_order():
    log = take_turns({"leader": 0.001, "operator": 0.003, "follower": 0.002}, {"leader": 7, "operator": 3, "follower": 4})
    assert log == [(0.0, "leader"), (0.0, "operator"), (0.0, "follower"), (0.001, "leader"),
                   (0.002, "leader"), (0.002, "follower"), (0.003, "leader"), (0.003, "operator"),
                   (0.004, "leader"), (0.004, "follower"), (0.005, "leader"), (0.006, "leader"),
                   (0.006, "operator"), (0.006, "follower")]


def test_a_subsystem_that_ends_leaves_the_rotation_and_the_others_go_on():
    log = take_turns({"short": 0.001, "long": 0.001}, {"short": 2, "long": 5})
    assert [key for _, key in log] == ["short", "long", "short", "long", "long", "long", "long"]


def test_the_turn_semaphores_are_private_and_gone_after_close():
    run_id = shm.new_run_id()
    lockstep = ApplicationLockstep("locktest", run_id, {"a": 0.001, "b": 0.01})
    names = [n for n in os.listdir("/dev/shm") if run_id in n]
    assert len(names) == 4 and all(os.stat(f"/dev/shm/{n}").st_mode & 0o777 == 0o600 for n in names)
    assert all(n.startswith("sem.pbo.locktest.") for n in names)  # the application's name: cleanup finds them
    lockstep.close()
    assert [n for n in os.listdir("/dev/shm") if run_id in n] == []


@pytest.mark.multiprocess
def test_the_turn_semaphores_of_a_runner_that_died_are_removed_by_the_next_cleanup():
    run_id = f"{dead_pid()}-abc123"
    ApplicationLockstep("locktest_dead", run_id, {"a": 0.001})  # never closed: its runner was killed
    assert sorted(remove_dead_runs("locktest_dead").removed) == [
        f"/pbo.locktest_dead.{run_id}.turn-a.{end}" for end in ("done", "go")]


def test_a_gate_of_a_run_asked_to_stop_no_longer_waits_for_the_turn():
    lockstep = ApplicationLockstep("locktest", shm.new_run_id(), {"a": 0.001})
    stopping = threading.Event()
    gate = TurnGate(lockstep.bases["a"], abandoned=stopping.is_set)
    try:
        threading.Timer(0.2, stopping.set).start()
        assert gate.take(lambda: None) and gate.open and not gate.held  # nobody gave the turn: the stop let it go
        gate.give()  # nothing to give back
    finally:
        gate.close()
        lockstep.close()


def test_a_gate_whose_wait_is_given_up_does_not_take_the_turn():
    lockstep = ApplicationLockstep("locktest", shm.new_run_id(), {"a": 0.001})
    gate = TurnGate(lockstep.bases["a"])
    try:
        assert gate.take(lambda: True) is False and not gate.held
    finally:
        gate.close()
        lockstep.close()


@pytest.mark.parametrize("in_application", [False, True])
def test_a_participant_stuck_past_the_limit_is_a_named_fault_in_an_application_and_a_warning_alone(in_application):
    lockstep = ApplicationLockstep("locktest", shm.new_run_id(), {"a": 0.001})
    gate = TurnGate(lockstep.bases["a"]) if in_application else None
    clock = SimRunClock(0.001, gate, stall_limit=0.5)
    try:
        clock.start("locktest", shm.new_run_id(), ["rtpu0"], np.zeros(HEADER_WORDS, dtype=np.int64))
        assert clock.lockstep is not None
        clock.lockstep.stepping, clock.lockstep.step_started = "rtpu0", time.monotonic() - 1.0  # a step begun 1 s ago
        if gate is None:
            assert clock.slow_participant(0.1) == ("rtpu0", 0.0, pytest.approx(1.0, abs=0.5))
        else:
            assert clock.slow_participant(0.1) is None  # while waiting for the turn, none of ours steps
            gate.held = True
            with pytest.raises(TurnStalled, match=r"rtpu0 has not finished the tick at 0\.000 s .* every subsystem"):
                clock.slow_participant(0.1)
    finally:
        clock.close()
        lockstep.close()


# --- what an application on the simulated clock refuses ------------------------------------------


ZENOH_LINKS = ("  arm_state: {type: float64, shape: [6], transport: zenoh}\n"
               "  goal: {kind: message, type: float64, shape: [6], capacity: 4, transport: shm}\n")


def test_zenoh_links_are_refused_on_the_simulated_clock_before_anything_starts(tmp_path, capsys):
    path = application_copy(tmp_path, "replay_zenoh", links=ZENOH_LINKS)
    assert "link(s) 'arm_state' go over Zenoh" in unreplayable_links(check_application(path).application)
    assert main(["run", str(path), "--clock", "sim", "--no-live", "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "--clock sim runs an application that replays bit for bit only over shared memory links" in err
    assert "use transport: shm, or --clock real" in err and "Traceback" not in err


def test_on_the_simulated_clock_each_subsystem_is_told_its_turn():
    from pbo_runtime.supervisor.application_runner import ApplicationRunner

    application = check_application(REPO / "configs" / "leader_follower.yaml").application
    runner = ApplicationRunner(application, 1.0, lambda text: None, clock="sim")
    runner.lockstep = ApplicationLockstep(application.name, runner.run_id, {key: 0.001 for key in application.subsystems})
    try:
        for key in application.subsystems:
            command = runner.command(key)
            assert command[command.index("--turn") + 1] == f"/pbo.leader_follower.{runner.run_id}.turn-{key}"
        assert "--turn" not in ApplicationRunner(application, 1.0, lambda text: None).command("leader")
    finally:
        runner.lockstep.close()


@pytest.mark.parametrize("codes, worst", [([0, 0, 0], 0), ([0, 2, 0], 2), ([0, -9, 0], 2), ([1, -15, 3], 3)])
def test_the_runners_status_is_the_worst_of_its_subsystems_and_a_killed_one_counts_as_a_failed_run(codes, worst):
    from types import SimpleNamespace

    from pbo_runtime.supervisor.application_runner import ApplicationRunner

    runner = ApplicationRunner(check_application(REPO / "configs" / "leader_follower.yaml").application, 1.0, lambda text: None)
    runner._children = {f"s{i}": SimpleNamespace(returncode=code) for i, code in enumerate(codes)}  # fake processes
    assert runner._worst() == worst


# --- runs of the three subsystems ------------------------------------------------------------


def run_application(tmp_path, app, out: str) -> str:
    done = subprocess.run([*PBO, "run", str(app), "--clock", "sim", "--duration", "1.5", "--no-live", "--out",
                           str(tmp_path / out)], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


@pytest.mark.multiprocess
def test_two_simulated_runs_of_an_application_write_identical_logs(tmp_path):
    app = application_copy(tmp_path, "replay")
    said = run_application(tmp_path, app, "first")
    run_application(tmp_path, app, "second")
    for log in LOGS:
        assert (tmp_path / "first" / log).read_bytes() == (tmp_path / "second" / log).read_bytes(), log
    leader, follower = read_log(tmp_path / "first" / LOGS[0]), read_log(tmp_path / "first" / LOGS[1])
    assert len(leader["time"]) == len(follower["time"]) == 151  # 0 to 1.5 s, every 10 ms
    assert np.allclose(leader["q_d"][-1], GOAL_A)  # the operator's message reached the leader
    assert np.max(np.abs(follower["q_m"][-1] - follower["q_m"][0])) > 0.1  # and the follower moved after it
    assert np.max(np.abs(follower["q_d"][-1] - leader["q_m"][-1])) < 0.05  # tracking the leader over the link
    # The operator's 10 ms ticks interleave by time with the arms' 1 ms ones: its second goal, sent after
    # 1.5 s, never reaches the leader, whose run ends at 1.5 s. (On clocks of their own, the operator ran
    # ahead of the arms and the leader took both goals.)
    operator = read_log(tmp_path / "first" / LOGS[2])
    assert operator["time"][np.argmax(np.all(np.isclose(operator["goal"], GOAL_B), axis=1))] > 1.5
    assert not np.any(np.all(np.isclose(leader["q_d"], GOAL_B), axis=1))
    for key in ("leader", "follower", "operator"):
        report = json.loads((tmp_path / "first" / key / "report.json").read_text())
        assert report["clock"] == "sim"
        assert_nothing_left(report)
    assert [n for n in os.listdir("/dev/shm") if "pbo.replay" in n] == [], said


def started_on_the_simulated_clock(app, tmp_path, duration: str = "600") -> tuple[subprocess.Popen, str, int]:
    """The application running on the simulated clock with every arm on: its runner, what it said, the follower's pid."""
    runner = subprocess.Popen([*PBO, "run", str(app), "--clock", "sim", "--duration", duration, "--no-live", "--out",
                               str(tmp_path / "out")], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    said = read_until(runner, "[follower] pbo: configuration 'follow' is on", "[leader] pbo: configuration 'lead' is on")
    (follower,) = [pid for pid, command in children_of(runner.pid).items() if "follower.yaml" in command]
    return runner, said, follower


@pytest.mark.multiprocess
def test_a_subsystem_killed_in_a_simulated_application_stops_the_others_and_leaves_nothing(tmp_path):
    runner, said, follower = started_on_the_simulated_clock(application_copy(tmp_path, "replay_kill"), tmp_path)
    with killed_on_failure(runner):
        os.kill(follower, signal.SIGKILL)
        out, err = run_output(runner, 300)
    assert runner.returncode == 2, said + out + err
    assert f"stopping every subsystem: subsystem 'follower' (pid {follower}) failed (killed by SIGKILL) while " in out
    assert "error: application 'replay_kill' stopped" in err
    for key in ("leader", "operator"):  # stopped by the runner, cleanly
        assert_nothing_left(json.loads((tmp_path / "out" / key / "report.json").read_text()))
    assert [n for n in os.listdir("/dev/shm") if "pbo.replay_kill" in n] == []


@pytest.mark.multiprocess
def test_a_participant_stopped_in_a_simulated_application_ends_the_run_with_a_named_fault_not_a_hang(tmp_path):
    """An RTPU stopped (SIGSTOP) holds every subsystem; past the watchdog's limit (30 s) its run fails, naming it."""
    runner, said, follower = started_on_the_simulated_clock(application_copy(tmp_path, "replay_stall"), tmp_path)
    with killed_on_failure(runner):
        (rtpu,) = [pid for pid, command in children_of(follower).items() if "--rtpu rtpu0" in command]
        os.kill(rtpu, signal.SIGSTOP)
        out, err = run_output(runner, 300)
    assert runner.returncode == 2, said + out + err
    assert "[follower] error: rtpu0 has not finished the tick at " in out
    assert "every subsystem of the application waits for it" in out
    assert f"stopping every subsystem: subsystem 'follower' (pid {follower}) failed (exit 2) while it held" in out
    for key in ("leader", "follower", "operator"):
        assert_nothing_left(json.loads((tmp_path / "out" / key / "report.json").read_text()))
    assert [n for n in os.listdir("/dev/shm") if "pbo.replay_stall" in n] == []


OPERATOR_ABORTS = (  # the operator's RTPU, with a restart policy, aborts 0.5 s into the run, inside its tick
    ("    rtpus: [rtpu0]\n", "    rtpus: [rtpu0]\n    restart: {max: 3, within: 10 min}\n"),
    ("    configurations:\n      operate: [console, logger]",
     "      crash: {module: fault_injector, rtpu: rtpu0, period: 10 ms, params: {fault: abort, at: [0.5]}, "
     "ports: {watched: goal}}\n    configurations:\n      operate: [console, logger, crash]"))


def with_changes(path, changes) -> None:
    text = path.read_text()
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new, 1)
    path.write_text(text)


@pytest.mark.multiprocess
def test_an_rtpu_that_dies_in_a_simulated_application_is_restarted_in_its_turn_and_the_run_replays(tmp_path):
    app = application_copy(tmp_path, "replay_restart")
    with_changes(app, OPERATOR_ABORTS)
    said = run_application(tmp_path, app, "first")
    assert "[operator] RTPU 'rtpu0' restarted, 0.50 s into the run: pid " in said and "killed by SIGABRT" in said
    run_application(tmp_path, app, "second")
    for log in LOGS:
        assert (tmp_path / "first" / log).read_bytes() == (tmp_path / "second" / log).read_bytes(), log
    operator = json.loads((tmp_path / "first" / "operator" / "report.json").read_text())
    assert [(r["rtpu"], r["died_at"], r["seconds"], r["tasks_on"]) for r in operator["restarts"]] == [
        ("rtpu0", pytest.approx(0.5), 0, ["console", "logger", "crash"])]  # between two of its ticks
    leader = read_log(tmp_path / "first" / LOGS[0])
    assert np.allclose(leader["q_d"][-1], GOAL_A)  # the operator's goal still reached the leader
    for key in ("leader", "follower", "operator"):
        report = json.loads((tmp_path / "first" / key / "report.json").read_text())
        assert report["failure"] == ""
        assert report["tasks"].get("robot", {}).get("cycles", 1501) == 1501  # the arms ran every tick: 0 .. 1.5 s
        assert_nothing_left(report)


@pytest.mark.multiprocess
def test_an_rtpu_killed_from_outside_a_simulated_application_is_restarted_and_the_others_go_on(tmp_path):
    app = application_copy(tmp_path, "replay_killed")
    with_changes(tmp_path / "leader.yaml", (("\nrtpus: [rtpu0]\n", "\nrtpus: [rtpu0]\nrestart: {max: 3, within: 10 min}\n"),))
    # it ends by its duration (a restart takes no simulated time), not Ctrl-C, which may cut a last tick
    runner, said, _ = started_on_the_simulated_clock(app, tmp_path, duration="3")
    with killed_on_failure(runner):
        (leader,) = [pid for pid, command in children_of(runner.pid).items() if "leader.yaml" in command]
        (rtpu,) = [pid for pid, command in children_of(leader).items() if "--rtpu rtpu0" in command]
        os.kill(rtpu, signal.SIGKILL)  # wherever the application's turn is
        out, err = run_output(runner, 300)
    assert runner.returncode == 0, said + out + err
    assert "[leader] pbo: RTPU 'rtpu0' restarted: robot, goal, traj, pid, send, logger ON again after 0 ms" in out
    reports = {key: json.loads((tmp_path / "out" / key / "report.json").read_text())
               for key in ("leader", "follower", "operator")}
    assert [(r["rtpu"], r["pid"], r["cause"]) for r in reports["leader"]["restarts"]] == [("rtpu0", rtpu, "killed by SIGKILL")]
    follower = reports["follower"]["tasks"]["robot"]
    assert follower["state"] == "ON" and follower["cycles"] == reports["follower"]["plant"]["steps"]  # never held up
    for report in reports.values():
        assert_nothing_left(report)
    assert [n for n in os.listdir("/dev/shm") if "pbo.replay_killed" in n] == []
