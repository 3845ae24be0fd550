"""The product as a user runs it: `pbo run` on the demo file, in real processes.

These start the plant and two RTPUs (three processes besides pbo), each for a few seconds. Runs on
the real clock assert no timing (what a machine manages depends on the machine); what the arm
does and how many cycles ran are asserted on the simulated clock, where they are exact.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import numpy as np
import pytest

from pbo_runtime import read_log
from tests.support import DEMO, PBO, REPO, assert_ended_well, assert_nothing_left, children_of, only_file, read_until

pytestmark = pytest.mark.multiprocess


def test_make_run_s_demo_runs_for_its_duration_on_the_real_clock_and_leaves_nothing_behind(tmp_path):
    # A smoke test of what `make run` does: no timing is asserted (the real clock's counts depend on the machine).
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(DEMO), "--duration", "3", "--report", str(report_path), "--no-live"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert "run summary" in done.stdout and "Traceback" not in done.stderr, done.stderr
    report = json.loads(report_path.read_text())
    assert_ended_well(done.returncode, report, done.stderr)
    assert report["stopped_by"] == "duration" and report["failure"] == "" and report["clock"] == "real"
    for settings in report["realtime"].values():  # asked for by default on the real clock: granted, or refused and why
        assert settings["scheduler"] in ("SCHED_FIFO 50", "SCHED_FIFO 55") \
            or settings["scheduler"].startswith("SCHED_OTHER: SCHED_FIFO refused (")
    if report["realtime"]["rtpu1"]["scheduler"].startswith("SCHED_FIFO"):  # the robot interface's RTPU preempts the controller's
        assert (report["realtime"]["rtpu0"]["scheduler"],
                report["realtime"]["rtpu1"]["scheduler"]) == ("SCHED_FIFO 50", "SCHED_FIFO 55")
    assert all(report["states_at_stop"][name] == "ON" for name in report["tasks"])
    assert only_file(tmp_path, "runs/puma-*/pid_joint.mcap").stat().st_size > 0  # the run's own directory
    assert_nothing_left(report)


def test_demo_moves_the_arm_to_its_goal_on_the_simulated_clock(tmp_path):
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(DEMO), "--duration", "3", "--clock", "sim", "--report", str(report_path),
                           "--no-live"], cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    report = json.loads(report_path.read_text())
    assert report["stopped_by"] == "duration" and report["failure"] == ""
    q_m = np.array(report["variables"]["q_m"]["value"])
    q_d = np.array(report["variables"]["q_d"]["value"])
    assert np.max(np.abs(q_m - q_d)) < 0.01, f"arm at {q_m}, goal {q_d}"
    for name, period in {"robot": 0.001, "pid": 0.001, "traj": 0.002, "logger": 0.01}.items():
        assert report["states_at_stop"][name] == "ON"
        assert report["tasks"][name]["cycles"] == round(3.0 / period) + 1, name  # released at 0, period, ..., 3 s
    log = read_log(only_file(tmp_path, "runs/puma-*/pid_joint.mcap"))
    assert log["q_m"].shape == (301, 6) and np.allclose(np.diff(log["time"]), 0.01)
    assert_nothing_left(report)


def test_killing_an_rtpu_stops_everything_and_names_the_rtpu_and_its_tasks(tmp_path):
    report_path = tmp_path / "report.json"
    pbo = subprocess.Popen([*PBO, "run", str(DEMO), "--duration", "60", "--report", str(report_path), "--no-live"],
                           cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        read_until(pbo, "is on")  # wait until the configuration is on
        rtpu1 = [pid for pid, cmd in children_of(pbo.pid).items() if "--rtpu rtpu1" in cmd]
        assert len(rtpu1) == 1
        os.kill(rtpu1[0], signal.SIGKILL)
        _out, err = pbo.communicate(timeout=60)
    finally:
        if pbo.poll() is None:
            pbo.kill()
            pbo.wait()
    assert pbo.returncode == 2
    assert f"RTPU 'rtpu1' (pid {rtpu1[0]}) died (killed by SIGKILL) while hosting tasks: robot" in err
    assert "Traceback" not in err
    report = json.loads(report_path.read_text())
    assert report["stopped_by"] == "failure"
    assert children_of(pbo.pid) == {}
    assert_nothing_left(report)


def test_ctrl_c_stops_the_run_cleanly_with_a_summary(tmp_path):
    report_path = tmp_path / "report.json"
    pbo = subprocess.Popen([*PBO, "run", str(DEMO), "--duration", "0", "--report", str(report_path), "--no-live"],
                           cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        read_until(pbo, "is on")
        time.sleep(0.5)  # let it cycle; nothing below depends on how long
        pbo.send_signal(signal.SIGINT)
        out, err = pbo.communicate(timeout=60)
    finally:
        if pbo.poll() is None:
            pbo.kill()
            pbo.wait()
    assert "run summary" in out and "stopped by Ctrl-C" in out, err
    report = json.loads(report_path.read_text())
    assert_ended_well(pbo.returncode, report, err)
    assert report["stopped_by"] == "Ctrl-C"
    assert all(report["states_at_stop"][name] == "ON" for name in report["tasks"])
    assert_nothing_left(report)


def test_computed_torque_as_a_combined_module_moves_the_arm_to_its_goal(tmp_path):
    """TR Figure 14: PID + inverse dynamics as one task (TR 4.5), on the arm."""
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(REPO / "configs" / "computed_torque.yaml"), "--config", "combined",
                           "--duration", "3", "--clock", "sim", "--report", str(report_path), "--no-live"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    report = json.loads(report_path.read_text())
    q_m = np.array(report["variables"]["q_m"]["value"])
    q_d = np.array(report["variables"]["q_d"]["value"])
    assert np.max(np.abs(q_m - q_d)) < 0.005, f"arm at {q_m}, goal {q_d}"
    assert report["variables"]["tau_u"]["writer"] == "ctc"
    assert report["variables"]["qdd_r"]["sequence"] == 0  # kept local: never written to the table
    assert_nothing_left(report)


def test_cartesian_teleoperation_follows_the_trackball(tmp_path):
    """TR Figure 10's earlier variant (configuration teleop; tests/test_figures.py runs the figure as
    published): trackball -> Cartesian trajectory -> resolved rate -> integrator -> PID -> arm."""
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(REPO / "configs" / "cartesian_teleop.yaml"), "--config", "teleop",
                           "--duration", "5.5", "--clock", "sim",
                           "--report", str(report_path), "--no-live"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=180)
    assert done.returncode == 0, done.stderr
    report = json.loads(report_path.read_text())
    x_m = np.array(report["variables"]["x_m"]["value"])
    x_d = np.array(report["variables"]["x_d"]["value"])
    assert np.max(np.abs(x_m[:3] - x_d[:3])) < 0.002, f"hand at {x_m[:3]}, goal {x_d[:3]}"
    log = read_log(only_file(tmp_path, "runs/*/teleop.mcap"))
    moved = log["x_d"][-1, :3] - log["x_d"][0, :3]
    # the script: 5 cm along x, then 5 cm up (logging starts a tick late)
    assert moved == pytest.approx([0.05, 0.0, 0.05], abs=1e-3)
    assert_nothing_left(report)


def test_an_rtpu_hosting_thirty_tasks_reports_every_one_at_stop(tmp_path):
    # Regression: the RTPU sent all its tasks' statistics in one message; past ~23 tasks it did
    # not fit the queue (8 KiB) and the RTPU crashed at stop, leaving the run report without tasks.
    lines = ["subsystem: many", "rtpus: [rtpu0]", "dims: {NDOF: 6}", "variables:",
             "  q_m: {type: float64, shape: [NDOF], initial: 0.0}", "tasks:"]
    lines += [f"  w{i}: {{module: fault_injector, rtpu: rtpu0, period: 10 ms, params: {{fail_after: 1000000000}}, "
              f"ports: {{watched: q_m}}}}" for i in range(30)]
    lines += ["configurations:"] + [f"  c{i}: [w{i}]" for i in range(30)]
    path = tmp_path / "many.yaml"
    path.write_text("\n".join(lines) + "\n")
    report_path = tmp_path / "report.json"
    done = subprocess.run([*PBO, "run", str(path), "--duration", "0.2", "--clock", "sim", "--report", str(report_path),
                           "--no-live"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    report = json.loads(report_path.read_text())
    assert sorted(report["tasks"]) == sorted(f"w{i}" for i in range(30))
    # c0 is the one on: released at 0, 10, ..., 200 ms of simulated time
    assert report["tasks"]["w0"]["cycles"] == 21 and report["tasks"]["w1"]["cycles"] == 0
    assert_nothing_left(report)
