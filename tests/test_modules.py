"""The four control modules, each driven through a real Task on a real shared-memory table.

The transfers are the runtime's own (`Task.spawn`, `turn_on`, `run_cycle`, ...), the clock is
the release time each call is given, and the arm is an in-process MuJoCo plant stepped by hand.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pinocchio
import pytest

from drivers.mujoco_arm.driver import MujocoArmDriver
from drivers.mujoco_arm.plant import MujocoArmPlant
from drivers.robots import robot
from modules._braking import BrakingLaw
from modules.data_logger import DataLogger, read_log
from modules.fault_injector import FaultInjector
from modules.joint_trajectory import JointTrajectory
from modules.pid_joint import PidJoint
from modules.robot_torque import RobotTorque
from pbo_runtime import OutputError, ParamError, Status, arm_gains, inertia_range
from pbo_runtime.config.model import DeviceSpec, PortBinding, TaskSpec
from pbo_runtime.table.table import Flag, StateTable, TaskState
from pbo_runtime.task.background import process_background
from pbo_runtime.task.lifecycle import Task
from tests.support import NO_WATCHDOG, arm_constants, arm_tables, dh_pinocchio_model, fill_disk, task_spec, unique_name, variables

PUMA = robot("puma560")
PUMA_ARM, PUMA_EE = arm_tables("puma560")  # what its robot interface publishes
N = PUMA.ndof
DIMS = {"NDOF": N}
EPS = 1e-12


def arm_variables(n: int = N):
    return variables(
        *arm_constants(n),
        ("q_m", "float64", (n,)), ("qd_m", "float64", (n,)), ("q_r", "float64", (n,)),
        ("qd_r", "float64", (n,)), ("q_d", "float64", (n,)), ("tau_u", "float64", (n,)),
    )


@pytest.fixture
def table(make_table) -> StateTable:
    return make_table(arm_variables())


# --- JointTrajectory ---------------------------------------------------------------------------

V_MAX, A_MAX, DT = 1.0, 4.0, 0.01
Q0 = np.array([0.1, -0.2, 0.3, 0.0, 0.5, -1.0])
GOAL = np.array([1.0, 0.8, -0.7, 0.0, 0.5005, 2.0])  # long, short, reversed, still, tiny moves


def trajectory_task(table: StateTable, q_m=Q0, q_d=GOAL) -> Task:
    """A JointTrajectory task turned on at t = 0 with the arm at `q_m` and the goal `q_d`."""
    table.write("q_m", q_m, when=0.0)
    table.write("q_d", q_d, when=0.0)
    params = {"max_velocity": V_MAX, "max_acceleration": A_MAX}
    task = Task(task_spec(JointTrajectory, dims=DIMS, params=params, period=DT), JointTrajectory, table, DIMS)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    return task


def run_trajectory(table: StateTable, task: Task, cycles: int, first: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(q_r, qd_r) as published after each of `cycles` cycles, one row per cycle."""
    q_r, qd_r = np.zeros((cycles, N)), np.zeros((cycles, N))
    for k in range(cycles):
        assert task.run_cycle((first + k) * DT) is Status.CONTINUE
        q_r[k], qd_r[k] = table.read("q_r")[0], table.read("qd_r")[0]
    return q_r, qd_r


def test_trajectory_starts_from_q_m_at_rest_when_turned_on(table):
    table.write("q_r", np.full(N, 9.0), when=-1.0)  # stale values another task left a second ago
    table.write("qd_r", np.full(N, 5.0), when=-1.0)
    trajectory_task(table)
    np.testing.assert_array_equal(table.read("q_r")[0], Q0)
    np.testing.assert_array_equal(table.read("qd_r")[0], np.zeros(N))


def test_trajectory_goes_on_from_a_reference_that_drives_the_arm_now_when_turned_on(table):
    """A restart that took no time (the simulated clock), a switch mid-move: the path goes on as planned."""
    q_r, qd_r = Q0 + 0.01, np.full(N, 0.5)
    table.write("q_r", q_r, when=-DT)  # its predecessor's last cycle
    table.write("qd_r", qd_r, when=-DT)
    task = trajectory_task(table)
    np.testing.assert_array_equal(table.read("q_r")[0], q_r)
    np.testing.assert_array_equal(table.read("qd_r")[0], qd_r)
    _, velocity = run_trajectory(table, task, 1)
    assert velocity_steps(velocity, start=qd_r).max() <= A_MAX * DT + EPS


def test_trajectory_turned_on_while_the_actuators_are_held_starts_from_the_measured_state(table):
    """A restart on the real clock: the robot interface held the arm on its brakes meanwhile."""
    table.write("q_r", Q0 + 0.01, when=0.0)
    table.write("qd_r", np.full(N, 0.5), when=0.0)
    table.set_flag(Flag.ILLEGAL_CONFIGURATION)
    trajectory_task(table)
    np.testing.assert_array_equal(table.read("q_r")[0], Q0)
    np.testing.assert_array_equal(table.read("qd_r")[0], np.zeros(N))


def test_trajectory_reaches_q_d_exactly_and_stops_there(table):
    task = trajectory_task(table)
    q_r, qd_r = run_trajectory(table, task, 500)  # 5 s: the longest move (3 rad at 1 rad/s) takes ~3.3 s
    np.testing.assert_array_equal(q_r[-100:], np.broadcast_to(GOAL, (100, N)))  # exactly, and it stays
    np.testing.assert_array_equal(qd_r[-100:], np.zeros((100, N)))


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1.0, 1e3])
def test_a_reference_at_its_goal_and_at_rest_stays_there_bit_for_bit_with_a_positive_zero_velocity(scale):
    goal = np.array([1.0, -0.5, 0.0, -0.0, 0.25, -2.0]) * scale
    position, velocity = goal.copy(), np.array([0.0, -0.0, 0.0, -0.0, 0.0, -0.0])
    position[goal == 0.0] = -0.0  # at the goal, whatever the sign of its zeros
    BrakingLaw(6, V_MAX, A_MAX, DT).step(goal, position, velocity)
    assert position.tobytes() == goal.tobytes() and velocity.tobytes() == np.zeros(6).tobytes()


