"""The differentiator, position inverse kinematics, Cartesian interpolator and Cartesian controller
(TR Figure 7), each driven through a real Task on a real table.

Kinematic references come from Pinocchio on the tests' own model of the PUMA 560 (built from its
DH rows, not from the ARM table the modules read).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pinocchio
import pytest

from drivers.robots import robot
from modules._robot_model import END_EFFECTOR_FRAME, pose_error
from modules.cartesian_controller import CartesianController
from modules.cartesian_interpolator import CartesianInterpolator
from modules.differentiator import Differentiator
from modules.inverse_kinematics import InverseKinematics
from pbo_runtime import ParamError, PortBasedObject, Status
from pbo_runtime.config.model import PortBinding, TaskSpec
from pbo_runtime.table.table import StateTable
from pbo_runtime.task.lifecycle import Task
from tests.support import allocation_peak, dh_pinocchio_model, one_array, robot_state_table, spawned_task, write_values

PUMA = robot("puma560")
N = PUMA.ndof
DIMS = {"NDOF": N}
DT = 0.001
MODEL = dh_pinocchio_model(PUMA.dh, PUMA.dyn)
EE = MODEL.getFrameId(END_EFFECTOR_FRAME)
Q_GENERIC = np.array([0.2, -0.5, 0.8, 0.3, -0.9, 0.4])  # well away from every singularity


@pytest.fixture
def table(make_table) -> StateTable:
    return robot_state_table(make_table, "puma560",
        ("q_m", "float64", (N,)), ("qd_m", "float64", (N,)), ("q_r", "float64", (N,)), ("qdd_r", "float64", (N,)),
        ("x_m", "float64", (6,)), ("x_d", "float64", (6,)), ("x_r", "float64", (6,)), ("xd_r", "float64", (6,)),
        ("xdd_u", "float64", (6,)), ("J", "float64", (6, N)), ("ik_residual", "float64", ()),
        ("signal", "float64", (3,)), ("rate", "float64", (3,)),
    )


def spawned(table: StateTable, module: type[PortBasedObject], params: dict | None = None, period: float = DT) -> Task:
    return spawned_task(table, module, DIMS, params, period)


write = write_values


def read(table: StateTable, name: str) -> np.ndarray:
    return table.read(name)[0]


def pose(q: np.ndarray) -> np.ndarray:
    data = MODEL.createData()
    pinocchio.forwardKinematics(MODEL, data, q)
    frame = pinocchio.updateFramePlacement(MODEL, data, EE)
    return np.concatenate([frame.translation, pinocchio.log3(frame.rotation)])


def jacobian(q: np.ndarray) -> np.ndarray:
    data = MODEL.createData()
    pinocchio.computeJointJacobians(MODEL, data, q)
    return pinocchio.getFrameJacobian(MODEL, data, EE, pinocchio.LOCAL_WORLD_ALIGNED).copy()


# --- Differentiator -------------------------------------------------------------------------------


def differentiator(table: StateTable, z0: np.ndarray, params: dict | None = None, period: float = DT) -> Task:
    """A differentiator of the (3,) variable 'signal' into 'rate', turned on at t = 0 with signal = z0."""
    ports = {"z": "signal", "zd": "rate"}
    bindings = tuple(PortBinding(p, ports[p.name], (3,)) for p in Differentiator.ports())
    spec = TaskSpec(name="diff", module="Differentiator", rtpu="rtpu0", period=period, params=params or {},
                    bindings=bindings, index=0)
    write(table, signal=z0, rate=np.full(3, 7.0))  # a stale rate another task left
    task = Task(spec, Differentiator, table, DIMS)
    assert task.spawn(0.0), task.last_error
    assert task.turn_on(0.0), task.last_error
    return task


SLOPE = np.array([0.5, -2.0, 0.0])
OFFSET = np.array([1.0, 3.0, -4.0])


def test_differentiator_starts_at_zero_when_turned_on(table):
    differentiator(table, OFFSET)
    np.testing.assert_array_equal(read(table, "rate"), np.zeros(3))


def test_differentiator_of_a_ramp_is_its_slope_from_the_first_cycle(table):
    task = differentiator(table, OFFSET)
    for k in range(1, 51):
        write(table, when=k * DT, signal=OFFSET + SLOPE * k * DT)
        assert task.run_cycle(k * DT) is Status.CONTINUE
        np.testing.assert_allclose(read(table, "rate"), SLOPE, rtol=1e-9, atol=1e-9)


def test_differentiator_divides_by_the_time_since_the_last_cycle_not_the_period(table):
    task = differentiator(table, OFFSET)
    write(table, when=DT, signal=OFFSET + SLOPE * DT)
    task.run_cycle(DT)
    write(table, when=4 * DT, signal=OFFSET + SLOPE * 4 * DT)  # three periods later (cycles skipped)
    task.run_cycle(4 * DT)
    np.testing.assert_allclose(read(table, "rate"), SLOPE, rtol=1e-9, atol=1e-9)


def test_differentiator_smoothing_is_a_first_order_low_pass_of_the_derivative(table):
    task = differentiator(table, OFFSET, {"smoothing": 0.009})  # alpha = dt / (tau + dt) = 0.1
    rates = []
    for k in range(1, 201):
        write(table, when=k * DT, signal=OFFSET + SLOPE * k * DT)
        task.run_cycle(k * DT)
        rates.append(read(table, "rate").copy())
    np.testing.assert_allclose(rates[0], 0.1 * SLOPE, rtol=1e-9)
    np.testing.assert_allclose(rates[1], 0.19 * SLOPE, rtol=1e-9)
    np.testing.assert_allclose(rates[-1], SLOPE, rtol=1e-6, atol=1e-9)


def test_differentiator_cycle_allocates_nothing(table):
    task = differentiator(table, OFFSET, {"smoothing": 0.01})
    assert allocation_peak(task.module.cycle) < one_array()


# --- InverseKinematics ----------------------------------------------------------------------------


def ik_task(table: StateTable, q_m: np.ndarray, x_d: np.ndarray, params: dict | None = None, first_cycle: bool = True) -> Task:
    """Turned on, and its first cycle run at the same boundary, as the executive does."""
    write(table, q_m=q_m, x_d=x_d)
    task = spawned(table, InverseKinematics, params)
    assert task.turn_on(0.0), task.last_error
    if first_cycle:
        task.run_cycle(0.0)
    return task


def test_inverse_kinematics_turns_on_where_the_arm_is_and_searches_in_its_first_cycle(table):
    # no search in `on`: it would lengthen the switch that turns the task on, before any cycle runs
    x_d = pose(Q_GENERIC + 0.1)
    task = ik_task(table, Q_GENERIC, x_d, first_cycle=False)
    np.testing.assert_array_equal(read(table, "q_r"), Q_GENERIC)
    assert task.module.iterations == 0
    assert task.run_cycle(0.0) is Status.CONTINUE and task.module.converged
    assert np.abs(pose_error(x_d, pose(read(table, "q_r")), np.zeros(6))).max() < 1e-6


@pytest.mark.parametrize("offset", [np.array([0.1, -0.08, 0.12, -0.1, 0.09, 0.1]), np.array([0.4, 0.3, -0.3, 0.5, 0.4, -0.5])])
def test_inverse_kinematics_reaches_a_reachable_pose_to_1e_6_and_says_so(table, offset):
    x_d = pose(Q_GENERIC + offset)
    task = ik_task(table, Q_GENERIC, x_d)
    assert task.module.converged
    assert read(table, "ik_residual") <= 1e-9
    error = pose_error(x_d, pose(read(table, "q_r")), np.zeros(6))
    assert np.abs(error).max() < 1e-6


def test_inverse_kinematics_follows_a_moving_pose_in_a_step_or_two_a_cycle(table):
    task = ik_task(table, Q_GENERIC, pose(Q_GENERIC))
    for k in range(1, 101):
        goal = pose(Q_GENERIC + 0.2 * math.sin(k * DT * 10) * np.ones(N))
        write(table, when=k * DT, x_d=goal)
        assert task.run_cycle(k * DT) is Status.CONTINUE
        assert task.module.converged and task.module.iterations <= 2
        assert np.abs(pose_error(goal, pose(read(table, "q_r")), np.zeros(6))).max() < 1e-6


def test_inverse_kinematics_of_an_unreachable_pose_says_so_and_gives_the_nearest_found(table):
    far = pose(Q_GENERIC)
    far[:3] = [3.0, 0.0, 0.5]  # 3 m out: the PUMA reaches under 1 m
    task = ik_task(table, Q_GENERIC, far, {"max_iterations": 50})
    assert not task.module.converged
    assert task.module.iterations == 50
    residual = float(read(table, "ik_residual"))
    assert residual > 1.5
    assert np.isfinite(read(table, "q_r")).all()
    assert residual == pytest.approx(np.linalg.norm(pose_error(far, pose(read(table, "q_r")), np.zeros(6))), rel=1e-9)


def test_inverse_kinematics_continues_or_reports_an_error_when_it_does_not_converge(table):
    far = pose(Q_GENERIC)
    far[:3] = [3.0, 0.0, 0.5]
    patient = ik_task(table, Q_GENERIC, far)
    assert patient.run_cycle(DT) is Status.CONTINUE
    patient.kill()
    strict = ik_task(table, Q_GENERIC, far, {"unreachable": "error"}, first_cycle=False)
    strict.run_cycle(DT)
    assert "inverse kinematics did not reach x_d within 1e-09 in 20 iterations" in strict.last_error


# --- CartesianInterpolator ------------------------------------------------------------------------

X0 = np.array([0.4, -0.1, 0.3, 0.1, 0.2, -0.1])
SAMPLE = 0.01  # s: x_d changes every 10 cycles


def interpolator(table: StateTable, params: dict | None = None) -> Task:
    write(table, x_m=X0, x_d=X0, x_r=np.full(6, 9.0))  # a stale x_r another task left
    task = spawned(table, CartesianInterpolator, {"sample_period": SAMPLE, **(params or {})})
    assert task.turn_on(0.0), task.last_error
    return task


def desired(t: float) -> np.ndarray:
    """A 10 cm, 0.2 rad circle a second, sampled every SAMPLE like a trackball's."""
    held = math.floor(t / SAMPLE + 1e-9) * SAMPLE
    angle = 2 * math.pi * held
    return X0 + np.array([0.1 * math.cos(angle) - 0.1, 0.1 * math.sin(angle), 0.0, 0.2 * math.sin(angle), 0.0, 0.0])


