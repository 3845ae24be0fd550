"""A part of a running subsystem fails: the runtime stays safe, says what happened, exits 2, and
leaves nothing behind. Real processes on the real clock (a stopped process needs real time to
go by); no figure is asserted, only outcomes (bench/faults.py measures the figures)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

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
    demo_copy,
    excursion_from_path,
    killed_on_failure,
    measured_arm,
    run_output,
    run_processes,
    settling,
    start_run,
    stop_process,
    travelled,
    until,
)

pytestmark = pytest.mark.multiprocess

STOPPED_FOR = 0.5  # seconds: hundreds of the robot task's periods, on any machine
PLANT_STEP = 0.001  # seconds: the demo plant's timestep
PLANT_STOPPED_FOR = 2.0  # seconds: the plant's stop mid-move
REACHED = 0.005  # rad: every joint ends within this of its goal
EXCURSION_LIMIT = 0.05  # rad: off its path, at most
REACH_SAFETY_NET = 180.0  # seconds: a net for an arm that never arrives, not a timing


def run_with_a_stop(tmp_path, subsystem: str, role: str) -> tuple[subprocess.CompletedProcess, dict]:
    """Run the demo for 3 s; SIGSTOP its child `role` ('rtpu0', 'plant', ...) for STOPPED_FOR once the configuration is on."""
    config = demo_copy(tmp_path, subsystem, logger={"params": {"variables": ["q_m"], "path": "arm.npy"}})
    report = tmp_path / "report.json"
    process = start_run(config, tmp_path, "--duration", "3", "--report", str(report))
    try:
        stopped = run_processes(process)[role]
        stop_process(stopped)
        time.sleep(STOPPED_FOR)
        os.kill(stopped, signal.SIGCONT)
        stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    done = subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)
    return done, json.loads(report.read_text())


def test_a_stopped_controller_makes_the_robot_hold_the_arm_and_the_run_exit_2(tmp_path):
    done, report = run_with_a_stop(tmp_path, "fault_controller", "rtpu0")
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stderr and "run summary" in done.stdout
    held = [e for e in report["stable_episodes"] if e["cause"] == "stale" and not e["while_starting"]]
    assert held and all(e["task"] == "robot" for e in held)
    assert "in-var 'tau_u' is" in held[0]["reason"] and "('pid' stopped writing it)" in held[0]["reason"]
    assert held[0]["to"] is not None  # back to its cycle by itself once the controller ran again
    assert any(f.startswith("critical task 'robot' ran its locally stable behaviour") for f in report["faults"])
    assert "fault: critical task 'robot' ran its locally stable behaviour" in done.stderr
    assert report["states_at_stop"]["robot"] == "ON"
    assert_nothing_left(report)


def test_a_stopped_plant_resumes_without_integrating_the_backlog_and_the_run_exits_2(tmp_path):
    done, report = run_with_a_stop(tmp_path, "fault_plant", "plant")
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    # the stop is one stall at least; a busy machine may starve the plant past the stall bound again
    stalls = [f for f in report["faults"] if f.startswith("the plant did not run for")]
    assert stalls and all("without integrating the backlog" in stall for stall in stalls)
    # counted from the step it missed, which may come up to one plant step (1 ms) after the stop
    assert report["plant"]["stalls"] >= len(stalls) and report["plant"]["stalled_for"] >= STOPPED_FOR - PLANT_STEP
    held = [e for e in report["stable_episodes"] if e["cause"] == "module"]  # the robot saw the sim time stand still
    assert held and held[0]["task"] == "robot" and held[0]["to"] is not None
    assert "fault: the plant did not run for" in done.stderr
    assert_nothing_left(report)


def test_a_plant_stopped_for_2_s_mid_move_leaves_the_arm_on_its_path_and_it_ends_on_its_goal(tmp_path):
    """The demo as shipped, at its speed: while the robot interface holds the arm, the trajectory
    stands still and the PID integrates nothing; after, they go on from where the arm is."""
    config = config_copy(DEMO, tmp_path, "fault_plant_mid_move")
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "0", "--report", str(report_path), "--out", str(tmp_path / "out"))
    with killed_on_failure(run):
        with measured_arm(config, run, "fault_plant_mid_move") as q_m:
            plant = run_processes(run)["plant"]
            until(lambda: travelled(q_m()) >= DEMO_MID_MOVE, "the arm to be mid-move", REACH_SAFETY_NET)
            stop_process(plant)
            time.sleep(PLANT_STOPPED_FOR)
            os.kill(plant, signal.SIGCONT)
            settled = settling(DEMO_GOAL, REACHED)
            until(lambda: settled(q_m()), "the arm to settle on its goal", REACH_SAFETY_NET)
        run.send_signal(signal.SIGINT)
        _, err = run_output(run)
    assert "Traceback" not in err, err
    report = json.loads(report_path.read_text())
    held = [e for e in report["stable_episodes"] if e["task"] == "robot" and e["cause"] == "module"]
    assert held and all(e["to"] is not None for e in held)  # the robot saw the sim time stand still, then go on
    log = read_log(next((tmp_path / "out").rglob("pid_joint.mcap")))
    assert excursion_from_path(log["q_m"], log["q_m"][0], DEMO_GOAL) < EXCURSION_LIMIT
    assert np.abs(log["q_m"][-1] - DEMO_GOAL).max() < REACHED
    assert_nothing_left(report)


def test_a_stopped_robot_interface_leaves_the_arm_to_its_drive_watchdog_and_the_run_exits_2(tmp_path):
    done, report = run_with_a_stop(tmp_path, "fault_robot", "rtpu1")
    assert done.returncode == 2, done.stdout + done.stderr
    assert report["plant"]["watchdog_trips"] >= 1
    assert any(f.startswith("the arm's drive watchdog held the arm") for f in report["faults"])
    assert "fault: the arm's drive watchdog held the arm" in done.stderr and "Traceback" not in done.stderr
    assert_nothing_left(report)

def test_a_module_that_never_returns_stops_its_rtpu_and_the_robot_holds_the_arm_until_the_end(tmp_path):
    config = demo_copy(tmp_path, "fault_hang", stuck={"module": "fault_injector", "rtpu": "rtpu0", "period": "2 ms",
                                                       "params": {"fail_after": 100, "fault": "hang"}})
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(config), "--duration", "2", "--report", str(report_path), "--no-live"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    report = json.loads(report_path.read_text())
    held = [e for e in report["stable_episodes"] if e["cause"] == "stale" and not e["while_starting"]]
    assert held and held[-1]["task"] == "robot" and "('pid' stopped writing it)" in held[-1]["reason"]
    # held until the stop ("until the stop", or "N times (one until the stop)" after brief holds on a busy machine)
    held_lines = [line for line in done.stderr.splitlines() if line.startswith("fault: critical task 'robot' ran its")]
    assert any("until the stop" in line and "('pid' stopped writing it)" in line for line in held_lines), done.stderr
    assert report["tasks"]["stuck"]["cycles"] == 100 and report["unstopped"] == ["rtpu0"]
    assert "error: rtpu0 did not stop within 5 s and was killed" in done.stderr
    assert_nothing_left(report)


INJECTED = {"module": "fault_injector", "rtpu": "rtpu0", "period": "2 ms", "params": {"fail_after": 150},
            "ports": {"watched": "q_m"}}


def test_a_task_left_in_error_and_the_arm_held_for_it_are_faults_and_the_run_exits_2(tmp_path):
    config = demo_copy(tmp_path, "fault_left", inj=INJECTED)
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(config), "--clock", "sim", "--duration", "1", "--no-live",
                           "--report", str(report_path)], cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stdout + done.stderr
    report = json.loads(report_path.read_text())
    assert report["states_at_stop"]["inj"] == "ERROR"
    assert report["faults"] == [
        "task 'inj' on rtpu0 was in ERROR at the stop: cycle raised RuntimeError: injected fault after 150 cycles at "
        f"{report['tasks']['inj']['error'].rsplit(' at ', 1)[1]} (while a run goes on: pbo clear inj, then pbo on inj)",
        "critical task 'robot' ran its locally stable behaviour until the stop, from 0.301 s into the run: the "
        "configuration is illegal (a task in ERROR, or a switch that overran a cycle)"]
    assert done.stderr.splitlines()[-2:] == [f"fault: {line}" for line in report["faults"]]