def test_a_reference_at_a_goal_that_is_not_finite_is_left_to_the_finite_check():
    goal = np.array([np.inf, np.nan, 0.0, 0.0, 0.0, 0.0])
    position, velocity = goal.copy(), np.zeros(6)
    with np.errstate(invalid="ignore"):
        BrakingLaw(6, V_MAX, A_MAX, DT).step(goal, position, velocity)
    assert not np.isfinite(position[:2]).any() and not np.isfinite(velocity[:2]).any()


def test_trajectory_never_exceeds_max_velocity_on_any_joint(table):
    task = trajectory_task(table)
    _, qd_r = run_trajectory(table, task, 500)
    assert np.abs(qd_r).max() <= V_MAX
    assert np.abs(qd_r).max() == V_MAX  # the long moves do cruise at the limit


def test_trajectory_position_integrates_its_velocity_until_arrival(table):
    task = trajectory_task(table)
    q_r, qd_r = run_trajectory(table, task, 500)
    q_r, qd_r = np.vstack([Q0, q_r]), np.vstack([np.zeros(N), qd_r])
    moving = q_r[1:] != GOAL  # each joint's cycles before it snapped onto its goal
    assert moving.sum() > 300
    np.testing.assert_allclose(np.diff(q_r, axis=0)[moving], qd_r[1:][moving] * DT, rtol=0, atol=EPS)


def velocity_steps(qd_r: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """|change of qd_r| from one cycle to the next, every joint."""
    before = np.zeros(N) if start is None else start
    return np.abs(np.diff(np.vstack([before, qd_r]), axis=0))


def test_trajectory_accelerates_and_brakes_within_max_acceleration_before_arrival(table):
    task = trajectory_task(table)
    q_r, qd_r = run_trajectory(table, task, 500)
    steps = velocity_steps(qd_r)
    # the cycle on which a joint snaps onto its goal is the known exception (next test)
    arriving = (q_r == GOAL) & (np.vstack([Q0, q_r[:-1]]) != GOAL)
    assert steps[~arriving].max() <= A_MAX * DT + EPS


def test_trajectory_changes_velocity_by_at_most_max_acceleration_times_period(table):
    task = trajectory_task(table)
    _, qd_r = run_trajectory(table, task, 500)
    assert velocity_steps(qd_r).max() <= A_MAX * DT + EPS


def test_trajectory_stands_still_while_the_actuators_are_held_and_starts_again_from_the_measured_state(table):
    task = trajectory_task(table, q_m=np.zeros(N), q_d=np.full(N, 1.0))
    q_r, qd_r = run_trajectory(table, task, 20)
    assert (qd_r[-1] > 0).all()
    table.set_flag(Flag.ILLEGAL_CONFIGURATION)  # the plant stopped: the robot interface holds the arm
    held, held_velocity = run_trajectory(table, task, 50, first=21)
    np.testing.assert_array_equal(held, np.broadcast_to(q_r[-1], held.shape))  # no running on without the arm
    np.testing.assert_array_equal(held_velocity, np.zeros(held.shape))
    table.set_flag(Flag.ILLEGAL_CONFIGURATION, False)
    arm = np.full(N, 0.05)  # where the brakes stopped it
    table.write("q_m", arm, when=0.71)
    table.write("qd_m", np.zeros(N), when=0.71)
    again, again_velocity = run_trajectory(table, task, 100, first=71)
    np.testing.assert_allclose(again[0], arm + again_velocity[0] * DT, rtol=0, atol=EPS)  # from the arm, at rest
    assert velocity_steps(again_velocity).max() <= A_MAX * DT + EPS
    assert (np.diff(again, axis=0) >= 0).all()  # on towards the goal, never back


def test_a_new_q_d_mid_way_redirects_the_trajectory_smoothly(table):
    task = trajectory_task(table, q_m=np.zeros(N), q_d=np.full(N, 1.0))
    _, qd_before = run_trajectory(table, task, 40)  # 0.4 s: every joint at 1 rad/s, cruising
    np.testing.assert_array_equal(qd_before[-1], np.full(N, V_MAX))
    back = np.array([-0.5, -0.5, 0.2, 0.9, -1.0, 1.5])  # four turn round, two go on
    table.write("q_d", back, when=40 * DT)
    q_r, qd_r = run_trajectory(table, task, 40, first=41)  # before any joint can arrive
    assert velocity_steps(qd_r, start=qd_before[-1]).max() <= A_MAX * DT + EPS
    assert np.abs(qd_r).max() <= V_MAX
    behind = back < 0.28  # where the joints were at the switch: 0.28 rad
    assert np.all(qd_r[-1][behind] < 0) and np.all(qd_r[-1][~behind] > 0)
    q_r, qd_r = run_trajectory(table, task, 400, first=81)
    np.testing.assert_array_equal(q_r[-1], back)
    np.testing.assert_array_equal(qd_r[-1], np.zeros(N))


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"max_velocity": 0}, r"max_velocity must be in \(0, 100\], got: 0"),
        ({"max_velocity": -1.0}, r"max_velocity must be in \(0, 100\], got: -1"),
        ({"max_velocity": 1e308}, r"max_velocity must be in \(0, 100\], got: 1e\+308"),
        ({"max_velocity": math.nan}, r"max_velocity must be in \(0, 100\], got: \.nan \(not a number\)"),
        ({"max_acceleration": 0.0}, r"max_acceleration must be in \(0, 10000\], got: 0"),
    ],
)
def test_trajectory_refuses_limits_out_of_their_range(params, message):
    with pytest.raises(ParamError, match=rf"^JointTrajectory\.{message}$"):
        JointTrajectory.build_params(params)


def test_the_fault_injector_raises_hangs_or_aborts_and_refuses_any_other_fault():
    assert FaultInjector.build_params({"fault": "hang"}).fault == "hang"
    assert FaultInjector.build_params({"fault": "abort", "in_init": True}).in_init is True
    with pytest.raises(ParamError, match=r"FaultInjector.fault must be one of 'raise', 'hang', 'abort', got: 'freeze'$"):
        FaultInjector.build_params({"fault": "freeze"})


