"""The kinematics and dynamics modules, each driven through a real Task on a real table.

fk_jacobian, inverse_dynamics, gravity_compensation, resolved_rate, damped_least_squares,
time_integrator and cartesian_trajectory, with the PUMA 560's ARM and EE as the robot
interface would publish them. References come from Pinocchio's own algorithms on the tests' own
model of the PUMA (built from its DH rows, not from the ARM table) and from finite differences;
the rate controllers are closed with a plain Euler loop standing in for the arm.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio
import pytest

from drivers.robots import robot
from modules._robot_model import END_EFFECTOR_FRAME, pose_error
from modules.cartesian_trajectory import CartesianTrajectory
from modules.damped_least_squares import DampedLeastSquares
from modules.fk_jacobian import FkJacobian
from modules.gravity_compensation import GravityCompensation
from modules.inverse_dynamics import InverseDynamics
from modules.resolved_rate import ResolvedRate
from modules.time_integrator import TimeIntegrator
from pbo_runtime import ParamError, PortBasedObject, Status
from pbo_runtime.table.table import Flag, StateTable, TaskState
from pbo_runtime.task.lifecycle import Task
from tests.support import dh_forward_kinematics, dh_pinocchio_model, robot_state_table, spawned_task, task_spec, write_values

PUMA = robot("puma560")
N = PUMA.ndof
DIMS = {"NDOF": N}
DT = 0.001
RNG = np.random.default_rng(560)
RANDOM_Q = [RNG.uniform(-np.pi, np.pi, N) for _ in range(4)]
Q_GENERIC = np.array([0.2, -0.5, 0.8, 0.3, -0.9, 0.4])  # well away from every singularity
Q_NEAR_WRIST_SINGULARITY = np.array([0.0, 0.3, 0.3, 0.0, 0.002, 0.0])  # q5 = 0 aligns joints 4 and 6


KINEMATICS_VARIABLES = (
    ("q_m", "float64", (N,)), ("qd_m", "float64", (N,)), ("qdd_r", "float64", (N,)),
    ("q_r", "float64", (N,)), ("qd_r", "float64", (N,)), ("tau_u", "float64", (N,)),
    ("tau_g", "float64", (N,)), ("x_m", "float64", (6,)), ("x_d", "float64", (6,)),
    ("x_r", "float64", (6,)), ("J", "float64", (6, N)),
)


@pytest.fixture
def table(make_table) -> StateTable:
    return robot_state_table(make_table, "puma560", *KINEMATICS_VARIABLES)


def spawned(table: StateTable, module: type[PortBasedObject], params: dict | None = None, period: float = DT) -> Task:
    return spawned_task(table, module, DIMS, params, period)


write = write_values


def read(table: StateTable, name: str) -> np.ndarray:
    return table.read(name)[0]


MODEL = dh_pinocchio_model(PUMA.dh, PUMA.dyn)  # the oracle: the modules build theirs from ARM and EE
EE = MODEL.getFrameId(END_EFFECTOR_FRAME)


def placement(q: np.ndarray) -> pinocchio.SE3:
    data = MODEL.createData()
    pinocchio.forwardKinematics(MODEL, data, q)
    pinocchio.updateFramePlacements(MODEL, data)
    return data.oMf[EE].copy()


def pose(q: np.ndarray) -> np.ndarray:
    frame = placement(q)
    return np.concatenate([frame.translation, pinocchio.log3(frame.rotation)])


def rigid_mass_matrix(q: np.ndarray) -> np.ndarray:
    """M(q) of the links alone (armature zeroed), both triangles filled."""
    model = pinocchio.Model(MODEL)
    model.armature[:] = 0.0
    mass = pinocchio.crba(model, model.createData(), q).copy()
    return np.triu(mass) + np.triu(mass, 1).T


# --- FkJacobian -----------------------------------------------------------------------------------


def fk_task(table: StateTable, q: np.ndarray, params: dict | None = None) -> Task:
    write(table, q_m=q)
    task = spawned(table, FkJacobian, params)
    assert task.turn_on(0.0), task.last_error
    return task


@pytest.mark.parametrize("q", RANDOM_Q)
def test_fk_x_m_is_pinocchios_frame_placement_and_the_dh_product(table, q):
    task = fk_task(table, np.zeros(N))
    write(table, when=DT, q_m=q)
    assert task.run_cycle(DT) is Status.CONTINUE
    x_m, frame = read(table, "x_m"), placement(q)
    np.testing.assert_allclose(x_m[:3], frame.translation, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pinocchio.exp3(x_m[3:]), frame.rotation, rtol=0, atol=1e-12)
    assert np.linalg.norm(x_m[3:]) <= np.pi + 1e-12  # a rotation vector as log3 gives it
    np.testing.assert_allclose(np.linalg.inv(dh_forward_kinematics(PUMA.dh, q)) @ np.block(
        [[pinocchio.exp3(x_m[3:]), x_m[:3, None]], [np.zeros((1, 3)), np.ones((1, 1))]]), np.eye(4), rtol=0, atol=1e-12)


@pytest.mark.parametrize("q", RANDOM_Q)
def test_fk_jacobian_matches_finite_differences_of_position_and_orientation(table, q):
    fk_task(table, q)
    jacobian, h = read(table, "J"), 1e-6
    linear, angular = np.zeros((3, N)), np.zeros((3, N))
    for i in range(N):
        step = np.eye(N)[i] * h
        plus, minus = placement(q + step), placement(q - step)
        linear[:, i] = (plus.translation - minus.translation) / (2 * h)
        angular[:, i] = pinocchio.log3(plus.rotation @ minus.rotation.T) / (2 * h)  # base-frame angular velocity
    np.testing.assert_allclose(jacobian[:3], linear, rtol=0, atol=1e-6)
    np.testing.assert_allclose(jacobian[3:], angular, rtol=0, atol=1e-6)


def test_fk_publishes_x_m_and_j_already_when_turned_on(table):
    fk_task(table, Q_GENERIC)
    np.testing.assert_allclose(read(table, "x_m"), pose(Q_GENERIC), rtol=0, atol=1e-12)
    assert np.abs(read(table, "J")).max() > 0.1


def test_fk_of_another_frame_gives_that_frames_pose(table):
    fk_task(table, Q_GENERIC, {"frame": "link3"})
    data = MODEL.createData()
    pinocchio.framesForwardKinematics(MODEL, data, Q_GENERIC)
    np.testing.assert_allclose(read(table, "x_m")[:3], data.oMf[MODEL.getFrameId("link3")].translation, rtol=0, atol=1e-12)


def test_fk_refuses_at_init_a_frame_the_arm_does_not_have(table):
    task = Task(task_spec(FkJacobian, dims=DIMS, params={"frame": "tool"}), FkJacobian, table, DIMS)
    assert not task.spawn(0.0)
    assert task.state is TaskState.KILLED
    assert task.last_error.startswith(
        "init raised ValueError: frame must be one of the model's frames "
        "(link1, link2, link3, link4, link5, link6, ee), got: 'tool' at _robot_model.py:"
    )


# --- InverseDynamics ------------------------------------------------------------------------------

STATES = [(RNG.uniform(-np.pi, np.pi, N), RNG.uniform(-2, 2, N), RNG.uniform(-5, 5, N)) for _ in range(4)]


@pytest.mark.parametrize(("q", "qd", "qdd"), STATES)
def test_inverse_dynamics_is_mass_matrix_times_qdd_plus_coriolis_and_gravity(table, q, qd, qdd):
    task = spawned(table, InverseDynamics)
    write(table, q_m=np.zeros(N), qd_m=np.zeros(N), qdd_r=np.zeros(N))
    assert task.turn_on(0.0)
    write(table, when=DT, q_m=q, qd_m=qd, qdd_r=qdd)
    assert task.run_cycle(DT) is Status.CONTINUE
    data = MODEL.createData()
    nonlinear = pinocchio.nonLinearEffects(MODEL, data, q, qd).copy()  # C(q, qd) qd + g(q)
    mass = rigid_mass_matrix(q) + np.diag(PUMA.dyn[:, 10])  # the links, plus the rotors' armature
    np.testing.assert_allclose(read(table, "tau_u") - nonlinear, mass @ qdd, rtol=0, atol=1e-8)


def test_inverse_dynamics_at_rest_is_the_gravity_torque(table):
    task = spawned(table, InverseDynamics)
    write(table, q_m=Q_GENERIC, qd_m=np.zeros(N), qdd_r=np.zeros(N))
    assert task.turn_on(0.0)
    expected = pinocchio.computeGeneralizedGravity(MODEL, MODEL.createData(), Q_GENERIC)
    np.testing.assert_allclose(read(table, "tau_u"), expected, rtol=0, atol=1e-10)


def test_inverse_dynamics_clips_each_joint_at_max_torque(table):
    task = spawned(table, InverseDynamics, {"max_torque": 20.0})
    write(table, q_m=np.zeros(N), qd_m=np.zeros(N), qdd_r=np.array([100.0, -100.0, 0.0, 0.0, 0.0, 0.0]))
    assert task.turn_on(0.0)
    tau = read(table, "tau_u")
    assert tau[0] == 20.0 and tau[1] == -20.0
    assert np.abs(tau).max() <= 20.0


# --- GravityCompensation --------------------------------------------------------------------------


@pytest.mark.parametrize("q", RANDOM_Q)
def test_gravity_compensation_is_pinocchios_generalized_gravity(table, q):
    task = spawned(table, GravityCompensation)
    write(table, q_m=np.zeros(N))
    assert task.turn_on(0.0)
    write(table, when=DT, q_m=q)
    assert task.run_cycle(DT) is Status.CONTINUE
    expected = pinocchio.computeGeneralizedGravity(MODEL, MODEL.createData(), q)
    np.testing.assert_allclose(read(table, "tau_g"), expected, rtol=0, atol=1e-12)


def test_gravity_torque_of_the_puma_shoulder_at_zero_pose_is_37_48_n_m(table):
    task = spawned(table, GravityCompensation)
    write(table, q_m=np.zeros(N))
    assert task.turn_on(0.0)
    assert task.run_cycle(DT) is Status.CONTINUE
    assert read(table, "tau_g")[1] == pytest.approx(37.48, abs=0.01)


def test_gravity_compensation_scale_outputs_that_fraction_of_the_gravity_torque(table):
    task = spawned(table, GravityCompensation, {"scale": 0.25})
    write(table, q_m=Q_GENERIC)
    assert task.turn_on(0.0)
    expected = 0.25 * pinocchio.computeGeneralizedGravity(MODEL, MODEL.createData(), Q_GENERIC)
    np.testing.assert_allclose(read(table, "tau_g"), expected, rtol=0, atol=1e-12)


# --- ResolvedRate and DampedLeastSquares ----------------------------------------------------------

RATE_MODULES = [ResolvedRate, DampedLeastSquares]


def rate_task(table: StateTable, module: type[PortBasedObject], q: np.ndarray, x_d: np.ndarray,
              params: dict | None = None) -> Task:
    """A rate controller turned on and run once at time 0: its qd_r is in the table."""
    write(table, q_m=q, x_d=x_d)
    task = spawned(table, module, params)
    assert task.turn_on(0.0), task.last_error
    assert not read(table, "qd_r").any()  # at rest until its first cycle (a switch's work stays short)
    assert task.run_cycle(0.0) is Status.CONTINUE
    return task


def error_norm(x_d: np.ndarray, q: np.ndarray) -> float:
    return float(np.linalg.norm(pose_error(x_d, pose(q), np.zeros(6))))


def perturbed_goal(q: np.ndarray, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """The pose at q moved by `position` (m) and turned by the base-frame rotation vector `rotation`."""
    frame = placement(q)
    return np.concatenate([frame.translation + position, pinocchio.log3(pinocchio.exp3(rotation) @ frame.rotation)])


@pytest.mark.parametrize("module", RATE_MODULES)
def test_rate_controller_integrated_with_euler_drives_x_m_to_x_d_from_a_nearby_pose(table, module):
    x_d = pose(Q_GENERIC + np.array([0.1, -0.08, 0.12, -0.1, 0.09, 0.1]))
    q = Q_GENERIC.copy()
    task = rate_task(table, module, q, x_d)
    before = error_norm(x_d, q)
    for k in range(1, 2001):  # 2 s of 1 ms steps
        q += read(table, "qd_r") * DT  # the arm follows its velocity reference exactly
        write(table, when=k * DT, q_m=q)
        assert task.run_cycle(k * DT) is Status.CONTINUE
    assert before > 0.1
    after = error_norm(x_d, q)
    assert after < before / 100, (before, after)


@pytest.mark.parametrize("module", RATE_MODULES)
def test_rate_controller_scales_qd_r_down_to_max_joint_speed_keeping_its_direction(table, module):
    x_d = pose(Q_GENERIC + 0.5)
    unlimited = rate_task(table, module, Q_GENERIC, x_d, {"max_joint_speed": 1e6})
    fast = read(table, "qd_r").copy()
    unlimited.kill()
    rate_task(table, module, Q_GENERIC, x_d, {"max_joint_speed": 0.5})
    slow = read(table, "qd_r")
    assert np.abs(fast).max() > 0.5
    assert np.abs(slow).max() == pytest.approx(0.5, rel=1e-12)
    np.testing.assert_allclose(slow, fast * 0.5 / np.abs(fast).max(), rtol=1e-12, atol=1e-15)


def test_resolved_rate_is_the_pseudo_inverse_times_gain_times_the_pose_error(table):
    x_d = perturbed_goal(Q_GENERIC, np.array([0.01, -0.02, 0.005]), np.array([0.02, 0.0, -0.01]))
    rate_task(table, ResolvedRate, Q_GENERIC, x_d, {"gain": 3.0, "max_joint_speed": 1e6})
    data = MODEL.createData()
    pinocchio.computeJointJacobians(MODEL, data, Q_GENERIC)
    jacobian = pinocchio.getFrameJacobian(MODEL, data, EE, pinocchio.LOCAL_WORLD_ALIGNED)
    error = pose_error(x_d, pose(Q_GENERIC), np.zeros(6))
    np.testing.assert_allclose(read(table, "qd_r"), np.linalg.solve(jacobian, 3.0 * error), rtol=1e-9, atol=1e-12)


def test_damped_least_squares_away_from_singularities_without_fixed_damping_is_resolved_rate(table):
    x_d = perturbed_goal(Q_GENERIC, np.array([0.01, -0.02, 0.005]), np.array([0.02, 0.0, -0.01]))
    task = rate_task(table, DampedLeastSquares, Q_GENERIC, x_d, {"max_joint_speed": 1e6})
    assert task.module.manipulability > 0.01  # above the default threshold: no damping at all
    assert task.module.damping_squared == 0.0
    damped = read(table, "qd_r").copy()
    rate_task(table, ResolvedRate, Q_GENERIC, x_d, {"max_joint_speed": 1e6})
    np.testing.assert_allclose(damped, read(table, "qd_r"), rtol=1e-8, atol=1e-10)


def test_near_the_wrist_singularity_resolved_rate_blows_up_and_damped_least_squares_stays_bounded(table):
    # 1 mm and 0.017 rad off the pose at q5 = 0.002 rad, where sigma_min(J) is 4e-4
    x_d = perturbed_goal(Q_NEAR_WRIST_SINGULARITY, np.full(3, 1e-3), np.array([0.01, -0.01, 0.01]))
    unbounded = {"gain": 5.0, "max_joint_speed": 1e6}
    rate_task(table, ResolvedRate, Q_NEAR_WRIST_SINGULARITY, x_d, unbounded)
    resolved = np.abs(read(table, "qd_r")).max()
    task = rate_task(table, DampedLeastSquares, Q_NEAR_WRIST_SINGULARITY, x_d,
                     {**unbounded, "max_damping": 0.05, "manipulability_threshold": 0.01})
    damped = np.linalg.norm(read(table, "qd_r"))
    # the variable damping is almost all on: w is far below the threshold
    assert task.module.manipulability < 1e-4
    assert math.sqrt(task.module.damping_squared) > 0.049
    # the stated bound |qd_r| <= gain |e| / (2 lambda), here under 1 rad/s
    gain_error = 5.0 * error_norm(x_d, Q_NEAR_WRIST_SINGULARITY)
    assert damped <= gain_error / (2 * math.sqrt(task.module.damping_squared))
    assert damped < 1.0
    assert resolved > 20.0  # rad/s, for a 1.7 mm and 1 degree error
    assert resolved > 100 * damped


def test_damped_least_squares_variable_damping_follows_nakamura_hanafusa(table):
    task = rate_task(table, DampedLeastSquares, Q_GENERIC, pose(Q_GENERIC),
                     {"damping": 0.01, "max_damping": 0.2, "manipulability_threshold": 0.04})
    module = task.module
    assert module.damping_for(0.0) == pytest.approx(0.01**2 + 0.2**2)
    assert module.damping_for(0.02) == pytest.approx(0.01**2 + 0.2**2 * 0.75)
    assert module.damping_for(0.04) == pytest.approx(0.01**2)
    assert module.damping_for(1.0) == pytest.approx(0.01**2)


@pytest.mark.parametrize("module", RATE_MODULES)
def test_rate_controller_at_the_goal_commands_no_motion(table, module):
    rate_task(table, module, Q_GENERIC, pose(Q_GENERIC))
    np.testing.assert_allclose(read(table, "qd_r"), np.zeros(N), rtol=0, atol=1e-12)


# --- TimeIntegrator -------------------------------------------------------------------------------


def integrator_task(table: StateTable, q_m: np.ndarray, params: dict | None = None) -> Task:
    write(table, q_m=q_m, qd_r=np.zeros(N), q_r=np.full(N, 9.0))  # a stale q_r another task left
    task = spawned(table, TimeIntegrator, params)
    assert task.turn_on(0.0), task.last_error
    return task


def test_time_integrator_starts_q_r_at_q_m_when_turned_on(table):
    integrator_task(table, Q_GENERIC)
    np.testing.assert_array_equal(read(table, "q_r"), Q_GENERIC)


def test_time_integrator_q_r_is_q_m_at_on_plus_the_sum_of_qd_r_times_period(table):
    task = integrator_task(table, Q_GENERIC)
    expected = Q_GENERIC.copy()
    for k in range(1, 501):
        qd_r = RNG.uniform(-2, 2, N)
        write(table, when=k * DT, qd_r=qd_r, q_m=RNG.uniform(-1, 1, N))  # q_m moving does not matter
        assert task.run_cycle(k * DT) is Status.CONTINUE
        expected = expected + qd_r * DT
        np.testing.assert_array_equal(read(table, "q_r"), expected)


def test_time_integrator_keeps_q_r_within_max_lead_of_q_m(table):
    task = integrator_task(table, np.zeros(N), {"max_lead": 0.05})
    write(table, when=DT, qd_r=np.array([1.0, -1.0, 0.5, 0.0, 2.0, -2.0]))
    for k in range(1, 201):  # the arm is held at 0 while the reference runs on
        assert task.run_cycle(k * DT) is Status.CONTINUE
    np.testing.assert_allclose(read(table, "q_r"), [0.05, -0.05, 0.05, 0.0, 0.05, -0.05], rtol=0, atol=1e-15)


def test_time_integrator_integrates_nothing_while_the_actuators_are_held_then_starts_again_from_q_m(table):
    task = integrator_task(table, np.zeros(N))
    write(table, when=DT, qd_r=np.full(N, 1.0))
    assert task.run_cycle(DT) is Status.CONTINUE
    table.set_flag(Flag.ILLEGAL_CONFIGURATION)  # the plant stopped: the robot interface holds the arm
    for k in range(2, 50):
        assert task.run_cycle(k * DT) is Status.CONTINUE
    np.testing.assert_allclose(read(table, "q_r"), np.full(N, DT), rtol=0, atol=1e-15)  # no running on
    table.set_flag(Flag.ILLEGAL_CONFIGURATION, False)
    write(table, when=50 * DT, q_m=np.full(N, 0.002))  # where the brakes stopped the arm
    assert task.run_cycle(50 * DT) is Status.CONTINUE
    np.testing.assert_allclose(read(table, "q_r"), np.full(N, 0.002 + DT), rtol=0, atol=1e-15)


# --- CartesianTrajectory --------------------------------------------------------------------------

CT_DT = 0.01
V_LIN, A_LIN, V_ANG, A_ANG = 0.2, 1.0, 0.8, 3.0
CT_LIMITS = {"max_linear_velocity": V_LIN, "max_linear_acceleration": A_LIN,
             "max_angular_velocity": V_ANG, "max_angular_acceleration": A_ANG}
V_MAX = np.array([V_LIN] * 3 + [V_ANG] * 3)
A_MAX = np.array([A_LIN] * 3 + [A_ANG] * 3)
X0 = np.array([0.4, -0.1, 0.5, 0.1, -0.2, 0.3])
X_GOAL = np.array([0.0, 0.2, 0.5004, 1.2, 0.3, -0.9])  # long, short, tiny; long turns both ways


def cartesian_task(table: StateTable) -> Task:
    write(table, x_m=X0, x_d=X_GOAL, x_r=np.full(6, 9.0))
    task = spawned(table, CartesianTrajectory, CT_LIMITS, period=CT_DT)
    assert task.turn_on(0.0), task.last_error
    return task


def run_cartesian(table: StateTable, task: Task, cycles: int) -> tuple[np.ndarray, np.ndarray]:
    x_r, xd_r = np.zeros((cycles, 6)), np.zeros((cycles, 6))
    for k in range(cycles):
        assert task.run_cycle((k + 1) * CT_DT) is Status.CONTINUE
        x_r[k], xd_r[k] = read(table, "x_r"), task.module.velocity
    return x_r, xd_r


def test_cartesian_trajectory_starts_from_x_m_when_turned_on(table):
    cartesian_task(table)
    np.testing.assert_array_equal(read(table, "x_r"), X0)


def test_cartesian_trajectory_arrives_exactly_at_x_d_and_stays(table):
    task = cartesian_task(table)
    x_r, xd_r = run_cartesian(table, task, 400)  # the longest move, 2.1 rad at 0.8 rad/s, takes ~3 s
    np.testing.assert_array_equal(x_r[-50:], np.broadcast_to(X_GOAL, (50, 6)))
    np.testing.assert_array_equal(xd_r[-50:], np.zeros((50, 6)))


def test_cartesian_trajectory_respects_linear_and_angular_velocity_and_acceleration_limits(table):
    task = cartesian_task(table)
    x_r, xd_r = run_cartesian(table, task, 400)
    assert np.all(np.abs(xd_r) <= V_MAX)
    np.testing.assert_array_equal(np.abs(xd_r).max(axis=0)[[0, 1, 3, 4, 5]], V_MAX[[0, 1, 3, 4, 5]])  # long moves cruise
    steps = np.abs(np.diff(np.vstack([np.zeros(6), xd_r]), axis=0))
    assert np.all(steps <= A_MAX * CT_DT * (1 + 1e-9))
    moved = np.abs(np.diff(np.vstack([X0, x_r]), axis=0))
    assert np.all(moved <= V_MAX * CT_DT * (1 + 1e-9))


# --- Params validation ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("module", "params", "message"),
    [
        (FkJacobian, {"frame": ""}, r"bad parameters for FkJacobian: frame must name a frame of the arm, got: ''"),
        (InverseDynamics, {"max_torque": 0.0},
         r"InverseDynamics\.max_torque must be a number > 0, or \.inf for no limit, got: 0"),
        (InverseDynamics, {"max_torque": math.nan}, r"InverseDynamics\.max_torque must be a number > 0, or \.inf for no limit, "
               r"got: \.nan \(not a number\)"),
        (GravityCompensation, {"scale": -1.0}, r"GravityCompensation\.scale must be in \[0, 10\], got: -1"),
        (GravityCompensation, {"scale": math.nan},
         r"GravityCompensation\.scale must be in \[0, 10\], got: \.nan \(not a number\)"),
        (ResolvedRate, {"gain": 0.0}, r"ResolvedRate\.gain must be in \(0, 10000\], got: 0"),
        (ResolvedRate, {"max_joint_speed": -1.0},
         r"ResolvedRate\.max_joint_speed must be a number > 0, or \.inf for no limit, got: -1"),
        (DampedLeastSquares, {"gain": math.inf}, r"DampedLeastSquares\.gain must be in \(0, 10000\], got: \.inf"),
        (DampedLeastSquares, {"damping": -0.1}, r"DampedLeastSquares\.damping must be in \[0, 10\], got: -0\.1"),
        (DampedLeastSquares, {"max_damping": 0.0},
         r"bad parameters for DampedLeastSquares: max_damping and manipulability_threshold must both be > 0 \(variable damping\) "
         r"or both 0, got: 0\.0, 0\.01"),
        (DampedLeastSquares, {"max_damping": 0.0, "manipulability_threshold": 0.0},
         r"bad parameters for DampedLeastSquares: damping or max_damping must be > 0, or J J\^T is singular at a singularity"),
        (DampedLeastSquares, {"max_joint_speed": 0.0},
         r"DampedLeastSquares\.max_joint_speed must be a number > 0, or \.inf for no limit, got: 0"),
        (TimeIntegrator, {"max_lead": 0.0}, r"TimeIntegrator\.max_lead must be a number > 0, or \.inf for no limit, got: 0"),
        (CartesianTrajectory, {"max_linear_velocity": 0.0},
         r"CartesianTrajectory\.max_linear_velocity must be in \(0, 100\], got: 0"),
        (CartesianTrajectory, {"max_angular_acceleration": -2.0},
         r"CartesianTrajectory\.max_angular_acceleration must be in \(0, 10000\], got: -2"),
    ],
)
def test_modules_refuse_bad_params_saying_which_and_why(module, params, message):
    with pytest.raises(ParamError, match=rf"^{message}$"):
        module.build_params(params)


def test_every_module_accepts_its_default_params():
    for module in (FkJacobian, InverseDynamics, GravityCompensation, ResolvedRate, DampedLeastSquares,
                   TimeIntegrator, CartesianTrajectory):
        module.build_params({})
