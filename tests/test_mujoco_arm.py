"""The simulated arm's plant and driver, in one process: registers, brakes, torque, cleanup."""

from __future__ import annotations

import stat
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np
import pinocchio
import pytest

from drivers.mujoco_arm import driver as driver_module
from drivers.mujoco_arm.driver import MujocoArmDriver
from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.mujoco_arm.registers import W_STATE_SEQ, DeviceError
from drivers.robots import robot
from pbo_runtime import Arm, arm_model
from tests.support import NO_WATCHDOG, arm_tables, dh_pinocchio_model, unique_name

TIMESTEP = 0.001
NDOF = 6


def segment_path(name: str) -> Path:
    return Path("/dev/shm") / name.lstrip("/")


@pytest.fixture
def name() -> str:
    """The plant's segment name; conftest's no_leftover_ipc fails the test if the segment outlives it."""
    return unique_name("plant")


@pytest.fixture
def plant(name: str) -> Iterator[MujocoArmPlant]:
    plant = MujocoArmPlant(name, "puma560", TIMESTEP, NO_WATCHDOG)
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
    arm, ee = arm_tables("puma560")
    np.testing.assert_array_equal(driver.arm(), arm)
    np.testing.assert_array_equal(driver.end_effector(), ee)
    np.testing.assert_array_equal(driver.arm()[:, Arm.ARMATURE], puma.dyn[:, 10])
    np.testing.assert_array_equal(driver.joint_limits(), puma.joint_limits)
    np.testing.assert_array_equal(driver.torque_limits(), puma.torque_limits)


def test_the_plant_starts_braked_at_its_home_pose(plant, driver) -> None:
    assert plant.brakes_engaged and driver.brakes_engaged
    q, _qd, sim_time = read(driver)
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


def test_a_plant_without_io_boards_moves_the_arm_bit_for_bit_as_one_with_them() -> None:
    # Without boards nobody reads the wrist sensor, and each step leaves its computation out.
    states = []
    for boards in (True, False):
        plant = MujocoArmPlant(unique_name("plant"), "puma560", TIMESTEP, NO_WATCHDOG, boards=boards)
        driver = MujocoArmDriver(plant.name, {"mode": "torque"})
        try:
            driver.write_torque(np.array([0.0, 30.0, 5.0, 0.5, -0.5, 0.1]))
            driver.release_brakes()
            run(plant, 0.3)
            q, qd, sim_time = read(driver)
            states.append((q.tobytes(), qd.tobytes(), sim_time))
        finally:
            driver.close()
            plant.close()
    assert states[0] == states[1]


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
    model = arm_model(driver.arm(), driver.end_effector())
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
    plant = MujocoArmPlant(name, "puma560", TIMESTEP, NO_WATCHDOG)
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
        MujocoArmPlant(plant.name, "puma560", TIMESTEP, NO_WATCHDOG)
    assert segment_path(plant.name).exists()


def test_opening_a_driver_on_a_missing_segment_says_the_plant_is_not_running(name) -> None:
    message = r"^no register segment '/pbo\.test\..*': the plant that owns it is not running"
    with pytest.raises(DeviceError, match=message):
        MujocoArmDriver(name, {"mode": "torque"})


def test_a_wrong_mode_names_the_valid_modes(plant) -> None:
    with pytest.raises(ValueError, match=r"^mujoco_arm driver mode must be one of: torque, position; got: 'velocity'$"):
        MujocoArmDriver(plant.name, {"mode": "velocity"})


def test_an_unknown_driver_option_is_an_error(plant) -> None:
    with pytest.raises(ValueError, match=r"^unknown mujoco_arm driver option\(s\) \['gain'\]; valid options: mode$"):
        MujocoArmDriver(plant.name, {"mode": "torque", "gain": 2})


def test_an_unknown_robot_model_names_the_known_ones(name) -> None:
    with pytest.raises(ValueError, match=r"^no robot model named 'puma600' \(registered: puma560, redundant7\)"):
        MujocoArmPlant(name, "puma600", TIMESTEP, NO_WATCHDOG)


def test_read_state_gives_up_on_a_plant_stuck_mid_publish(plant, driver, monkeypatch) -> None:
    monkeypatch.setattr(driver_module, "_STUCK_AFTER_S", 0.01)
    plant._registers.words[W_STATE_SEQ] += 1  # as if the plant died between the two seqlock writes
    with pytest.raises(DeviceError, match=r"mid-publish .*did the plant process die\?$"):
        read(driver)


# --- position mode -------------------------------------------------------------------------------

ROBOTS = ("puma560", "redundant7")