@pytest.mark.parametrize("spawned_at, restarted, faults_at", [
    (0.0, False, [0.5, 1.0]),  # each listed time once
    (0.5, False, [0.5, 1.0]),  # spawned at a listed time: that one counts
    (0.5, True, [1.0]),  # spawned again after faulting at it: the next one
    (1.2, True, []),  # past the last: never
], ids=["from the start", "spawned at a time", "restarted at a time", "restarted past the last"])
def test_a_fault_injector_with_times_faults_once_at_each_listed_time_after_its_init(table, spawned_at, restarted, faults_at):
    spec = task_spec(FaultInjector, params={"at": [0.5, 1.0], "recoverable": True}, ports={"watched": "q_m"}, period=0.1)
    task = Task(spec, FaultInjector, table, DIMS, restarted=restarted)
    assert task.spawn(spawned_at), task.last_error
    assert task.turn_on(spawned_at), task.last_error
    faulted = []
    for k in range(round(spawned_at * 10), 15):
        task.run_cycle(k / 10)
        if task.last_error and task.last_error not in faulted:
            faulted.append(task.last_error)
    assert [float(re.search(r"injected fault at (\S+) s", error)[1]) for error in faulted] == faults_at


@pytest.mark.parametrize(("at", "message"), [([0.5, 0.2], "at must list times in seconds, >= 0 and increasing"),
                                             ([-1.0], r"FaultInjector\.at\[0\] must be in \[0, 1e\+06\], got: -1"),
                                             ([0.5, 0.5], "at must list times in seconds, >= 0 and increasing")])
def test_a_fault_injectors_times_must_be_increasing_and_not_negative(at, message):
    with pytest.raises(ParamError, match=message):
        FaultInjector.build_params({"at": at})


def test_a_hanging_fault_injectors_cycle_does_not_return(table):
    task = Task(task_spec(FaultInjector, params={"fail_after": 1, "fault": "hang"}, ports={"watched": "q_m"}),
                FaultInjector, table, DIMS)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    assert task.run_cycle(0.0) == Status.CONTINUE
    hung = threading.Thread(target=task.run_cycle, args=(0.01,), daemon=True)  # left blocked: it holds nothing
    hung.start()
    hung.join(timeout=0.2)
    assert hung.is_alive() and task.module.failed and task.cycles == 1


# --- PidJoint ----------------------------------------------------------------------------------

PID_DT = 0.01
NO_GRAVITY = {"gravity_feedforward": False}


def pid_task(table: StateTable, params: dict, period: float = PID_DT) -> Task:
    """A PidJoint task for the PUMA's constants, spawned at t = 0 (not yet on)."""
    table.write("NDOF", N, when=0.0)
    table.write("ARM", PUMA_ARM, when=0.0)
    table.write("EE", PUMA_EE, when=0.0)
    return Task(task_spec(PidJoint, dims=DIMS, params=params, period=period), PidJoint, table, DIMS)


def write_state(table: StateTable, q_r, q_m, qd_r=None, qd_m=None, when: float = 0.0) -> None:
    """The PID's inputs; the velocities are zero unless given."""
    still = np.zeros(N)
    qd_r = still if qd_r is None else qd_r
    qd_m = still if qd_m is None else qd_m
    for name, value in (("q_r", q_r), ("q_m", q_m), ("qd_r", qd_r), ("qd_m", qd_m)):
        table.write(name, value, when=when)


def tau_u(table: StateTable) -> np.ndarray:
    return table.read("tau_u")[0]


def test_pid_output_is_kp_times_position_error_plus_kd_times_velocity_error(table):
    task = pid_task(table, {"kp": 100.0, "kd": 10.0, "ki": 0.0, **NO_GRAVITY})
    assert task.spawn(0.0), task.last_error
    write_state(
        table,
        q_r=[0.1, 0.2, 0.0, 1.0, -0.5, 0.0], q_m=[0.0, 0.3, 0.0, 0.5, 0.5, 0.0],
        qd_r=[0.0, 0.0, 1.0, 0.5, 0.0, 2.0], qd_m=[0.0, 0.0, 0.0, 1.0, -1.0, 2.5],
    )
    assert task.turn_on(0.0)
    np.testing.assert_allclose(tau_u(table), [10.0, -10.0, 10.0, 45.0, -90.0, -5.0], rtol=0, atol=1e-12)
    write_state(table, q_r=np.full(N, 0.25), q_m=np.zeros(N), qd_r=np.zeros(N), qd_m=np.full(N, -0.5), when=PID_DT)
    assert task.run_cycle(PID_DT) is Status.CONTINUE
    np.testing.assert_allclose(tau_u(table), np.full(N, 30.0), rtol=0, atol=1e-12)  # 100 * 0.25 + 10 * 0.5


def test_pid_integral_accumulates_ki_times_error_times_period_every_cycle(table):
    task = pid_task(table, {"kp": 0.0, "kd": 0.0, "ki": 10.0})  # with feed-forward the integral starts at zero
    assert task.spawn(0.0), task.last_error
    error = np.array([0.5, -0.5, 1.0, 0.0, 0.1, -2.0])
    write_state(table, q_r=error, q_m=np.zeros(N))
    assert task.turn_on(0.0)
    gravity = pinocchio_gravity(np.zeros(N))
    np.testing.assert_allclose(tau_u(table), gravity, rtol=0, atol=1e-12)  # nothing integrated yet
    for k in range(1, 6):
        task.run_cycle(k * PID_DT)
        np.testing.assert_allclose(tau_u(table), gravity + k * 10.0 * error * PID_DT, rtol=0, atol=1e-12)


def test_pid_integral_is_clipped_at_integral_limit_and_unwinds_at_once(table):
    task = pid_task(table, {"kp": 0.0, "kd": 0.0, "ki": 100.0, "integral_limit": 2.0, **NO_GRAVITY})
    assert task.spawn(0.0), task.last_error
    write_state(table, q_r=[1.0, -1.0, 1.0, -1.0, 1.0, -1.0], q_m=np.zeros(N))
    assert task.turn_on(0.0)
    for k in range(1, 51):  # 100 * 1 * 0.01 = 1 N m per cycle: at the limit after 2 cycles
        task.run_cycle(k * PID_DT)
    np.testing.assert_array_equal(tau_u(table), [2.0, -2.0, 2.0, -2.0, 2.0, -2.0])
    write_state(table, q_r=[-0.5, 0.5, -0.5, 0.5, -0.5, 0.5], q_m=np.zeros(N), when=0.5)
    task.run_cycle(0.51)
    # anti-windup: no stored excess to work off first; the limit minus one step's 0.5 N m
    np.testing.assert_allclose(tau_u(table), [1.5, -1.5, 1.5, -1.5, 1.5, -1.5], rtol=0, atol=1e-12)