def run_interpolator(table: StateTable, task: Task, cycles: int, goal) -> tuple[np.ndarray, np.ndarray]:
    x_r, xd_r = np.zeros((cycles, 6)), np.zeros((cycles, 6))
    for k in range(1, cycles + 1):
        write(table, when=k * DT, x_d=goal(k * DT))
        assert task.run_cycle(k * DT) is Status.CONTINUE
        x_r[k - 1], xd_r[k - 1] = read(table, "x_r"), read(table, "xd_r")
    return x_r, xd_r


def test_cartesian_interpolator_starts_at_x_m_at_rest_when_turned_on(table):
    interpolator(table)
    np.testing.assert_array_equal(read(table, "x_r"), X0)
    np.testing.assert_array_equal(read(table, "xd_r"), np.zeros(6))


def test_cartesian_interpolator_reaches_each_sample_within_one_sample_period_moving_every_cycle(table):
    task = interpolator(table, {"max_linear_velocity": 1.0})  # the circle's 0.63 m/s is within it
    x_r, xd_r = run_interpolator(table, task, 1000, desired)
    # a sample first seen at cycle 10 m is reached by cycle 10 m + 9 (row 10 m + 8), before the next one
    for row in range(2 * SAMPLE_CYCLES - 2, 1000, SAMPLE_CYCLES):
        np.testing.assert_allclose(x_r[row], desired((row + 1) * DT), rtol=0, atol=1e-12)
    steps = np.diff(x_r[SAMPLE_CYCLES - 1:, :2], axis=0)  # from the first new sample on
    assert np.all(np.linalg.norm(steps, axis=1) > 0)  # a smooth reference, not the samples' staircase
    np.testing.assert_allclose(np.diff(x_r, axis=0), xd_r[1:] * DT, rtol=1e-9, atol=1e-15)