@pytest.fixture(params=ROBOTS)
def any_plant(request, name: str) -> Iterator[MujocoArmPlant]:
    plant = MujocoArmPlant(name, request.param, TIMESTEP, NO_WATCHDOG)
    yield plant
    plant.close()


@pytest.fixture
def positioner(any_plant: MujocoArmPlant) -> Iterator[MujocoArmDriver]:
    driver = MujocoArmDriver(any_plant.name, {"mode": "position"})
    yield driver
    driver.close()


def hold_here(plant: MujocoArmPlant, driver: MujocoArmDriver) -> np.ndarray:
    """Command the current position and release the brakes, as a position interface's `on` does."""
    q, _, _ = read(driver)
    driver.write_position(q)
    driver.release_brakes()
    return q


def test_the_plant_builds_the_7_dof_arm_and_publishes_its_constants(name) -> None:
    arm = robot("redundant7")
    with MujocoArmPlant(name, "redundant7", TIMESTEP, NO_WATCHDOG) as plant:
        driver = MujocoArmDriver(name, {"mode": "position"})
        assert (driver.ndof, plant.ndof) == (7, 7)
        np.testing.assert_array_equal(driver.arm(), arm_tables("redundant7")[0])
        np.testing.assert_array_equal(driver.end_effector(), arm_tables("redundant7")[1])
        np.testing.assert_array_equal(driver.joint_limits(), arm.joint_limits)
        np.testing.assert_array_equal(driver.torque_limits(), arm.torque_limits)
        np.testing.assert_array_equal(read(driver)[0], arm.q0)
        driver.close()