def test_pid_takes_one_gain_per_joint_from_a_list(table):
    kp = [100.0, 200.0, 300.0, 0.0, 50.0, 1.0]
    task = pid_task(table, {"kp": kp, "kd": [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], "ki": 0.0, **NO_GRAVITY})
    assert task.spawn(0.0), task.last_error
    write_state(table, q_r=np.full(N, 0.5), q_m=np.zeros(N), qd_r=np.zeros(N), qd_m=np.full(N, 1.0))
    assert task.turn_on(0.0)
    task.run_cycle(PID_DT)
    np.testing.assert_allclose(tau_u(table), [49.0, 98.0, 147.0, -4.0, 20.0, -5.5], rtol=0, atol=1e-12)


def test_pid_with_a_bandwidth_makes_each_joints_gains_from_the_arms_inertia(table):
    task = pid_task(table, {"bandwidth": 20.0, "damping": 0.8, "integral_time": 0.5, **NO_GRAVITY})
    assert task.spawn(0.0), task.last_error
    inertia = inertia_range(PUMA_ARM, PUMA_EE)
    kp, kd, ki, design = arm_gains(inertia, 20.0, 0.8, 0.5, PID_DT)
    np.testing.assert_allclose(kp, design * 20.0 ** 2)
    np.testing.assert_allclose(kd, 2 * 0.8 * design * 20.0 - inertia.viscous)  # the joints' own friction damps too
    np.testing.assert_allclose(ki, kp / 0.5)
    write_state(table, q_r=np.full(N, 0.1), q_m=np.zeros(N), qd_r=np.zeros(N), qd_m=np.full(N, 1.0))
    assert task.turn_on(0.0)  # the integral starts at zero
    np.testing.assert_allclose(tau_u(table), 0.1 * kp - kd, rtol=1e-12)


@pytest.mark.parametrize("gain", ["kp", "kd", "ki"])
def test_pid_refuses_a_gain_list_of_the_wrong_length_at_init(table, gain):
    task = pid_task(table, {gain: [1.0] * 5, **NO_GRAVITY})
    assert not task.spawn(0.0)
    assert task.state is TaskState.KILLED
    assert task.last_error.startswith(
        f"init raised ValueError: {gain} must have one gain or NDOF = 6 gains, got: 5 at pid_joint.py:")


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"kp": -1.0}, r"kp must be in \[0, 1e\+06\], got: -1"),
        ({"kp": 1.0e308}, r"kp must be in \[0, 1e\+06\], got: 1e\+308"),
        ({"kp": math.nan}, r"kp must be in \[0, 1e\+06\], got: \.nan \(not a number\)"),
        ({"kd": -0.5}, r"kd must be in \[0, 100000\], got: -0\.5"),
        ({"ki": [1, 1, 1, -1, 1, 1]}, r"ki\[3\] must be in \[0, 1e\+06\], got: -1"),
        ({"ki": [1, 1, 1, math.inf, 1, 1]}, r"ki\[3\] must be in \[0, 1e\+06\], got: \.inf"),
        ({"integral_limit": -1.0}, r"integral_limit must be in \[0, 10000\], got: -1"),
    ],
)
def test_pid_refuses_gains_and_limits_out_of_their_range(params, message):
    with pytest.raises(ParamError, match=rf"^PidJoint\.{message}$"):
        PidJoint.build_params(params)


def pinocchio_gravity(q: np.ndarray) -> np.ndarray:
    """g(q) of the tests' own model of the PUMA, built from its DH rows (not from the ARM table the module reads)."""
    model = dh_pinocchio_model(PUMA.dh, PUMA.dyn)
    return pinocchio.computeGeneralizedGravity(model, model.createData(), q).copy()


@pytest.mark.parametrize("q", [np.zeros(N), np.array([0.3, -0.7, 1.2, 0.4, -0.9, 2.0]),
                               np.array([-1.0, 0.5, -0.4, 2.5, 1.3, 0.0])])
def test_pid_with_gravity_feedforward_on_target_outputs_pinocchios_generalized_gravity(table, q):
    task = pid_task(table, {"kp": 400.0, "kd": 40.0, "ki": 5.0})  # gravity_feedforward is the default
    assert task.spawn(0.0), task.last_error
    write_state(table, q_r=q, q_m=q)
    assert task.turn_on(0.0)
    for k in range(1, 4):
        task.run_cycle(k * PID_DT)
        np.testing.assert_allclose(tau_u(table), pinocchio_gravity(q), rtol=0, atol=1e-12)


def test_pid_gravity_torque_of_the_puma_shoulder_at_zero_pose_is_37_48_n_m(table):
    task = pid_task(table, {})
    assert task.spawn(0.0), task.last_error
    write_state(table, q_r=np.zeros(N), q_m=np.zeros(N))
    assert task.turn_on(0.0)
    task.run_cycle(PID_DT)
    assert tau_u(table)[1] == pytest.approx(37.48, abs=0.01)


def test_pid_takes_over_the_torque_left_in_the_table_without_a_bump(table):
    task = pid_task(table, {"kp": 100.0, "kd": 0.0, "ki": 1.0, "integral_limit": 50.0, **NO_GRAVITY})
    assert task.spawn(0.0), task.last_error
    left = np.array([5.0, -5.0, 10.0, 0.0, 1.0, -1.0])
    table.write("tau_u", left, when=0.0)  # what the previous controller commanded
    write_state(table, q_r=np.full(N, 0.01), q_m=np.zeros(N))
    assert task.turn_on(0.0)
    np.testing.assert_allclose(tau_u(table), left, rtol=0, atol=1e-12)  # no bump