SAMPLE_CYCLES = round(SAMPLE / DT)


def test_cartesian_interpolator_velocity_never_exceeds_its_limits_and_it_lands_on_a_far_sample(table):
    task = interpolator(table, {"max_linear_velocity": 0.2, "max_angular_velocity": 0.5})
    jump = X0 + np.array([0.1, -0.05, 0.02, 0.3, 0.0, -0.2])  # one sample far beyond what 10 ms allows
    x_r, xd_r = run_interpolator(table, task, 1000, lambda t: jump)
    assert np.linalg.norm(xd_r[:, :3], axis=1).max() <= 0.2 * (1 + 1e-12)
    assert np.linalg.norm(xd_r[:, 3:], axis=1).max() <= 0.5 * (1 + 1e-12)
    assert np.linalg.norm(xd_r[0, :3]) == pytest.approx(0.2, rel=1e-12)  # at the limit, in a straight line
    np.testing.assert_array_equal(x_r[-1], jump)
    np.testing.assert_array_equal(xd_r[-1], np.zeros(6))


def test_cartesian_interpolator_cycle_allocates_nothing(table):
    task = interpolator(table)
    write(table, when=DT, x_d=X0 + 0.01)
    task.run_cycle(DT)
    module = task.module
    assert allocation_peak(module.cycle) < one_array()

    samples = itertools.cycle([X0 + 0.02, X0 - 0.02])

    def new_sample() -> None:
        np.copyto(module.x_d, next(samples))  # a new sample every cycle: the segment restarts each time
        module.cycle()

    assert allocation_peak(new_sample) < one_array()


# --- CartesianController --------------------------------------------------------------------------


def controller(table: StateTable, q: np.ndarray, qd: np.ndarray, x_r: np.ndarray, xd_r: np.ndarray,
               params: dict | None = None) -> Task:
    write(table, x_r=x_r, xd_r=xd_r, x_m=pose(q), J=jacobian(q), qd_m=qd)
    task = spawned(table, CartesianController, params)
    assert task.turn_on(0.0), task.last_error
    return task