def test_position_mode_holds_the_arm_against_gravity_without_sag(any_plant, positioner) -> None:
    q0 = hold_here(any_plant, positioner)
    assert positioner.active_mode == "position"
    run(any_plant, 1.0)
    q, qd, _ = read(positioner)
    assert not any_plant.brakes_engaged
    np.testing.assert_allclose(q, q0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(qd, 0.0, rtol=0, atol=1e-9)
    # what holds it is the servo's gravity torque, not a brake
    gravity = any_plant.gravity_torque(q, np.zeros(any_plant.ndof))
    assert np.abs(gravity).max() > 10.0
    np.testing.assert_allclose(any_plant.data.qfrc_applied, gravity, rtol=0, atol=1e-6)


def step_joint(plant: MujocoArmPlant, driver: MujocoArmDriver, joint: int | None, size: float) -> np.ndarray:
    """Step joint (or every joint) by `size` from where it holds; 1 s of plant steps; the trace."""
    q0 = hold_here(plant, driver)
    target = q0.copy()
    if joint is None:
        target += size
    else:
        target[joint] += size
    driver.write_position(target)
    trace = np.empty((round(1.0 / plant.timestep), plant.ndof))
    for k in range(len(trace)):
        plant.step()
        trace[k] = plant.data.qpos
        assert np.all(np.abs(plant.data.qfrc_applied) <= plant.robot.torque_limits)
    return target, trace


@pytest.mark.parametrize(
    ("any_plant", "joint"), [(r, j) for r in ROBOTS for j in range(robot(r).ndof)], indirect=["any_plant"]
)
@pytest.mark.parametrize("size", [0.2, -0.2])
def test_a_position_step_brings_each_joint_within_1e_3_rad_in_1_s(any_plant, positioner, joint, size) -> None:
    target, trace = step_joint(any_plant, positioner, joint, size)
    np.testing.assert_allclose(trace[-1], target, rtol=0, atol=1e-3)
    # the step took well under the second, without overshoot, and the other joints held on
    error = np.abs(trace - target).max(axis=1)
    assert error[300:].max() < 1e-3
    assert (size * (trace[:, joint] - target[joint])).max() < 1e-3


def test_a_step_of_every_joint_at_once_settles_too(any_plant, positioner) -> None:
    target, trace = step_joint(any_plant, positioner, None, -0.3)
    np.testing.assert_allclose(trace[-1], target, rtol=0, atol=1e-3)


def test_a_small_step_is_the_critically_damped_linear_servo(any_plant, positioner) -> None:
    """Below saturation the loop is Kp e - Kd qd on J: 10-90 % rise 3.36 / w, no overshoot."""
    last = any_plant.ndof - 1  # a wrist joint: its inertia hardly changes with the pose
    size = 1e-5
    target, trace = step_joint(any_plant, positioner, last, size)
    response = (trace[:, last] - (target[last] - size)) / size
    rise = (np.argmax(response >= 0.9) - np.argmax(response >= 0.1)) * any_plant.timestep
    assert rise == pytest.approx(3.36 / any_plant.servo_omega, rel=0.15)
    assert response.max() < 1.01
    assert abs(response[-1] - 1.0) < 1e-6


def test_servo_gains_are_critically_damped_on_the_joint_inertia_at_25_hz(any_plant) -> None:
    desc = robot(any_plant.robot.name)
    full = np.zeros((desc.ndof, desc.ndof))
    data = type(any_plant.data)(any_plant.model)
    data.qpos[:] = desc.q0
    mujoco.mj_forward(any_plant.model, data)
    mujoco.mj_fullM(any_plant.model, data, full)
    inertia = np.diag(full)
    assert np.all(inertia >= desc.dyn[:, 10])  # armature plus the links
    omega = 2 * np.pi * 25.0 / np.sqrt(np.sqrt(2) - 1)
    assert any_plant.servo_omega == pytest.approx(omega)
    np.testing.assert_allclose(any_plant.servo_kp, inertia * omega**2, rtol=1e-12)
    np.testing.assert_allclose(any_plant.servo_kd, 2 * inertia * omega, rtol=1e-12)
    np.testing.assert_allclose(any_plant.servo_kd / (2 * np.sqrt(any_plant.servo_kp * inertia)), 1.0, rtol=1e-12)


def test_a_slow_plant_lowers_the_servo_frequency_to_stay_stable(name) -> None:
    with MujocoArmPlant(name, "puma560", 0.01, NO_WATCHDOG) as plant:
        assert plant.servo_omega == pytest.approx(25.0)
        driver = MujocoArmDriver(name, {"mode": "position"})
        target, trace = step_joint(plant, driver, 1, 0.2)
        np.testing.assert_allclose(trace[-1], target, rtol=0, atol=1e-3)
        driver.close()


def test_servo_gravity_is_mujocos_inverse_dynamics_at_rest(any_plant) -> None:
    rng = np.random.default_rng(1)
    desc = robot(any_plant.robot.name)
    # both Pinocchio models: the controllers' (from the plant's ARM and EE) and the DH oracle
    models = [arm_model(any_plant.robot.arm, any_plant.robot.ee), dh_pinocchio_model(desc.dh, desc.dyn)]
    data = type(any_plant.data)(any_plant.model)
    for _ in range(10):
        q = rng.uniform(desc.joint_limits[:, 0] + 0.05, desc.joint_limits[:, 1] - 0.05)
        data.qpos[:] = q
        mujoco.mj_inverse(any_plant.model, data)  # qvel = qacc = 0
        np.testing.assert_allclose(any_plant.gravity_torque(q, np.zeros(desc.ndof)), data.qfrc_inverse, atol=1e-10)
        for model in models:
            np.testing.assert_allclose(data.qfrc_inverse,
                                       pinocchio.computeGeneralizedGravity(model, model.createData(), q), atol=1e-9)


def test_position_commands_are_clipped_to_the_joint_limits(any_plant, positioner) -> None:
    last = any_plant.ndof - 1
    upper = any_plant.robot.joint_limits[last, 1]
    q0 = hold_here(any_plant, positioner)
    target = q0.copy()
    target[last] = upper + 1.0
    positioner.write_position(target)
    run(any_plant, 2.0)
    assert read(positioner)[0][last] == pytest.approx(upper, abs=1e-3)


def test_the_brakes_hold_in_position_mode_and_the_servo_takes_over_where_they_held(any_plant, positioner) -> None:
    q0 = hold_here(any_plant, positioner)
    positioner.engage_brakes()
    positioner.write_position(q0 + 0.3)
    run(any_plant, 0.2)
    np.testing.assert_array_equal(read(positioner)[0], q0)  # braked: the command waits
    positioner.release_brakes()
    run(any_plant, 1.0)
    np.testing.assert_allclose(read(positioner)[0], q0 + 0.3, rtol=0, atol=1e-3)


def test_a_position_driver_must_command_a_position_before_releasing_the_brakes(positioner) -> None:
    with pytest.raises(DeviceError, match=r"write_position before release_brakes; the plant would servo"):
        positioner.release_brakes()
    assert positioner.brakes_engaged and positioner.active_mode == "none"


def test_each_driver_writes_only_its_own_mode(plant, driver) -> None:
    positioner = MujocoArmDriver(plant.name, {"mode": "position"})
    try:
        with pytest.raises(DeviceError,
                           match=r"write_position needs a driver opened with mode: position; this one has mode: torque$"):
            driver.write_position(np.zeros(NDOF))
        with pytest.raises(DeviceError,
                           match=r"write_torque needs a driver opened with mode: torque; this one has mode: position$"):
            positioner.write_torque(np.zeros(NDOF))
        assert driver.commands_written == 0
    finally:
        positioner.close()


def test_opening_a_driver_claims_nothing(plant) -> None:
    drivers = [MujocoArmDriver(plant.name, {"mode": mode}) for mode in ("position", "torque", "position")]
    try:
        assert drivers[0].active_mode == "none"
    finally:
        for d in drivers:
            d.close()


def test_a_torque_driver_never_moves_an_arm_a_position_driver_commands(plant, driver) -> None:
    positioner = MujocoArmDriver(plant.name, {"mode": "position"})
    try:
        q0 = hold_here(plant, positioner)
        driver.write_torque(np.full(NDOF, 50.0))  # written, but not applied
        run(plant, 0.5)
        np.testing.assert_allclose(read(driver)[0], q0, rtol=0, atol=1e-9)
        message = (
            r"^arm registers '/pbo\.test\..*': cannot release the brakes in torque mode, another driver is "
            r"commanding the arm in position mode; it must engage the brakes first$"
        )
        with pytest.raises(DeviceError, match=message):
            driver.release_brakes()
        assert driver.active_mode == "position"
        run(plant, 0.1)
        np.testing.assert_allclose(read(driver)[0], q0, rtol=0, atol=1e-9)
        # handing over: the position driver lets go through the brakes, the torque driver takes the arm
        positioner.engage_brakes()
        driver.release_brakes()
        assert driver.active_mode == "torque"
        plant.step()
        np.testing.assert_array_equal(plant.data.qfrc_applied, np.minimum(50.0, driver.torque_limits()))
    finally:
        positioner.close()


def test_a_position_driver_never_moves_an_arm_a_torque_driver_commands(plant, driver) -> None:
    positioner = MujocoArmDriver(plant.name, {"mode": "position"})
    try:
        driver.write_torque(np.full(NDOF, 1.0))
        driver.release_brakes()
        positioner.write_position(np.full(NDOF, 0.5))
        with pytest.raises(DeviceError,
                           match=r"cannot release the brakes in position mode, "
                                 r"another driver is commanding the arm in torque mode"):
            positioner.release_brakes()
        plant.step()
        np.testing.assert_array_equal(plant.data.qfrc_applied, np.full(NDOF, 1.0))
        assert positioner.active_mode == "torque"
    finally:
        positioner.close()


# issue 18: a NaN torque made MuJoCo reset the simulation; the driver now refuses it
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("mode", ["torque", "position"])
def test_a_command_that_is_not_finite_is_refused_and_never_written(plant, mode, bad) -> None:
    arm = MujocoArmDriver(plant.name, {"mode": mode})
    try:
        write = arm.write_torque if mode == "torque" else arm.write_position
        good = np.full(NDOF, 0.25)
        write(good)
        written = arm.commands_written
        command = good.copy()
        command[3] = bad
        with pytest.raises(DeviceError, match=rf"^arm registers '{plant.name}': write_{mode} refused a {mode} command that is "
                                              rf"not finite \(\[0\.25, 0\.25, 0\.25, -?(nan|inf), 0\.25, 0\.25\]\); "
                                              rf"the arm keeps its previous command: fix the task that computes it$"):
            write(command)
        assert arm.commands_written == written
        registers = plant._registers.tau if mode == "torque" else plant._registers.q_cmd
        np.testing.assert_array_equal(registers, good)
    finally:
        arm.close()


def test_writing_a_finite_torque_allocates_no_array(plant, driver) -> None:
    from tests.support import allocation_peak, one_array

    tau = np.full(NDOF, 1.0)
    assert allocation_peak(lambda: driver.write_torque(tau)) < one_array()


def test_the_drive_watchdog_holds_the_arm_when_commands_stop_and_lets_go_at_the_next(name):
    # the robot interface's RTPU stopped (SIGSTOP): nobody engages the brakes, the last torque would stay
    with MujocoArmPlant(name, "puma560", TIMESTEP, {"command_timeout": 0.05}) as plant:
        driver = MujocoArmDriver(plant.name, {"mode": "torque"})
        try:
            driver.write_torque(np.full(6, 3.0))
            driver.release_brakes()
            run(plant, 0.05)  # within the timeout: the command is applied
            assert not plant.brakes_engaged and plant.watchdog_trips == 0
            run(plant, 0.01)
            assert plant.brakes_engaged and plant.watchdog_trips == 1
            held = plant.data.qpos.copy()
            run(plant, 0.1)
            np.testing.assert_array_equal(plant.data.qpos, held)  # on its brakes, not on the last torque
            driver.write_torque(np.full(6, 3.0))  # the controller is back
            plant.step()
            assert not plant.brakes_engaged and plant.watchdog_trips == 1
        finally:
            driver.close()