def test_pid_without_feed_forward_takes_over_into_its_integral_only_on_joints_with_integral_action(table):
    """Without feed-forward the integral carries the load: it keeps the torque taken over. A joint
    with ki = 0 must stay a plain PD joint after `on`, not carry a constant offset."""
    ki = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    task = pid_task(table, {"kp": 100.0, "kd": 0.0, "ki": ki, **NO_GRAVITY})
    assert task.spawn(0.0), task.last_error
    table.write("tau_u", np.full(N, 7.0), when=0.0)
    write_state(table, q_r=np.zeros(N), q_m=np.zeros(N))
    assert task.turn_on(0.0)
    write_state(table, q_r=np.full(N, 0.1), q_m=np.zeros(N), when=PID_DT)
    task.run_cycle(PID_DT)  # the first cycle takes the 7 N m over
    np.testing.assert_allclose(tau_u(table)[3:], np.full(3, 10.0), rtol=0, atol=1e-12)  # kp * 0.1, no 7 N m
    np.testing.assert_allclose(tau_u(table)[:3], np.full(3, 7.0), rtol=0, atol=1e-12)  # kept, by the integral
    task.run_cycle(2 * PID_DT)
    np.testing.assert_allclose(tau_u(table)[3:], np.full(3, 10.0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(tau_u(table)[:3], np.full(3, 7.0 + 0.1 * PID_DT), rtol=0, atol=1e-12)  # and integrated on


def test_pid_with_feed_forward_fades_out_the_torque_it_took_over_on_every_joint_and_leaves_no_offset(table):
    """The previous controller's torque beyond this one's fades with its HANDOVER_TIME_CONSTANT, whether
    the joint has integral action or not: none of it stays in the integral."""
    ki = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    task = pid_task(table, {"kp": 100.0, "kd": 0.0, "ki": list(ki)})
    assert task.spawn(0.0), task.last_error
    table.write("tau_u", np.full(N, 7.0), when=0.0)
    write_state(table, q_r=np.full(N, 0.1), q_m=np.zeros(N))
    assert task.turn_on(0.0)
    np.testing.assert_allclose(tau_u(table), np.full(N, 7.0), rtol=0, atol=1e-12)  # held until its first cycle
    gravity = pinocchio_gravity(np.zeros(N))
    fade = np.exp(-PID_DT / PidJoint.HANDOVER_TIME_CONSTANT)
    task.run_cycle(0.0)  # the first cycle, at the boundary of `on`: its output is the torque taken over
    np.testing.assert_allclose(tau_u(table), np.full(N, 7.0), rtol=0, atol=1e-12)
    handover = 7.0 - (100.0 * 0.1 + gravity + ki * 0.1 * PID_DT)
    for k in range(2, 102):  # ten time constants
        task.run_cycle(k * PID_DT)
        expected = 100.0 * 0.1 + gravity + ki * 0.1 * PID_DT * k + handover * fade**(k - 1)
        np.testing.assert_allclose(tau_u(table), expected, rtol=0, atol=1e-7)  # (dropped at a billionth of itself)
    left_over = np.abs(tau_u(table) - (10.0 + gravity + ki * 0.1 * PID_DT * 101))
    assert (left_over < np.abs(handover) * 1e-4).all()  # e^-10 of it


def test_pid_turned_on_while_the_actuators_are_held_starts_from_the_measured_state_alone(table):
    """A restarted controller: the torque its dead predecessor left is not what the arm feels (the
    robot interface holds it on its brakes), so none of it is taken over."""
    q = np.array([0.3, -0.7, 1.2, 0.4, -0.9, 2.0])
    task = pid_task(table, {"kp": 400.0, "kd": 40.0, "ki": 10.0})
    assert task.spawn(0.0), task.last_error
    table.write("tau_u", np.full(N, 30.0), when=0.0)
    write_state(table, q_r=q, q_m=q)
    table.set_flag(Flag.ILLEGAL_CONFIGURATION)
    assert task.turn_on(0.0)
    np.testing.assert_allclose(tau_u(table), pinocchio_gravity(q), rtol=0, atol=1e-12)


def test_pid_integrates_nothing_while_the_actuators_are_held_and_goes_on_after(table):
    task = pid_task(table, {"kp": 0.0, "kd": 0.0, "ki": 10.0})
    assert task.spawn(0.0), task.last_error
    error = np.array([0.5, -0.5, 1.0, 0.0, 0.1, -2.0])
    write_state(table, q_r=error, q_m=np.zeros(N))
    assert task.turn_on(0.0)
    gravity = pinocchio_gravity(np.zeros(N))
    task.run_cycle(PID_DT)
    table.set_flag(Flag.ILLEGAL_CONFIGURATION)  # the plant stopped: q_m stands still, the arm is held
    for k in range(2, 50):
        task.run_cycle(k * PID_DT)
        np.testing.assert_allclose(tau_u(table), gravity + 10.0 * error * PID_DT, rtol=0, atol=1e-12)
    table.set_flag(Flag.ILLEGAL_CONFIGURATION, False)
    task.run_cycle(50 * PID_DT)
    np.testing.assert_allclose(tau_u(table), gravity + 2 * 10.0 * error * PID_DT, rtol=0, atol=1e-12)


# --- RobotTorque ---------------------------------------------------------------------------------

ARM = DeviceSpec("arm", "mujoco_arm", True, {"mode": "torque"})


class RecordingDriver(MujocoArmDriver):
    """The real driver, remembering whether it was closed."""

    closed = False

    def close(self) -> None:
        self.closed = True
        super().close()


@pytest.fixture
def plant() -> Iterator[MujocoArmPlant]:
    plant = MujocoArmPlant(unique_name("plant"), "puma560", 0.001, NO_WATCHDOG)
    try:
        yield plant
    finally:
        plant.close()


@pytest.fixture
def observer(plant) -> Iterator[MujocoArmDriver]:
    """A second driver on the same registers, to see the brake request without the task's."""
    driver = MujocoArmDriver(plant.name, {})
    try:
        yield driver
    finally:
        driver.close()


def robot_task(table: StateTable, plant: MujocoArmPlant, resources: tuple[str, ...] = ("arm",),
               dims: dict[str, int] = DIMS) -> tuple[Task, list[RecordingDriver]]:
    opened: list[RecordingDriver] = []

    def opener(device: DeviceSpec, _task: TaskSpec) -> RecordingDriver:
        driver = RecordingDriver(plant.name, device.options)
        opened.append(driver)
        return driver

    spec = dataclasses.replace(task_spec(RobotTorque, dims=dims, period=plant.timestep), resources=resources)
    return Task(spec, RobotTorque, table, dims, devices={"arm": ARM}, opener=opener), opened


def test_robot_spawn_publishes_ndof_arm_and_ee_of_the_arm(table, plant):
    task, _ = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    ndof, _, _, writer = table.read("NDOF")
    assert ndof == N and writer == task.index
    np.testing.assert_array_equal(table.read("ARM")[0], PUMA_ARM)
    np.testing.assert_array_equal(table.read("EE")[0], PUMA_EE)
    assert table.read("ARM")[3] == table.read("EE")[3] == task.index
    task.kill()


def test_robot_on_releases_the_brakes_and_publishes_where_the_arm_is(table, plant, observer):
    task, _ = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    assert observer.brakes_engaged
    assert task.turn_on(0.0)
    assert not observer.brakes_engaged
    np.testing.assert_array_equal(table.read("q_m")[0], PUMA.q0)
    np.testing.assert_array_equal(table.read("qd_m")[0], np.zeros(N))
    plant.step()
    assert not plant.brakes_engaged
    task.kill()


def test_robot_cycle_sends_tau_u_to_the_arm_and_publishes_the_state_the_plant_stepped(table, plant):
    task, _ = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0)
    for k in range(1, 21):
        tau = np.array([5.0, 40.0, -3.0, 1.0, -0.5, 0.2]) * (1 + 0.1 * k)
        table.write("tau_u", tau, when=k * plant.timestep)
        assert task.run_cycle(k * plant.timestep) is Status.CONTINUE
        q_m, seq, when, writer = table.read("q_m")
        np.testing.assert_array_equal(q_m, plant.data.qpos)  # the state as of the plant's last step
        np.testing.assert_array_equal(table.read("qd_m")[0], plant.data.qvel)
        assert (seq, when, writer) == (k, k * plant.timestep, task.index)
        plant.step()
        np.testing.assert_array_equal(plant.data.qfrc_applied, tau)  # what this cycle commanded
    assert np.abs(plant.data.qpos - PUMA.q0).max() > 1e-4  # the arm did move
    task.kill()


def test_robot_holds_the_arm_and_says_stable_while_the_plant_stops_stepping(table, plant, observer):
    task, _ = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0)
    dt = plant.timestep
    table.write("tau_u", np.full(N, 5.0), when=0.0)
    statuses = []
    for k in range(1, 11):  # the plant steps for 4 cycles, then stops (SIGSTOP) for 6
        statuses.append(task.run_cycle(k * dt))
        if k <= 4:
            plant.step()
    # cycle 5 reads the 4th step, the last: cycles 6-8 are within 3 periods of it, 9 and 10 are held
    assert statuses == [Status.CONTINUE] * 8 + [Status.STABLE] * 2
    assert observer.brakes_engaged
    plant.step()  # the plant runs again: the next cycle drives the arm again
    assert task.run_cycle(11 * dt) is Status.CONTINUE
    assert not observer.brakes_engaged
    task.kill()