def test_cartesian_controller_at_the_reference_at_rest_commands_nothing(table):
    controller(table, Q_GENERIC, np.zeros(N), pose(Q_GENERIC), np.zeros(6))
    np.testing.assert_allclose(read(table, "xdd_u"), np.zeros(6), rtol=0, atol=1e-12)
    np.testing.assert_allclose(read(table, "qdd_r"), np.zeros(N), rtol=0, atol=1e-12)


def test_cartesian_controller_is_a_pd_on_the_pose_error_through_the_damped_inverse_jacobian(table):
    qd = np.array([0.1, -0.2, 0.05, 0.3, -0.1, 0.2])
    x_r = pose(Q_GENERIC) + np.array([0.01, -0.02, 0.005, 0.0, 0.0, 0.0])
    xd_r = np.array([0.05, 0.0, -0.02, 0.1, 0.0, 0.0])
    controller(table, Q_GENERIC, qd, x_r, xd_r, {"kp": 64.0, "kd": 16.0, "damping": 1e-6})
    error = pose_error(x_r, pose(Q_GENERIC), np.zeros(6))
    command = 64.0 * error + 16.0 * (xd_r - jacobian(Q_GENERIC) @ qd)
    np.testing.assert_allclose(read(table, "xdd_u"), command, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(jacobian(Q_GENERIC) @ read(table, "qdd_r"), command, rtol=1e-6, atol=1e-9)


def test_cartesian_controller_closed_on_a_double_integrator_brings_the_hand_to_the_reference(table):
    """The arm with inverse dynamics behind the controller is a double integrator qdd = qdd_r."""
    x_r = pose(Q_GENERIC + np.array([0.05, -0.04, 0.06, -0.05, 0.04, 0.05]))
    q, qd = Q_GENERIC.copy(), np.zeros(N)
    task = controller(table, q, qd, x_r, np.zeros(6))
    before = np.linalg.norm(pose_error(x_r, pose(q), np.zeros(6)))
    for k in range(1, 2001):  # 2 s: ten time constants of kp = 100, kd = 20
        qdd = read(table, "qdd_r")
        qd += qdd * DT
        q += qd * DT
        write(table, when=k * DT, x_m=pose(q), J=jacobian(q), qd_m=qd)
        assert task.run_cycle(k * DT) is Status.CONTINUE
    after = np.linalg.norm(pose_error(x_r, pose(q), np.zeros(6)))
    assert before > 0.05
    assert after < 1e-4, (before, after)


def test_cartesian_controller_caps_the_joint_acceleration_keeping_its_direction(table):
    x_r = pose(Q_GENERIC) + np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    free = controller(table, Q_GENERIC, np.zeros(N), x_r, np.zeros(6))
    fast = read(table, "qdd_r").copy()
    free.kill()
    controller(table, Q_GENERIC, np.zeros(N), x_r, np.zeros(6), {"max_joint_acceleration": 1.0})
    slow = read(table, "qdd_r")
    assert np.abs(fast).max() > 1.0
    np.testing.assert_allclose(slow, fast / np.abs(fast).max(), rtol=1e-12)


# --- Params ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("module", "params", "message"),
    [
        (Differentiator, {"smoothing": -0.1}, r"smoothing must be in \[0, 3600\], got: -0\.1"),
        (InverseKinematics, {"tolerance": 0.0}, r"tolerance must be in \(0, 1\], got: 0"),
        (InverseKinematics, {"max_iterations": 0}, r"max_iterations must be in \[1, 1000\], got: 0"),
        (CartesianInterpolator, {"sample_period": 0.0}, r"sample_period must be in \(0, 3600\], got: 0"),
        (CartesianInterpolator, {"max_angular_velocity": math.inf}, r"max_angular_velocity must be in \(0, 100\], got: \.inf"),
        (CartesianController, {"kp": -1.0}, r"kp must be in \[0, 1e\+06\], got: -1"),
        (CartesianController, {"damping": 0.0}, r"damping must be in \(0, 10\], got: 0"),
    ],
)
def test_new_library_modules_refuse_bad_params_saying_which_and_why(module, params, message):
    with pytest.raises(ParamError, match=rf"^{module.__name__}\.{message}$"):
        module.build_params(params)


def test_inverse_kinematics_refuses_an_unknown_unreachable_choice_listing_the_choices():
    with pytest.raises(ParamError, match=r"^InverseKinematics\.unreachable must be one of 'continue', 'error', got: 'ignore'$"):
        InverseKinematics.build_params({"unreachable": "ignore"})


@pytest.mark.parametrize("module", [Differentiator, InverseKinematics, CartesianInterpolator, CartesianController])
def test_new_library_modules_accept_their_default_params(module):
    module.build_params({})
