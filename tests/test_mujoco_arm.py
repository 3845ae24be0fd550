"""The simulated arm's plant and driver, in one process: registers, brakes, torque, cleanup."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pinocchio
import pytest

from drivers.mujoco_arm import driver as driver_module
from drivers.mujoco_arm.driver import MujocoArmDriver
from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.mujoco_arm.registers import W_STATE_SEQ, DeviceError
from drivers.robots import robot
from modules._robot_model import pinocchio_model

TIMESTEP = 0.001
NDOF = 6


def segment_path(name: str) -> Path:
    return Path("/dev/shm") / name.lstrip("/")


@pytest.fixture
def name() -> Iterator[str]:
    name = f"/pbo.test.{os.getpid()}-{os.urandom(4).hex()}.plant"
    yield name
    assert not segment_path(name).exists(), f"{name} left in /dev/shm"


@pytest.fixture
def plant(name: str) -> Iterator[MujocoArmPlant]:
    plant = MujocoArmPlant(name, "puma560", TIMESTEP, {})
    yield plant
    plant.close()


@pytest.fixture
def driver(plant: MujocoArmPlant) -> Iterator[MujocoArmDriver]:
    driver = MujocoArmDriver(plant.name, {"mode": "torque"})
    yield driver
    driver.close()


def read(driver: MujocoArmDriver) -> tuple[np.ndarray, np.ndarray, float]:
    q, qd = np.zeros(driver.ndof), np.zeros(driver.ndof)
    sim_time = driver.read_state(q, qd)
    return q, qd, sim_time


def run(plant: MujocoArmPlant, seconds: float) -> None:
    for _ in range(round(seconds / plant.timestep)):
        plant.step()


def test_driver_reads_what_the_plant_published(plant, driver) -> None:
    driver.release_brakes()
    run(plant, 0.05)
    q, qd, sim_time = read(driver)
    np.testing.assert_array_equal(q, plant.data.qpos)
    np.testing.assert_array_equal(qd, plant.data.qvel)
    assert sim_time == plant.sim_time == pytest.approx(0.05)
    assert driver.step_count == 50


def test_driver_reads_the_constants_the_plant_wrote(plant, driver) -> None:
    puma = robot("puma560")
    assert (driver.ndof, driver.timestep) == (NDOF, TIMESTEP)
    np.testing.assert_array_equal(driver.dh(), puma.dh)
    np.testing.assert_array_equal(driver.dynamics(), puma.dyn)
    np.testing.assert_array_equal(driver.joint_limits(), puma.joint_limits)
    np.testing.assert_array_equal(driver.torque_limits(), puma.torque_limits)


def test_the_plant_starts_braked_at_its_home_pose(plant, driver) -> None:
    assert plant.brakes_engaged and driver.brakes_engaged
    q, qd, sim_time = read(driver)
    np.testing.assert_array_equal(q, robot("puma560").q0)
    assert sim_time == 0.0


def test_arm_does_not_move_while_braked_even_under_torque(plant, driver) -> None:
    driver.write_torque(np.full(NDOF, 10.0))
    run(plant, 0.2)
    q, qd, sim_time = read(driver)
    np.testing.assert_array_equal(q, np.zeros(NDOF))
    np.testing.assert_array_equal(qd, np.zeros(NDOF))
    assert sim_time == pytest.approx(0.2)


def test_arm_falls_under_gravity_after_the_brakes_release(plant, driver) -> None:
    driver.write_torque(np.zeros(NDOF))
    driver.release_brakes()
    run(plant, 0.2)
    q, qd, _ = read(driver)
    # At the home pose the upper arm is level: gravity pulls joint 2 negative (it needs +37 N m to hold).
    assert q[1] < -0.05 and qd[1] < 0


def test_engaging_the_brakes_holds_the_arm_where_it_is(plant, driver) -> None:
    driver.release_brakes()
    run(plant, 0.1)
    driver.engage_brakes()
    plant.step()
    held, _, _ = read(driver)
    run(plant, 0.1)
    q, qd, _ = read(driver)
    np.testing.assert_array_equal(q, held)
    np.testing.assert_array_equal(qd, np.zeros(NDOF))
    assert held[1] < 0


@pytest.mark.parametrize("joint", range(NDOF))
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_torque_command_moves_the_joint_in_the_commanded_direction(plant, driver, joint: int, sign: float) -> None:
    # Like a controller: build the model from the driver's constants, cancel gravity, push one joint.
    model = pinocchio_model(driver.dh(), driver.dynamics())
    data = model.createData()
    q, qd = np.zeros(NDOF), np.zeros(NDOF)
    push = np.zeros(NDOF)
    push[joint] = sign * 0.2 * driver.torque_limits()[joint]
    driver.release_brakes()
    for _ in range(50):
        driver.read_state(q, qd)
        driver.write_torque(pinocchio.computeGeneralizedGravity(model, data, q) + push)
        plant.step()
    driver.read_state(q, qd)
    assert sign * q[joint] > 1e-3
    # Inertial coupling moves the others too (pushing the shoulder swings the elbow), but less.
    assert np.argmax(np.abs(q)) == joint


def test_torque_commands_are_clipped_to_the_torque_limits(plant, driver) -> None:
    driver.release_brakes()
    driver.write_torque(np.full(NDOF, -1e6))
    plant.step()
    np.testing.assert_array_equal(plant.data.qfrc_applied, -driver.torque_limits())
    assert driver.commands_written == 1


def test_segment_is_created_owner_only(plant) -> None:
    assert stat.S_IMODE(segment_path(plant.name).stat().st_mode) == 0o600


def test_close_leaves_nothing_in_dev_shm(name) -> None:
    plant = MujocoArmPlant(name, "puma560", TIMESTEP, {})
    driver = MujocoArmDriver(name, {"mode": "torque"})
    assert segment_path(name).exists()
    driver.close()
    assert segment_path(name).exists(), "a driver must never remove the plant's segment"
    plant.close()
    plant.close()
    driver.close()
    assert not segment_path(name).exists()


def test_a_second_plant_on_the_same_segment_is_refused_and_leaves_the_first_alone(plant) -> None:
    with pytest.raises(DeviceError, match=r"^register segment '/pbo\.test\..*' already exists"):
        MujocoArmPlant(plant.name, "puma560", TIMESTEP, {})
    assert segment_path(plant.name).exists()


def test_opening_a_driver_on_a_missing_segment_says_the_plant_is_not_running(name) -> None:
    message = r"^no register segment '/pbo\.test\..*': the plant that owns it is not running"
    with pytest.raises(DeviceError, match=message):
        MujocoArmDriver(name, {"mode": "torque"})


def test_a_wrong_mode_names_the_valid_modes(plant) -> None:
    with pytest.raises(ValueError, match=r"^mujoco_arm driver mode must be one of: torque; got: 'velocity'$"):
        MujocoArmDriver(plant.name, {"mode": "velocity"})


def test_an_unknown_driver_option_is_an_error(plant) -> None:
    with pytest.raises(ValueError, match=r"^unknown mujoco_arm driver option\(s\) \['gain'\]; valid options: mode$"):
        MujocoArmDriver(plant.name, {"mode": "torque", "gain": 2})


def test_an_unknown_robot_model_names_the_known_ones(name) -> None:
    with pytest.raises(ValueError, match=r"^unknown robot model 'puma600'; known models: puma560"):
        MujocoArmPlant(name, "puma600", TIMESTEP, {})


def test_read_state_gives_up_on_a_plant_stuck_mid_publish(plant, driver, monkeypatch) -> None:
    monkeypatch.setattr(driver_module, "_STUCK_AFTER_S", 0.01)
    plant._registers.words[W_STATE_SEQ] += 1  # as if the plant died between the two seqlock writes
    with pytest.raises(DeviceError, match=r"mid-publish .*did the plant process die\?$"):
        read(driver)