# issue 18: a NaN torque reached the arm and MuJoCo reset the simulation
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_robot_refuses_a_non_finite_torque_goes_to_error_and_the_brakes_hold_the_arm(table, plant, observer, bad):
    task, _ = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0)
    table.write("tau_u", np.full(N, 2.0), when=plant.timestep)
    assert task.run_cycle(plant.timestep) is Status.CONTINUE
    written = observer.commands_written
    tau = np.full(N, 2.0)
    tau[1] = bad
    table.write("tau_u", tau, when=2 * plant.timestep)
    assert task.run_cycle(2 * plant.timestep) is Status.ERROR
    assert task.state is TaskState.ERROR and observer.brakes_engaged and observer.commands_written == written
    assert task.last_error.startswith("cycle raised DeviceError: arm registers ")
    assert "write_torque refused a torque command that is not finite" in task.last_error
    plant.step()
    assert plant.brakes_engaged and np.isfinite(plant.data.qpos).all()
    assert task.clear() and task.state is TaskState.OFF  # the operator's clear, then on: it drives the arm again
    task.kill()


def test_robot_off_engages_the_brakes(table, plant, observer):
    task, _ = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0)
    task.run_cycle(plant.timestep)
    task.turn_off()
    assert observer.brakes_engaged
    plant.step()
    assert plant.brakes_engaged
    task.kill()


def test_robot_kill_engages_the_brakes_and_closes_the_driver(table, plant, observer):
    task, opened = robot_task(table, plant)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0)
    task.turn_off()
    observer.release_brakes()  # someone let go of the arm while the task was off
    task.kill()
    assert observer.brakes_engaged
    assert [d.closed for d in opened] == [True]
    assert task.state is TaskState.KILLED and task.last_error == ""


def test_robot_task_whose_resources_do_not_list_the_device_fails_init_naming_it(table, plant):
    task, opened = robot_task(table, plant, resources=())
    assert not task.spawn(0.0)
    assert task.state is TaskState.KILLED
    assert task.last_error.startswith("init raised ModuleError: task 't' opens device 'arm', but its resources are: none at ")
    assert opened == []


def test_robot_fails_init_when_ndof_differs_from_the_arms_joints(make_table, plant, observer):
    table = make_table(arm_variables(5))
    task, opened = robot_task(table, plant, dims={"NDOF": 5})
    assert not task.spawn(0.0)
    assert task.state is TaskState.KILLED
    assert task.last_error.startswith(
        "init raised ModuleError: the arm on device 'arm' has 6 joints, "
        "but the configuration says NDOF = 5 at _robot_interface.py:"
    )
    assert [d.closed for d in opened] == [True]  # kill ran and the driver was not leaked
    assert observer.brakes_engaged


# --- DataLogger ----------------------------------------------------------------------------------

LOG_DT = 0.01
LOGGED = variables(("x", "float64", (3,)), ("k", "int32", ()), ("m", "float64", (2, 2)), ("unlogged", "float64", ()))


@pytest.fixture
def log_table(make_table) -> StateTable:
    return make_table(LOGGED)


def logger_task(table: StateTable, params: dict, clock: str = "real") -> Task:
    built = DataLogger.build_params(params)
    bindings = tuple(PortBinding(p, p.variable, table.layout.slot(p.variable).shape) for p in DataLogger.ports_for(built))
    spec = TaskSpec(name="log", module="DataLogger", rtpu="rtpu0", period=LOG_DT, params=params, bindings=bindings, index=1)
    task = Task(spec, DataLogger, table, run_metadata={"clock": clock})
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    return task


