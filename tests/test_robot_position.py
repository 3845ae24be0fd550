"""The position-mode robot interface, driven through a real Task on a real table.

The arm is an in-process MuJoCo plant stepped by hand, one plant step per task cycle (the task's
period is the plant's timestep), for both robots the plant can build.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.mujoco_arm.driver import MujocoArmDriver
from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.mujoco_arm.registers import DeviceError
from drivers.robots import RobotDescription, robot
from modules.robot_position import RobotPosition
from pbo_runtime import Status
from pbo_runtime.config.model import DeviceSpec, TaskSpec
from pbo_runtime.table.table import StateTable, TaskState
from pbo_runtime.task.lifecycle import Task
from tests.support import NO_WATCHDOG, arm_constants, arm_tables, task_spec, unique_name, variables

ROBOTS = ("puma560", "redundant7")
TIMESTEP = 0.001
ARM = DeviceSpec("arm", "mujoco_arm", True, {"mode": "position"})


@pytest.fixture(params=ROBOTS)
def plant(request) -> Iterator[MujocoArmPlant]:
    plant = MujocoArmPlant(unique_name("plant"), request.param, TIMESTEP, NO_WATCHDOG)
    try:
        yield plant
    finally:
        plant.close()


@pytest.fixture
def desc(plant: MujocoArmPlant) -> RobotDescription:
    return robot(plant.robot.name)


@pytest.fixture
def table(make_table, plant: MujocoArmPlant) -> StateTable:
    n = plant.ndof
    return make_table(
        variables(
            *arm_constants(n),
            ("q_m", "float64", (n,)), ("qd_m", "float64", (n,)), ("q_r", "float64", (n,)),
        )
    )


@pytest.fixture
def observer(plant: MujocoArmPlant) -> Iterator[MujocoArmDriver]:
    """A second driver on the same registers, to see the brake request without the task's."""
    driver = MujocoArmDriver(plant.name, {"mode": "position"})
    try:
        yield driver
    finally:
        driver.close()


class RecordingDriver(MujocoArmDriver):
    """The real driver, remembering whether it was closed."""

    closed = False

    def close(self) -> None:
        self.closed = True
        super().close()


def robot_task(table: StateTable, plant: MujocoArmPlant, device: DeviceSpec = ARM,
               ndof: int | None = None) -> tuple[Task, list[RecordingDriver]]:
    opened: list[RecordingDriver] = []

    def opener(spec: DeviceSpec, _task: TaskSpec) -> RecordingDriver:
        driver = RecordingDriver(plant.name, spec.options)
        opened.append(driver)
        return driver

    dims = {"NDOF": plant.ndof if ndof is None else ndof}
    spec = dataclasses.replace(task_spec(RobotPosition, dims=dims, period=plant.timestep), resources=("arm",))
    return Task(spec, RobotPosition, table, dims, devices={"arm": device}, opener=opener), opened


@pytest.fixture
def task(table, plant) -> Iterator[Task]:
    task, _ = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    yield task
    if task.state is not TaskState.KILLED:
        task.kill()


class Clock:
    """Cycles of the task, each followed by one plant step, at the plant's rate."""

    def __init__(self, table: StateTable, plant: MujocoArmPlant, task: Task) -> None:
        self.table, self.plant, self.task, self.k = table, plant, task, 0

    def run(self, seconds: float, q_r: np.ndarray | None = None, stable: bool = False) -> None:
        for _ in range(round(seconds / self.plant.timestep)):
            self.k += 1
            now = self.k * self.plant.timestep
            if q_r is not None:
                self.table.write("q_r", q_r, when=now)
            run = self.task.run_stable_cycle if stable else self.task.run_cycle
            assert run(now) is Status.CONTINUE, self.task.last_error
            self.plant.step()


def q_m(table: StateTable) -> np.ndarray:
    return table.read("q_m")[0]


def test_spawn_publishes_ndof_arm_and_ee_of_the_arm(table, plant, desc, task):
    ndof, _, _, writer = table.read("NDOF")
    assert ndof == desc.ndof and writer == task.index
    arm, ee = arm_tables(desc.name)
    np.testing.assert_array_equal(table.read("ARM")[0], arm)
    np.testing.assert_array_equal(table.read("EE")[0], ee)
    assert table.read("ARM")[3] == table.read("EE")[3] == task.index


def test_on_releases_the_brakes_without_moving_the_arm(table, plant, desc, task, observer):
    table.write("q_r", desc.q0 + 0.5, when=0.0)  # a stale reference far from the arm
    assert observer.brakes_engaged
    assert task.turn_on(0.0), task.last_error
    assert not observer.brakes_engaged and observer.active_mode == "position"
    np.testing.assert_array_equal(q_m(table), desc.q0)
    np.testing.assert_array_equal(table.read("qd_m")[0], np.zeros(desc.ndof))
    for _ in range(500):  # 0.5 s of the plant with no cycle: only what `on` commanded acts
        plant.step()
    assert not plant.brakes_engaged
    np.testing.assert_allclose(plant.data.qpos, desc.q0, rtol=0, atol=1e-9)


