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

from drivers.mujoco_arm.registers import DeviceError
from drivers.ros2_control.driver import Ros2ControlArm
from tests.support import (
    PBO,
    REPO,
    allocation_peak,
    arm_tables,
    config_copy,
    one_array,
    own_dds_domain,
    read_until,
    run_output,
    start_run,
    unique_name,
    until,
)

GOAL = [0.3, -0.5, 0.5, 0.2, 0.4, 0.2]  # configs/ros2_control.yaml's initial q_d: the demo's move


@pytest.mark.parametrize("options, wanted", [
    ({"mode": "velocity"}, r"mode must be torque \(an effort controller\) or position"),
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
        _out, err = stop_run_and_arm(run, arm)
    assert "Traceback" not in err, err
    report = json.loads(report_path.read_text())
    assert run.returncode == 2, err
    assert any(fault.startswith("critical task 'robot' ran its locally stable behaviour") and fault.endswith(
        "the module's own inputs are not fresh (its cycle returned STABLE)") for fault in report["faults"]), report["faults"]


def stop_run_and_arm(run: subprocess.Popen, arm: subprocess.Popen) -> tuple[str, str]:
    """Stop the run as Ctrl-C does (if it still runs) and kill the stand-in arm: the run's (stdout, stderr)."""
    if run.poll() is None:
        run.send_signal(signal.SIGINT)
    out, err = run_output(run)
    arm.kill()
    run_output(arm)
    return out, err


def position_mode_copy(folder):
    """ros2_control.yaml with the arm in position mode: robot_position tracks the trajectory's q_r, no PID."""
    text = (REPO / "configs" / "ros2_control.yaml").read_text()
    for old, new in (("subsystem: ros2_control\n", f"subsystem: ros2_position_{os.getpid()}\n"),
                     ("mode: torque", "mode: position"),
                     ("commands: /forward_effort_controller/commands", "commands: /forward_position_controller/commands"),
                     ("module: robot_torque", "module: robot_position"),
                     ("  joint_pid: [robot, traj, pid]", "  joint_position: [robot, traj]")):
        assert old in text, old
        text = text.replace(old, new)
    text = text.replace(text[text.index("  pid:"):text.index("\nconfigurations:")], "")
    path = folder / "ros2_position.yaml"
    path.write_text(text)
    return path


@pytest.mark.multiprocess
def test_in_position_mode_the_trajectory_goes_to_a_ros2_control_position_controller_and_the_arm_reaches_its_goal(
        tmp_path, monkeypatch):
    domain = own_dds_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    arm = subprocess.Popen([sys.executable, "-m", "tests.ros2_control_peer", str(domain), "300", *map(str, GOAL), "--position"],
                           cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    config = position_mode_copy(tmp_path)
    checked = subprocess.run([*PBO, "check", str(config)], capture_output=True, text=True, timeout=120)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    run = start_run(config, tmp_path, "--duration", "300")
    try:
        reached = json.loads(read_until(arm, '"reached"').strip().splitlines()[-1])
        assert np.abs(np.subtract(reached["q"], GOAL)).max() < 0.01  # held there for 0.5 s, by the arm's own account
    finally:
        _out, err = stop_run_and_arm(run, arm)
    assert "Traceback" not in err, err  # (braked without position commands, the arm would never have left q0)


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


@pytest.fixture
def plant_registers():
    """An arm register segment as a running plant leaves it for drivers: the PUMA 560's constants."""
    from drivers.mujoco_arm.registers import MAGIC, W_MAGIC, create_registers

    name = unique_name("ros2-regs")
    shm, registers = create_registers(name, 6)
    arm, ee = arm_tables("puma560")
    registers.arm[:] = arm
    registers.ee[:] = ee
    registers.words[W_MAGIC] = MAGIC
    yield name
    registers.release()
    shm.unlink()


@pytest.mark.multiprocess
def test_the_driver_takes_the_robots_joints_by_name_in_its_own_order_and_its_cycle_calls_allocate_nothing(plant_registers):
    domain = own_dds_domain()
    names_sent = [3, 1, 2, 6, 5, 4]  # the robot's order differs from the driver's
    positions = [0.3, 0.1, 0.2, 0.6, 0.5, 0.4]
    robot = subprocess.Popen([sys.executable, "-m", "tests.ros2_peer", "publish", str(domain), "/joint_states",
                              "sensor_msgs/msg/JointState", "20", *map(str, names_sent + positions)], cwd=REPO,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        driver = Ros2ControlArm(plant_registers, {"domain": domain})  # waits for the first JointState
        try:
            q, qd = np.zeros(6), np.zeros(6)
            stamp = driver.read_state(q, qd)
            assert stamp >= 1.0  # the header stamp: the arm's time
            np.testing.assert_array_equal(q, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
            np.testing.assert_array_equal(qd, q)
            np.testing.assert_array_equal(driver.arm(), arm_tables("puma560")[0])
            # short windows: the robot's JointStates (20 Hz) arrive on the driver's thread meanwhile
            assert allocation_peak(lambda: driver.read_state(q, qd), times=100) < one_array()
            driver.write_torque(np.full(6, 1.0))
            assert driver.published == 0  # the brakes are engaged: no command goes out
            driver.release_brakes()
            driver.write_torque(np.full(6, 1.0))
            until(lambda: driver.published == 1, "the command is published")
            with pytest.raises(DeviceError, match="not finite"):
                driver.write_torque(np.full(6, np.nan))
            with pytest.raises(DeviceError, match="write_position on an arm opened in torque mode"):
                driver.write_position(np.zeros(6))
        finally:
            driver.close()
        positioned = Ros2ControlArm(plant_registers, {"domain": domain, "mode": "position"})
        try:
            assert positioned.mode == "position"
            with pytest.raises(DeviceError, match="write_torque on an arm opened in position mode"):
                positioned.write_torque(np.zeros(6))
            positioned.release_brakes()
            positioned.write_position(np.full(6, 0.1))
            until(lambda: positioned.published == 1, "the position command is published")
        finally:
            positioned.close()
    finally:
        robot.kill()
        run_output(robot)


def joint_states_of(domain: int, names: list[int], positions: list[float]) -> subprocess.Popen:
    """A robot's joint_state_broadcaster stand-in: JointStates of joints `names` (joint<n>) at 100 Hz."""
    return subprocess.Popen([sys.executable, "-m", "tests.ros2_peer", "publish", str(domain), "/joint_states",
                             "sensor_msgs/msg/JointState", "60", *map(str, names + positions)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.multiprocess
def test_a_driver_whose_dds_process_dies_keeps_the_last_state_and_the_run_says_so(plant_registers, capfd):
    domain = own_dds_domain()
    robot = joint_states_of(domain, [1, 2, 3, 4, 5, 6], [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    try:
        driver = Ros2ControlArm(plant_registers, {"domain": domain})
        try:
            q, qd = np.zeros(6), np.zeros(6)
            until(lambda: driver.read_state(q, qd) >= 1.0, "a whole state is read")
            dds = driver._dds
            dds.process.kill()
            until(lambda: dds.ended, "the driver learns that its DDS process ended")
            stamp = driver.read_state(q, qd)
            assert driver.read_state(q, qd) == stamp >= 1.0  # no new state can come: the arm's time stands still
            np.testing.assert_array_equal(q, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
            ended = f"ros2_control driver: its DDS process (pid {dds.process.pid}) ended with exit status -9"
            assert driver.figures()["dds_process"] == ended
        finally:
            driver.close()
    finally:
        robot.kill()
        run_output(robot)
    assert f"{ended}: the arm's state is stale from now on, and no command goes out" in capfd.readouterr().err


@pytest.mark.multiprocess
def test_a_joint_state_that_lacks_a_joint_is_refused_naming_what_it_has_and_what_is_needed(plant_registers, capfd):
    domain = own_dds_domain()
    robot = joint_states_of(domain, [1, 2, 3], [0.1, 0.2, 0.3])  # three joints of the six
    try:
        with pytest.raises(DeviceError, match="no JointState of the joints"):
            Ros2ControlArm(plant_registers, {"domain": domain})
    finally:
        robot.kill()
        run_output(robot)
    assert ("ros2_control driver: refused a JointState on /joint_states (names ['joint1', 'joint2', 'joint3'], 3 positions; "
            "it needs the joints ['joint1', 'joint2', 'joint3', 'joint4', 'joint5', 'joint6']); 1 refused so far"
            ) in capfd.readouterr().err