def log_cycles(table: StateTable, task: Task, cycles: int, t0: float = 1.0) -> list[tuple[float, np.ndarray, int, np.ndarray]]:
    """Write fresh values, run a cycle; return what was written, with each release time."""
    written = []
    for i in range(cycles):
        t = t0 + i * LOG_DT
        x, k, m = np.array([i, -i, 0.5 * i]), 10 * i - 3, np.arange(4.0).reshape(2, 2) + i
        for name, value in (("x", x), ("k", k), ("m", m), ("unlogged", -1.0)):
            table.write(name, value, when=t)
        assert task.run_cycle(t) is Status.CONTINUE
        task.module.wait_for_writer()  # each chunk written before the next cycle, as a period gives it time to
        written.append((t, x, k, m))
    return written


def kill_and_finish(task: Task) -> None:
    """Kill the logger and wait for the RTPU's background thread to finish its log (as the RTPU's stop does)."""
    task.kill()
    assert process_background().drain()


def assert_log_holds(path: Path, written: list, load=np.load) -> None:
    log = load(path)
    assert log.dtype.names == ("time", "x", "k", "m")
    np.testing.assert_array_equal(log["time"], [w[0] for w in written])
    assert np.all(np.diff(log["time"]) > 0)
    np.testing.assert_array_equal(log["x"], np.array([w[1] for w in written]).reshape(len(written), 3))
    np.testing.assert_array_equal(log["k"], np.array([w[2] for w in written], dtype=np.int32))
    assert log["k"].dtype == np.int32
    np.testing.assert_array_equal(log["m"], np.array([w[3] for w in written]).reshape(len(written), 2, 2))


def test_logger_off_writes_one_row_per_cycle_of_every_logged_variable(log_table, tmp_path):
    path = tmp_path / "runs" / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path)})
    written = log_cycles(log_table, task, 7)
    assert len(np.load(path)) == 0  # a second's chunk is not full yet: the cycles wrote nothing
    task.turn_off()
    task.module.wait_for_writer()  # off handed the chunk begun to the writer
    assert_log_holds(path, written)
    assert sorted(p.name for p in path.parent.iterdir()) == ["log.npy"]  # no partial file left behind
    task.kill()


def test_logger_appends_each_chunk_as_it_fills_and_the_file_is_a_whole_array_after_each(log_table, tmp_path):
    path = tmp_path / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path), "chunk": 3 * LOG_DT})
    written = log_cycles(log_table, task, 2)
    assert len(np.load(path)) == 0
    written += log_cycles(log_table, task, 5, t0=2.0)
    assert_log_holds(path, written[:6])  # two chunks of 3: the 7th row waits in the third
    kill_and_finish(task)
    assert_log_holds(path, written)


def test_logger_kill_writes_the_chunk_begun(log_table, tmp_path):
    path = tmp_path / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path)})
    written = log_cycles(log_table, task, 4)
    task.turn_off()
    written += log_cycles_after_on(log_table, task, 2)
    kill_and_finish(task)  # from ON: off, then kill
    assert_log_holds(path, written)


def log_cycles_after_on(table: StateTable, task: Task, cycles: int) -> list:
    assert task.turn_on(2.0)
    return log_cycles(table, task, cycles, t0=2.0)


def test_logger_keeps_appending_after_off_and_on(log_table, tmp_path):
    path = tmp_path / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path)})
    written = log_cycles(log_table, task, 3)
    task.turn_off()
    written += log_cycles_after_on(log_table, task, 2)
    task.turn_off()
    task.module.wait_for_writer()
    assert_log_holds(path, written)
    task.kill()


def test_logger_keeps_every_row_of_a_run_longer_than_the_120_s_it_once_kept(log_table, tmp_path):
    # Regression (issue 18): rows past 120 s were dropped; now the memory is one chunk, whatever the length.
    path = tmp_path / "log.npy"
    task = logger_task(log_table, {"variables": ["k"], "path": str(path)})
    cycles = 13_000  # 130 s of 10 ms cycles
    for i in range(cycles):
        task.run_cycle(1.0 + i * LOG_DT)
        task.module.wait_for_writer()
    assert task.module._rows == 100 and len(np.load(path)) == 13_000  # every chunk of a second written as it filled
    kill_and_finish(task)
    assert len(np.load(path)) == cycles


def slowed_writer(task: Task) -> threading.Event:
    """Hold the logger's writer thread in each append until the event returned is set (a slow disk)."""
    release, append = threading.Event(), task.module._append

    def slow_disk(index, rows):
        if threading.get_ident() == task.module.writer_id:
            release.wait(30)
        append(index, rows)

    task.module._append = slow_disk
    return release


def test_rows_taken_while_the_writer_still_writes_the_other_chunk_are_dropped_counted_and_reported(log_table, tmp_path):
    path = tmp_path / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path), "chunk": 2 * LOG_DT})
    release = slowed_writer(task)
    written = log_cycles_without_waiting(log_table, task, 7)  # 2 handed over, 2 filling the other, 3 with nowhere to go
    assert task.module.dropped == 3
    release.set()
    task.module.wait_for_writer()  # (off hands the chunk begun over only to a writer that is free: it never waits for it)
    with pytest.raises(OutputError, match=r"^log \S+/log\.npy: 3 rows dropped: writing a chunk of 2 rows took longer than "
                                          r"filling one \(the disk is too slow for this period\)$"):
        task.module.off()
    task.module.wait_for_writer()
    assert_log_holds(path, written[:4])
    task.kill()


def test_on_the_simulated_clock_a_logger_waits_for_a_slow_writer_and_drops_no_row(log_table, tmp_path):
    path = tmp_path / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path), "chunk": 2 * LOG_DT}, clock="sim")
    release = slowed_writer(task)
    buffers = task.module._count  # more than the real clock's two: the cycle fills them all before it waits
    assert buffers > 2
    threading.Timer(0.2, release.set).start()  # the cycle after every buffer is full waits until then, however long
    written = log_cycles_without_waiting(log_table, task, 2 * buffers + 3)
    assert task.module.dropped == 0 and release.is_set()
    task.module.off()
    task.module.wait_for_writer()
    assert_log_holds(path, written)
    task.kill()