def test_cycle_tracks_q_r_and_publishes_the_state_the_plant_stepped(table, plant, desc, task):
    assert task.turn_on(0.0), task.last_error
    clock = Clock(table, plant, task)
    clock.run(0.1, q_r=desc.q0)
    np.testing.assert_allclose(q_m(table), desc.q0, rtol=0, atol=1e-9)  # holds, no sag
    goal = desc.q0 + np.linspace(-0.2, 0.2, desc.ndof)
    clock.run(1.0, q_r=goal)
    q, seq, when, writer = table.read("q_m")
    np.testing.assert_allclose(q, goal, rtol=0, atol=1e-3)
    assert (seq, when, writer) == (clock.k, clock.k * plant.timestep, task.index)
    # q_m is the plant's state as of its step before the last cycle, exactly
    clock.run(0.001, q_r=goal)
    plant_q = plant.data.qpos.copy()
    plant.step()  # not seen yet
    np.testing.assert_array_equal(q_m(table), plant_q)


def test_stable_cycle_holds_where_the_arm_was_and_ignores_q_r(table, plant, desc, task):
    assert task.turn_on(0.0), task.last_error
    clock = Clock(table, plant, task)
    start = desc.q0 + 0.1
    clock.run(1.0, q_r=start)
    np.testing.assert_allclose(q_m(table), start, rtol=0, atol=1e-3)
    clock.run(0.5, q_r=desc.q0 - 0.3, stable=True)  # the configuration went illegal; q_r moves on
    held = q_m(table)
    np.testing.assert_allclose(held, start, rtol=0, atol=1e-3)
    np.testing.assert_allclose(plant.data.qvel, 0.0, rtol=0, atol=1e-6)
    assert not plant.brakes_engaged  # held by the servo, ready to go on
    # legal again: tracking q_r resumes
    clock.run(1.0, q_r=desc.q0 - 0.3)
    np.testing.assert_allclose(q_m(table), desc.q0 - 0.3, rtol=0, atol=1e-3)


def test_stable_cycle_entered_mid_move_stops_the_arm_where_it_was(table, plant, desc, task):
    assert task.turn_on(0.0), task.last_error
    clock = Clock(table, plant, task)
    goal = desc.q0 + 0.3
    clock.run(0.03, q_r=goal)  # on its way
    moving = plant.data.qpos.copy()
    assert np.abs(moving - desc.q0).max() > 0.01 and np.abs(moving - goal).max() > 0.01
    clock.run(1.0, q_r=goal, stable=True)
    np.testing.assert_allclose(plant.data.qpos, moving, rtol=0, atol=1e-3)
    assert np.abs(plant.data.qpos - goal).max() > 0.1


def test_off_engages_the_brakes(table, plant, desc, task, observer):
    assert task.turn_on(0.0), task.last_error
    Clock(table, plant, task).run(0.01, q_r=desc.q0)
    task.turn_off()
    assert observer.brakes_engaged
    plant.step()
    assert plant.brakes_engaged


def test_kill_engages_the_brakes_and_closes_the_driver(table, plant, observer):
    task, opened = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    task.turn_off()
    observer.write_position(plant.data.qpos)
    observer.release_brakes()  # someone let go of the arm while the task was off
    task.kill()
    assert observer.brakes_engaged
    assert [d.closed for d in opened] == [True]
    assert task.state is TaskState.KILLED and task.last_error == ""


def test_init_fails_on_a_device_opened_in_torque_mode(table, plant, observer):
    torque = DeviceSpec("arm", "mujoco_arm", True, {"mode": "torque"})
    task, opened = robot_task(table, plant, device=torque)
    assert not task.spawn(0.0)
    assert task.state is TaskState.KILLED
    assert task.last_error.startswith(
        "init raised ModuleError: the arm on device 'arm' is opened in torque mode; RobotPosition needs the "
        "device's option mode: position at _robot_interface.py:"
    )
    assert [d.closed for d in opened] == [True]
    assert observer.brakes_engaged


def test_init_fails_when_ndof_differs_from_the_arms_joints(make_table, plant, observer):
    n = plant.ndof - 1
    table = make_table(variables(*arm_constants(n),
                                 ("q_m", "float64", (n,)), ("qd_m", "float64", (n,)), ("q_r", "float64", (n,))))
    task, opened = robot_task(table, plant, ndof=n)
    assert not task.spawn(0.0)
    assert task.last_error.startswith(
        f"init raised ModuleError: the arm on device 'arm' has {plant.ndof} joints, but the configuration says NDOF = {n}"
    )
    assert [d.closed for d in opened] == [True]


def test_a_torque_driver_takes_the_arm_only_after_the_position_task_is_off(table, plant, desc, task):
    """The hand-over goes through the brakes: the position task's off, then the torque side's release."""
    assert task.turn_on(0.0), task.last_error
    torque = MujocoArmDriver(plant.name, {"mode": "torque"})
    try:
        with pytest.raises(DeviceError, match="another driver is commanding the arm in position mode"):
            torque.release_brakes()
        Clock(table, plant, task).run(0.1, q_r=desc.q0)
        np.testing.assert_allclose(plant.data.qpos, desc.q0, rtol=0, atol=1e-9)
        task.turn_off()
        torque.write_torque(plant.gravity_torque(plant.data.qpos, np.zeros(desc.ndof)))
        torque.release_brakes()
        assert torque.active_mode == "torque"
    finally:
        torque.close()
