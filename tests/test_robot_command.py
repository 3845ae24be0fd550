"""`pbo robot MODEL|FILE`: the arm's limits, masses and inertia range, held to Pinocchio and MuJoCo."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pinocchio
import pytest

from drivers.robots.plant_model import load_robot
from pbo_runtime import arm_model, inertia_range
from tests.support import PBO, REPO, example_robot

pytestmark = pytest.mark.multiprocess  # each test runs the `pbo` command

ARMS = {"puma560": "puma560", "ur5": example_robot("ur5"), "xarm7": example_robot("xarm7")}


def robot_json(*args: str) -> dict:
    done = subprocess.run([*PBO, "robot", *args, "--format", "json"], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.fixture(scope="module", params=sorted(ARMS))
def arm(request):
    """(the loaded robot, what `pbo robot` says of it) for each arm in turn."""
    model = ARMS[request.param]
    return load_robot(model, Path(REPO), 0.001, {}), robot_json(model)


def mujoco_diagonal(robot, q: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(robot.model)
    data.qpos[:] = q
    mujoco.mj_forward(robot.model, data)
    full = np.zeros((robot.model.nv, robot.model.nv))
    mujoco.mj_fullM(robot.model, data, full)
    return np.diag(full)


def test_pbo_robot_lists_every_joint_with_the_limits_the_check_lists(arm):
    robot, said = arm
    assert said["ndof"] == robot.ndof == len(said["joints"])
    assert said["end_effector"] == robot.ee_name
    for row, limits in zip(said["joints"], robot.limit_rows(), strict=True):
        assert {k: row[k] for k in limits} == limits
        assert row["mass"] >= 0 and 0 < row["inertia_coupled_min"] <= row["inertia_min"] <= row["inertia_max"]


def test_the_inertia_range_is_pinocchios_crba_and_mujocos_mass_matrix_at_the_poses_it_names(arm):
    robot, said = arm
    found = inertia_range(robot.arm, robot.ee)
    model = arm_model(robot.arm, robot.ee)
    data = model.createData()
    for j, row in enumerate(said["joints"]):
        for value, pose in ((row["inertia_min"], found.low_pose[j]), (row["inertia_max"], found.high_pose[j])):
            assert pinocchio.crba(model, data, pose)[j, j] == pytest.approx(value, rel=1e-9)
            assert mujoco_diagonal(robot, pose)[j] == pytest.approx(value, rel=1e-6, abs=1e-9)
    at_zero = mujoco_diagonal(robot, np.clip(0.0, robot.joint_limits[:, 0], robot.joint_limits[:, 1]))
    lows, highs = np.array([r["inertia_min"] for r in said["joints"]]), np.array([r["inertia_max"] for r in said["joints"]])
    assert np.all(lows <= at_zero + 1e-9) and np.all(at_zero <= highs + 1e-9)


def test_a_bandwidth_gives_gains_from_the_inertia_and_the_torque_of_a_step():
    said = robot_json(ARMS["ur5"], "--bandwidth", "30", "--damping", "1.0", "--step", "0.1")
    for row in said["joints"]:
        assert row["kp"] == pytest.approx(row["design_inertia"] * 30 ** 2)
        assert row["kd"] == pytest.approx(2 * row["design_inertia"] * 30)
        assert row["inertia_coupled_min"] <= row["design_inertia"] <= row["inertia_max"]
        assert row["step_torque"] == pytest.approx(0.1 * row["kp"])
        assert row["within_effort"] == (row["step_torque"] <= row["effort"])
        assert row["stable"] and row["damping_ratio"] >= 0.3
    wrist = said["joints"][5]
    assert wrist["design_inertia"] == wrist["inertia_max"]  # nearly constant: made for its heaviest pose


@pytest.mark.parametrize("args, message", [
    (["no_such_robot"], "no_such_robot"),
    (["robots/missing.urdf"], "does not exist"),
    (["puma560", "--bandwidth", "-3"], "--bandwidth must be > 0"),
])
def test_pbo_robot_refuses_what_it_cannot_describe_without_a_traceback(args, message):
    done = subprocess.run([*PBO, "robot", *args], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert done.returncode == 1
    assert message in done.stderr and "Traceback" not in done.stderr


def test_pbo_robot_prints_a_table_a_joint_a_line():
    done = subprocess.run([*PBO, "robot", "puma560", "--bandwidth", "20"], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "inertia min" in done.stdout and "joint6" in done.stdout and "damping ratio" in done.stdout
