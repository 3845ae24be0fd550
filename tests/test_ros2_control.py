"""The ros2_control driver: pbo's PID demo drives an arm behind ros2_control through DDS alone.

The arm is a MuJoCo PUMA 560 in a process of its own that plays the ros2_control side
(tests/ros2_control_peer.py: a joint_state_broadcaster's `/joint_states`, a forward effort
controller's `/forward_effort_controller/commands`), on a DDS domain of this test's own.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from drivers.ros2_control.driver import Ros2ControlArm  # noqa: E402
from tests.support import PBO, REPO, config_copy, own_dds_domain, read_until, run_output, start_run  # noqa: E402

GOAL = [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]  # configs/ros2_control.yaml's initial q_d: the demo's move


@pytest.mark.parametrize("options, wanted", [
    ({"mode": "position"}, "mode must be torque"),
    ({"joints": ["a", "a"]}, "joints must be a list of distinct joint names"),
    ({"domain": 300}, r"domain must be an integer in \[-1, 232\]"),
    ({"stall_after": 0}, r"stall_after must be seconds in \(0, 10\]"),
    ({"commands": "/"}, "commands must be a ROS 2 topic name"),
    ({"rate": 5}, r"unknown ros2_control driver option\(s\) \['rate'\]"),
])
def test_a_ros2_control_option_out_of_its_rules_is_refused(options, wanted):
    with pytest.raises(ValueError, match=wanted):
        Ros2ControlArm.check_options(options)


@pytest.mark.multiprocess
def test_the_demos_pid_brings_a_ros2_control_arm_to_its_goal_and_holds_when_joint_states_stop(tmp_path, monkeypatch):
    domain = own_dds_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    arm = subprocess.Popen([sys.executable, "-m", "tests.ros2_control_peer", str(domain), "300", *map(str, GOAL),
                            "--silent-after", "1"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    config = config_copy(REPO / "configs" / "ros2_control.yaml", tmp_path, f"ros2_control_{os.getpid()}")
    report_path = tmp_path / "report.json"
    run = start_run(config, tmp_path, "--duration", "300", "--report", str(report_path))
    try:
        reached = json.loads(read_until(arm, '"reached"').strip().splitlines()[-1])
        assert np.abs(np.subtract(reached["q"], GOAL)).max() < 0.01  # held there for 0.5 s, by the arm's own account
        read_until(arm, '"silent"')  # its /joint_states stop
        said = read_until(run, "critical task 'robot' runs its locally stable behaviour: the module's own inputs are not fresh")
        assert "the module's own inputs are not fresh" in said, said
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
        out, err = run_output(run)
        arm.kill()
        run_output(arm)
    assert "Traceback" not in err, err
    report = json.loads(report_path.read_text())
    assert run.returncode == 2, err
    assert any(fault.startswith("critical task 'robot' ran its locally stable behaviour") and fault.endswith(
        "the module's own inputs are not fresh (its cycle returned STABLE)") for fault in report["faults"]), report["faults"]


@pytest.mark.multiprocess
def test_a_robot_whose_joint_states_never_come_is_never_driven_and_the_run_says_why(tmp_path, monkeypatch):
    domain = own_dds_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))  # no ros2_control there
    config = config_copy(REPO / "configs" / "ros2_control.yaml", tmp_path, f"ros2_nobody_{os.getpid()}")
    done = subprocess.run([*PBO, "run", str(config), "--duration", "1", "--no-live"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=180)
    assert done.returncode != 0
    assert "Traceback" not in done.stderr, done.stderr
    assert (f"ros2_control driver: no JointState of the joints ['joint1', 'joint2', 'joint3', 'joint4', 'joint5', 'joint6'] "
            f"on /joint_states (DDS domain {domain}) within 5 s") in done.stdout + done.stderr