def log_cycles_without_waiting(table: StateTable, task: Task, cycles: int) -> list:
    written = log_values(1.0, cycles)
    for t, x, k, m in written:
        for name, value in (("x", x), ("k", k), ("m", m)):
            table.write(name, value, when=t)
        assert task.run_cycle(t) is Status.CONTINUE
    return written


def test_read_log_gives_back_the_rows_of_a_chunk_whose_count_a_killed_process_did_not_write(log_table, tmp_path):
    path = tmp_path / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path), "chunk": 2 * LOG_DT})
    written = log_cycles(log_table, task, 6)
    kill_and_finish(task)
    row = task.module._dtype.itemsize
    with open(path, "r+b") as file:  # as if killed after the third chunk's rows, before its count, halfway into a 4th
        file.write(task.module._file.header(4))
        file.seek(0, 2)
        file.write(b"\1" * (row // 2))
    assert len(np.load(path)) == 4
    assert_log_holds(path, written, load=read_log)


def test_logger_whose_file_is_removed_fails_at_the_next_chunk_with_the_os_error(log_table, tmp_path):
    path = tmp_path / "runs" / "log.npy"
    task = logger_task(log_table, {"variables": ["x"], "path": str(path), "chunk": 2 * LOG_DT})
    log_cycles(log_table, task, 2)
    shutil.rmtree(path.parent)
    assert cycles_until_error(log_table, task, 2.0, 10) == 2  # the 2nd fills the chunk, whose write fails; the 3rd says so
    assert task.state is TaskState.ERROR and task.output_failed
    assert re.fullmatch(r"cycle raised OutputError: cannot write log .*/runs/log\.npy \(2 rows after the 2 written\): "
                        r"\[Errno 2\] .*removed.* at data_logger\.py:\d+", task.last_error), task.last_error
    kill_and_finish(task)
    assert not path.parent.exists()  # nothing made again, no partial file


def test_logger_on_a_full_disk_fails_at_the_write_keeps_the_rows_written_and_leaves_no_partial_file(log_table, small_disk):
    path = small_disk / "log.npy"
    task = logger_task(log_table, {"variables": ["x", "k", "m"], "path": str(path), "chunk": 2 * LOG_DT})
    written = log_cycles(log_table, task, 2)
    fill_disk(small_disk)
    ran = cycles_until_error(log_table, task, 2.0, 1000)  # rows of 76 B: the file's one page takes a few dozen
    assert 0 < ran < 1000
    assert task.state is TaskState.ERROR and task.output_failed
    assert "[Errno 28] No space left on device" in task.last_error
    kept = np.load(path)
    assert len(kept) >= 2 and len(kept) % 2 == 0
    assert_log_holds(path, written + [(t, x, k, m) for t, x, k, m in log_values(2.0, len(kept) - 2)])
    assert os.path.getsize(path) == task.module._file.header_bytes + len(kept) * kept.dtype.itemsize  # no torn chunk
    kill_and_finish(task)
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler", "log.npy"]


def cycles_until_error(table: StateTable, task: Task, t0: float, most: int) -> int:
    """Run `log_cycles`' cycles until one ends in ERROR (or `most` ran); how many ended well."""
    for i, (t, x, k, m) in enumerate(log_values(t0, most)):
        for name, value in (("x", x), ("k", k), ("m", m)):
            table.write(name, value, when=t)
        if task.run_cycle(t) is not Status.CONTINUE:
            return i
        task.module.wait_for_writer()
    return most


def log_values(t0: float, cycles: int) -> list:
    """What `log_cycles` writes, without running anything."""
    return [(t0 + i * LOG_DT, np.array([i, -i, 0.5 * i]), 10 * i - 3, np.arange(4.0).reshape(2, 2) + i) for i in range(cycles)]


def test_logger_that_cannot_create_its_file_is_not_created(log_table, tmp_path):
    built = DataLogger.build_params({"variables": ["x"], "path": "/proc/pbo-log.npy"})
    bindings = tuple(PortBinding(p, p.variable, log_table.layout.slot(p.variable).shape) for p in DataLogger.ports_for(built))
    spec = TaskSpec(name="log", module="DataLogger", rtpu="rtpu0", period=LOG_DT, params={"variables": ["x"],
                    "path": "/proc/pbo-log.npy"}, bindings=bindings, index=1)
    task = Task(spec, DataLogger, log_table)
    assert not task.spawn(0.0)
    assert task.output_failed
    assert re.match(r"init raised OutputError: cannot create log /proc/pbo-log\.npy: \[Errno \d+\] ", task.last_error)


def test_logger_cycles_take_no_page_fault_as_its_log_fills(log_table, tmp_path):
    # Regression (issue 6): the log was np.zeros, mapped lazily: the cycle that first wrote into
    # each new page took a page fault (32 over these 4,096 rows of m). The chunk buffer is
    # written in init, so its rows fill without faults until the chunk is written.
    import resource

    task = logger_task(log_table, {"variables": ["m"], "path": str(tmp_path / "log.npy"), "chunk": 1_000_000 * LOG_DT})
    assert task.module._rows > 4096
    task.run_cycle(1.0)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for i in range(1, 4096):
        task.run_cycle(1.0 + i * LOG_DT)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    assert task.module.logged == 4096
    assert faults < 8, f"{faults} page faults in 4,095 cycles"  # 32 to 40 before the fix
    kill_and_finish(task)
    assert len(np.load(tmp_path / "log.npy")) == 4096


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"variables": []}, r"bad parameters for DataLogger: variables must name at least one variable to log"),
        ({"variables": ["x", "k", "x"]}, r"bad parameters for DataLogger: variables must not repeat, got: \['x', 'k', 'x'\]"),
        ({"variables": ["x", "time"]}, r"bad parameters for DataLogger: variables must not include 'time': .*"),
        ({"variables": ["x"], "path": "runs/log.npz"},
         r"bad parameters for DataLogger: path must end in \.mcap \(Foxglove, PlotJuggler\) or \.npy \(one numpy "
         r"structured array\), got: 'runs/log\.npz'"),
        ({"variables": ["x"], "chunk": 0}, r"DataLogger\.chunk must be in \(0, 86400\], got: 0"),
        ({"path": "log.npy"}, r"missing parameter\(s\) 'variables' for DataLogger"),
    ],
)
def test_logger_refuses_bad_params(params, message):
    with pytest.raises(ParamError, match=rf"^{message}$"):
        DataLogger.build_params(params)
