"""A dead RTPU restarted alone by its restart policy (`restart: {max, within}`).

Figure 8 (configs/pid_joint.yaml, at its own speed) with a policy: the controller's RTPU is
killed mid-move, then twice more; each time it comes back with its tasks ON while the robot
interface on the other RTPU, which never stops, holds the arm (its locally stable behaviour)
until the torque is fresh again. The restarted trajectory and PID start from the arm's measured
state, so the arm keeps to its path and ends on its goal. Past the policy, and for a module that
aborts its process in `init`, the run stops and says why. Real clock, no timing asserted: the
test waits for what the run says and what the arm does, and its safety nets only catch a hang.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess

import numpy as np
import pytest

from pbo_runtime import read_log
from tests.support import (
    DEMO,
    DEMO_GOAL,
    DEMO_MID_MOVE,
    PBO,
    assert_nothing_left,
    config_copy,
    excursion_from_path,
    kill_and_await_restart,
    killed_on_failure,
    measured_arm,
    read_until,
    run_output,
    run_processes,
    settling,
    start_run,
    travelled,
    until,
)

pytestmark = pytest.mark.multiprocess

POLICY = ("rtpus: [rtpu0, rtpu1]", "rtpus: [rtpu0, rtpu1]\nrestart: {max: 3, within: 10 min}")
LOGGER_BESIDE_THE_ROBOT = ("logger: {module: data_logger, rtpu: rtpu0", "logger: {module: data_logger, rtpu: rtpu1")
REACHED = 0.005  # rad: every joint ends within this of its goal
EXCURSION_LIMIT = 0.05  # rad: off its path, at most
REACH_SAFETY_NET = 180.0  # seconds: a net for an arm that never arrives, not a timing


def test_a_controller_rtpu_killed_mid_move_comes_back_and_the_arm_keeps_to_its_path_and_ends_on_its_goal(tmp_path):
    config = config_copy(DEMO, tmp_path, "restart_thrice", (POLICY, LOGGER_BESIDE_THE_ROBOT))
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "0", "--report", str(report_path), "--out", str(tmp_path / "out"))
    with killed_on_failure(run):
        with measured_arm(config, run, "restart_thrice") as q_m:
            controller = run_processes(run)["rtpu0"]  # the trajectory and the PID
            until(lambda: travelled(q_m()) >= DEMO_MID_MOVE, "the arm to be mid-move", REACH_SAFETY_NET)
            killed = [kill_and_await_restart(run, pid=controller)]
            killed += [kill_and_await_restart(run) for _ in range(2)]  # and as soon as it is back, twice
            settled = settling(DEMO_GOAL, REACHED)
            until(lambda: settled(q_m()), "the arm to settle on its goal", REACH_SAFETY_NET)
        run.send_signal(signal.SIGINT)
        out, err = run_output(run)
    assert "Traceback" not in err, err
    report = json.loads(report_path.read_text())
    assert report["failure"] == "" and report["stopped_by"] == "Ctrl-C"
    assert [(r["rtpu"], r["pid"], r["cause"]) for r in report["restarts"]] == [
        ("rtpu0", pid, "killed by SIGKILL") for pid in killed]
    assert all(r["seconds"] > 0 and r["tasks_on"] == ["traj", "pid"] for r in report["restarts"])
    assert out.count("RTPU 'rtpu0' restarted, ") == 3  # the summary tells each restart
    # the robot interface never stopped: ON throughout, holding the arm while its torque was stale
    robot = report["tasks"]["robot"]
    assert robot["state"] == "ON" and robot["error"] == ""
    holds = [e for e in report["stable_episodes"] if e["task"] == "robot" and "tau_u" in e["reason"]]
    assert len(holds) >= 3, report["stable_episodes"]
    # ... and the arm kept to its path and ended on its goal
    log = read_log(next((tmp_path / "out").rglob("pid_joint.mcap")))
    assert excursion_from_path(log["q_m"], log["q_m"][0], DEMO_GOAL) < EXCURSION_LIMIT
    assert np.abs(log["q_m"][-1] - DEMO_GOAL).max() < REACHED
    assert_nothing_left(report)


def test_a_module_that_aborts_in_init_ends_in_a_clear_stop_after_max_restarts(tmp_path):
    config = config_copy(DEMO, tmp_path, "restart_abort", (
        POLICY,
        ("  logger: {module: data_logger", "  crash: {module: fault_injector, rtpu: rtpu0, period: 10 ms, "
                                           "params: {fault: abort, in_init: true}}\n  logger: {module: data_logger"),
        ("joint_pid: [robot, traj, pid, logger]", "joint_pid: [robot, traj, pid, crash, logger]")))
    report_path = tmp_path / "report.json"
    run = subprocess.run([*PBO, "run", str(config), "--no-live", "--duration", "0", "--report", str(report_path),
                          "--out", str(tmp_path / "out")], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr, run.stderr
    assert "died (killed by SIGABRT) while hosting tasks: traj, pid, crash" in run.stderr, run.stderr
    assert "it died 4 times within 600 s, more than its restart policy allows (restart: {max: 3, within: 600 s})" in run.stderr
    report = json.loads(report_path.read_text())
    # three restarts, each dying again as the task's init runs; the fourth death stops the run: no loop
    assert [r["seconds"] is None for r in report["restarts"]] == [False, False, False, True]
    assert_nothing_left(report)


def test_past_its_policy_an_rtpus_death_stops_the_run_and_says_why(tmp_path):
    config = config_copy(DEMO, tmp_path, "restart_once", (
        ("rtpus: [rtpu0, rtpu1]", "rtpus: [rtpu0, rtpu1]\nrestart: {max: 1, within: 10 min}"),))
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "0", "--report", str(report_path), "--out", str(tmp_path / "out"))
    with killed_on_failure(run):
        first = run_processes(run)["rtpu0"]
        os.kill(first, signal.SIGKILL)
        read_until(run, "restarted:")
        second = run_processes(run)["rtpu0"]
        os.kill(second, signal.SIGKILL)
        _out, err = run_output(run)
    assert run.returncode == 2, err
    assert (f"RTPU 'rtpu0' (pid {second}) died (killed by SIGKILL)" in err
            and "it died 2 times within 600 s, more than its restart policy allows (restart: {max: 1, within: 600 s})"
            in err), err
    report = json.loads(report_path.read_text())
    assert [(r["pid"], r["seconds"] is None) for r in report["restarts"]] == [(first, False), (second, True)]  # not back
    assert_nothing_left(report)
