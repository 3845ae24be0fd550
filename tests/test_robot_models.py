"""The plant's MuJoCo model and the controllers' Pinocchio model are the same arm.

A registered robot is a RobotDescription's DH and DYN arrays. The plant's MuJoCo model is built
from them (`drivers.robots.mjcf`, then `drivers.robots.plant_model.load_robot`); the controllers'
Pinocchio model from the ARM and EE tables the plant reads back from its compiled model
(`pbo_runtime.arm_model`); and the tests' own oracle builds a Pinocchio model straight from the
DH rows (`tests.support.dh_pinocchio_model`). Three independent roads, held to each other.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pinocchio
import pytest

from drivers.robots import RobotDescription, robot, robot_names, to_mjcf
from drivers.robots.plant_model import PlantRobot, load_robot
from modules._robot_model import END_EFFECTOR_FRAME
from pbo_runtime import Arm, arm_model
from pbo_runtime.objects.waits import cycles_meanwhile
from tests.support import REPO, dh_forward_kinematics, dh_pinocchio_model

TIMESTEP = 0.001
ROBOTS = ("puma560", "redundant7")
#: The two Pinocchio models of a registered arm: the controllers' (from the plant's ARM and EE
#: tables) and the tests' oracle (straight from the DH rows).
PINOCCHIO_MODELS = ("arm_table", "dh_oracle")


@pytest.fixture(scope="module", params=ROBOTS)
def desc(request) -> RobotDescription:
    """Each registered arm in turn: the agreement tests hold for every robot."""
    return robot(request.param)


@pytest.fixture(scope="module")
def puma() -> RobotDescription:
    return robot("puma560")


@pytest.fixture(scope="module")
def arm7() -> RobotDescription:
    return robot("redundant7")


@pytest.fixture(scope="module")
def loaded(desc: RobotDescription) -> PlantRobot:
    """The robot as the plant loads it: its compiled MuJoCo model and the ARM and EE read from it."""
    return load_robot(desc.name, Path("."), TIMESTEP, {})


@pytest.fixture(scope="module")
def mj(loaded: PlantRobot) -> tuple[mujoco.MjModel, mujoco.MjData]:
    return loaded.model, mujoco.MjData(loaded.model)


def pinocchio_of(kind: str, desc: RobotDescription) -> pinocchio.Model:
    """The controllers' model of `desc` (from the plant's ARM and EE) or the DH oracle's."""
    if kind == "dh_oracle":
        return dh_pinocchio_model(desc.dh, desc.dyn)
    loaded = load_robot(desc.name, Path("."), TIMESTEP, {})
    return arm_model(loaded.arm, loaded.ee)


@pytest.fixture(scope="module", params=PINOCCHIO_MODELS)
def pin(request, desc: RobotDescription) -> tuple[pinocchio.Model, pinocchio.Data]:
    """Each Pinocchio model in turn: every agreement with MuJoCo holds for both."""
    model = pinocchio_of(request.param, desc)
    return model, model.createData()


def random_states(desc: RobotDescription, count: int = 20, seed: int = 560):
    """States strictly inside the joint limits, so no limit constraint acts in MuJoCo."""
    rng = np.random.default_rng(seed)
    lower, upper = desc.joint_limits[:, 0], desc.joint_limits[:, 1]
    margin = 0.05
    for _ in range(count):
        q = rng.uniform(lower + margin, upper - margin)
        yield q, rng.uniform(-2.0, 2.0, desc.ndof), rng.uniform(-5.0, 5.0, desc.ndof)


def test_pinocchio_rnea_agrees_with_mujoco_inverse_dynamics(desc, mj, pin) -> None:
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    for q, qd, qdd in random_states(desc):
        mj_data.qpos[:], mj_data.qvel[:], mj_data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(mj_model, mj_data)
        assert mj_data.nefc == 0, "a joint limit was active; the states must avoid them"
        # MuJoCo's inverse dynamics includes the joint damping (a passive force); Pinocchio's has none.
        tau = pinocchio.rnea(pin_model, pin_data, q, qd, qdd) + desc.damping * qd
        np.testing.assert_allclose(mj_data.qfrc_inverse, tau, rtol=0, atol=1e-6)


def test_armature_is_part_of_both_models(desc, mj, pin) -> None:
    mj_model, _ = mj
    pin_model, _ = pin
    np.testing.assert_array_equal(mj_model.dof_armature, desc.dyn[:, 10])
    np.testing.assert_array_equal(pin_model.armature, desc.dyn[:, 10])


def test_mass_matrices_agree(desc, mj, pin) -> None:
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    full = np.zeros((desc.ndof, desc.ndof))
    for q, _, _ in random_states(desc):
        mj_data.qpos[:] = q
        mujoco.mj_forward(mj_model, mj_data)
        mujoco.mj_fullM(mj_model, mj_data, full)
        upper = pinocchio.crba(pin_model, pin_data, q)
        pin_mass = np.triu(upper) + np.triu(upper, 1).T
        np.testing.assert_allclose(full, pin_mass, rtol=0, atol=1e-9)


def test_joint_frames_agree_between_pinocchio_and_mujoco_bodies(desc, mj, pin) -> None:
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    for q, _, _ in random_states(desc):
        mj_data.qpos[:] = q
        mujoco.mj_kinematics(mj_model, mj_data)
        pinocchio.forwardKinematics(pin_model, pin_data, q)
        for i in range(1, desc.ndof + 1):
            body = mj_model.body(f"link{i}").id
            np.testing.assert_allclose(pin_data.oMi[i].translation, mj_data.xpos[body], atol=1e-12)
            np.testing.assert_allclose(pin_data.oMi[i].rotation, mj_data.xmat[body].reshape(3, 3), atol=1e-12)


def test_end_effector_is_the_last_dh_frame_in_all_three(desc, mj, pin) -> None:
    # all three: the DH product itself, the Pinocchio model's frame ee and the plant's site ee
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    frame = pin_model.getFrameId(END_EFFECTOR_FRAME)
    site = mj_model.site("ee").id
    for q, _, _ in random_states(desc):
        expected = dh_forward_kinematics(desc.dh, q)
        pinocchio.framesForwardKinematics(pin_model, pin_data, q)
        np.testing.assert_allclose(pin_data.oMf[frame].homogeneous, expected, atol=1e-12)
        mj_data.qpos[:] = q
        mujoco.mj_kinematics(mj_model, mj_data)
        np.testing.assert_allclose(mj_data.site_xpos[site], expected[:3, 3], atol=1e-12)
        np.testing.assert_allclose(mj_data.site_xmat[site].reshape(3, 3), expected[:3, :3], atol=1e-12)


def test_dh_kinematics_reproduce_the_published_puma_reach(puma) -> None:
    # Corke's p560.fkine(qz): (a2 + a3, -d3, d4), tool z pointing up (z1 is -y0, so d3 goes to -y).
    pose = dh_forward_kinematics(puma.dh, np.zeros(6))
    np.testing.assert_allclose(pose[:3, 3], [0.4521, -0.15005, 0.4318], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 2], [0.0, 0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("kind", PINOCCHIO_MODELS)
def test_gravity_load_matches_corkes_published_value(puma, kind) -> None:
    # Corke's p560.gravload(qz) = [0 37.4837 0.2489 0 0 0]; our changes to link 1 and to link 3's
    # Izz must not move it.
    pin_model = pinocchio_of(kind, puma)
    pin_data = pin_model.createData()
    gravity = pinocchio.computeGeneralizedGravity(pin_model, pin_data, np.zeros(6))
    np.testing.assert_allclose(gravity, [0, 37.4837, 0.2489, 0, 0, 0], atol=1e-4)


def test_a_description_with_an_impossible_inertia_is_refused(puma) -> None:
    dyn = puma.dyn.copy()
    dyn[2, 6] = 0.0125  # Corke's published link-3 Izz
    rule = r"^robot 'puma560': link 3 principal inertias must satisfy the triangle inequality"
    with pytest.raises(ValueError, match=rule):
        RobotDescription(
            name="puma560", ndof=6, dh=puma.dh, dyn=dyn, damping=puma.damping,
            joint_limits=puma.joint_limits, torque_limits=puma.torque_limits, q0=puma.q0,
        )


def test_descriptions_are_immutable(puma) -> None:
    with pytest.raises(ValueError, match="read-only"):
        puma.dh[0, 0] = 1.0


def test_an_unknown_robot_name_lists_the_known_ones() -> None:
    with pytest.raises(ValueError, match=r"^unknown robot model 'puma561'; known models: .*puma560"):
        robot("puma561")


def test_every_robot_is_registered_and_builds_in_mujoco() -> None:
    assert robot_names() == ROBOTS
    for name in ROBOTS:
        desc = robot(name)
        assert desc.name == name
        mujoco.MjModel.from_xml_string(to_mjcf(desc, TIMESTEP))
        assert load_robot(name, Path("."), TIMESTEP, {}).ndof == desc.ndof


def test_the_generated_mjcf_has_no_plant_parts_and_load_robot_adds_them_once() -> None:
    """to_mjcf is the arm alone; the wrist sensor and the camera's target are the plant's, added by load_robot."""
    alone = mujoco.MjModel.from_xml_string(to_mjcf(robot("puma560"), TIMESTEP))
    assert (alone.nsensor, alone.nmocap) == (0, 0)
    assert all(alone.body(i).name != "ft" for i in range(alone.nbody))
    plant = load_robot("puma560", Path("."), TIMESTEP, {}, target=True).model
    assert [plant.sensor(i).name for i in range(plant.nsensor)] == ["ft_force", "ft_torque"]
    assert plant.nmocap == 1 and plant.body("target").mocapid[0] == 0
    assert plant.site("ft").bodyid[0] == plant.body("ft").id
    np.testing.assert_array_equal(plant.body("ft").pos, alone.site("ee").pos)  # welded at the end effector
    assert (plant.nq, plant.nv) == (alone.nq, alone.nv)  # the target is a mocap body: no joint of its own


def test_the_arm_table_carries_the_descriptions_limits_armature_and_damping(desc, loaded) -> None:
    arm = loaded.arm
    assert arm.shape == (desc.ndof, Arm.WIDTH) and loaded.ee.shape == (Arm.EE_WIDTH,)
    np.testing.assert_array_equal(arm[:, Arm.PARENT], np.arange(desc.ndof) - 1)  # a serial chain
    np.testing.assert_array_equal(arm[:, Arm.TYPE], Arm.HINGE)
    np.testing.assert_array_equal(arm[:, Arm.LIMITED], 1.0)
    np.testing.assert_array_equal(arm[:, [Arm.Q_MIN, Arm.Q_MAX]], desc.joint_limits)
    np.testing.assert_array_equal(arm[:, Arm.EFFORT], desc.torque_limits)
    np.testing.assert_array_equal(arm[:, Arm.ARMATURE], desc.dyn[:, 10])
    np.testing.assert_array_equal(arm[:, Arm.DAMPING], desc.damping)
    np.testing.assert_allclose(arm[:, Arm.MASS], desc.dyn[:, 0], rtol=1e-12)
    assert loaded.ee[0] == desc.ndof - 1  # the end effector moves with the last joint


def test_gravity_never_needs_more_than_the_torque_limits(desc, pin) -> None:
    pin_model, pin_data = pin
    worst = np.zeros(desc.ndof)
    for q, _, _ in random_states(desc, count=500, seed=7):
        worst = np.maximum(worst, np.abs(pinocchio.computeGeneralizedGravity(pin_model, pin_data, q)))
    assert np.all(worst < 0.5 * desc.torque_limits), worst / desc.torque_limits


# --- redundant7: the iiwa-like S-R-S arm ---------------------------------------------------------


def test_redundant7_is_a_spherical_shoulder_elbow_spherical_wrist_arm(arm7) -> None:
    assert arm7.ndof == 7
    np.testing.assert_array_equal(arm7.dh[:, 2], np.zeros(7))  # no a offsets: the axes intersect
    # stretched straight up at q = 0: shoulder 0.36, elbow 0.78, wrist 1.18, flange 1.306 m
    pose = dh_forward_kinematics(arm7.dh, np.zeros(7))
    np.testing.assert_allclose(pose[:3, 3], [0.0, 0.0, 1.306], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 2], [0.0, 0.0, 1.0], atol=1e-12)
    # wherever the arm is, joints 1-3 meet at the shoulder, 0.36 m up, and joints 5-7 at the
    # wrist centre, 0.126 m behind the flange (DH frames 1, 2 and 5, 6 sit on those points)
    rng = np.random.default_rng(3)
    for _ in range(10):
        q = rng.uniform(arm7.joint_limits[:, 0], arm7.joint_limits[:, 1])
        flange = dh_forward_kinematics(arm7.dh, q)
        for k in (1, 2):
            np.testing.assert_allclose(dh_forward_kinematics(arm7.dh[:k], q[:k])[:3, 3], [0, 0, 0.36], atol=1e-12)
        for k in (5, 6):
            frame = dh_forward_kinematics(arm7.dh[:k], q[:k])
            np.testing.assert_allclose(frame[:3, 3], flange[:3, 3] - 0.126 * flange[:3, 2], atol=1e-12)


def ee_jacobian(desc: RobotDescription, q: np.ndarray, kind: str) -> np.ndarray:
    model = pinocchio_of(kind, desc)
    data = model.createData()
    frame = model.getFrameId(END_EFFECTOR_FRAME)
    return pinocchio.computeFrameJacobian(model, data, q, frame, pinocchio.LOCAL_WORLD_ALIGNED)


@pytest.mark.parametrize("kind", PINOCCHIO_MODELS)
def test_redundant7_home_pose_is_away_from_singularities_with_one_self_motion(arm7, kind) -> None:
    singular_values = np.linalg.svd(ee_jacobian(arm7, arm7.q0, kind), compute_uv=False)
    assert singular_values.shape == (6,)
    assert singular_values.min() > 0.1  # full rank 6 of 7 joints: one redundant DOF left
    # at q = 0 the arm is stretched out and singular
    assert np.linalg.svd(ee_jacobian(arm7, np.zeros(7), kind), compute_uv=False).min() < 1e-12


# Drake's iiwa14_no_collision.urdf, verbatim: joint (xyz, rpy) and link (mass, com, diagonal inertia).
_URDF_JOINTS = [
    ((0, 0, 0.1575), (0, 0, 0)), ((0, 0, 0.2025), (np.pi / 2, 0, np.pi)), ((0, 0.2045, 0), (np.pi / 2, 0, np.pi)),
    ((0, 0, 0.2155), (np.pi / 2, 0, 0)), ((0, 0.1845, 0), (-np.pi / 2, np.pi, 0)), ((0, 0, 0.2155), (np.pi / 2, 0, 0)),
    ((0, 0.081, 0), (-np.pi / 2, np.pi, 0)),
]
_URDF_LINKS = [
    (5.76, (0, -0.03, 0.12), (0.033, 0.0333, 0.0123)), (6.35, (0.0003, 0.059, 0.042), (0.0305, 0.0304, 0.011)),
    (3.5, (0, 0.03, 0.13), (0.025, 0.0238, 0.0076)), (3.5, (0, 0.067, 0.034), (0.017, 0.0164, 0.006)),
    (3.5, (0.0001, 0.021, 0.076), (0.01, 0.0087, 0.00449)), (1.8, (0, 0.0006, 0.0004), (0.0049, 0.0047, 0.0036)),
    (1.2, (0, 0, 0.02), (0.001, 0.001, 0.001)),
]


def urdf_as_mjcf(desc: RobotDescription) -> str:
    """The Drake URDF's chain in MuJoCo, with our armature: an independent build of the same arm."""
    text = '<mujoco><compiler angle="radian" eulerseq="XYZ"/><option gravity="0 0 -9.81"/><worldbody>'
    for i, ((xyz, rpy), (mass, com, inertia)) in enumerate(zip(_URDF_JOINTS, _URDF_LINKS, strict=True)):
        text += (
            f'<body pos="{" ".join(map(str, xyz))}" euler="{" ".join(map(str, rpy))}">'
            f'<joint type="hinge" axis="0 0 1" armature="{desc.dyn[i, 10]}"/>'
            f'<inertial pos="{" ".join(map(str, com))}" mass="{mass}" diaginertia="{" ".join(map(str, inertia))}"/>'
        )
    return text + "</body>" * 7 + "</worldbody></mujoco>"


def test_redundant7_is_the_drake_iiwa14_urdf_moved_into_dh_frames(arm7) -> None:
    """Same mass matrix and gravity torques as Drake's URDF everywhere: the COMs and inertias were
    moved into the DH frames correctly, and every joint turns the same way as KUKA's."""
    urdf = mujoco.MjModel.from_xml_string(urdf_as_mjcf(arm7))
    ours = load_robot("redundant7", Path("."), TIMESTEP, {}).model  # the plant's, wrist sensor and all
    ours.dof_damping[:] = 0.0  # the URDF build has none
    full_urdf, full_ours = np.zeros((7, 7)), np.zeros((7, 7))
    data_urdf, data_ours = mujoco.MjData(urdf), mujoco.MjData(ours)
    for q, _, _ in random_states(arm7):
        for model, data, full in ((urdf, data_urdf, full_urdf), (ours, data_ours, full_ours)):
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            mujoco.mj_fullM(model, data, full)
        np.testing.assert_allclose(full_ours, full_urdf, rtol=0, atol=1e-12)
        np.testing.assert_allclose(data_ours.qfrc_bias, data_urdf.qfrc_bias, rtol=0, atol=1e-10)
    # and the flange: the URDF's last joint origin plus 0.045 m is our DH frame 7
    mujoco.mj_kinematics(urdf, data_urdf)
    last = urdf.nbody - 1
    flange = data_urdf.xpos[last] + 0.045 * data_urdf.xmat[last].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(flange, dh_forward_kinematics(arm7.dh, q)[:3, 3], atol=1e-12)


def test_every_robot_model_is_registered_for_the_checker_with_its_dims() -> None:
    from pbo_runtime.objects import registry

    assert registry.names(registry.ROBOTS) == robot_names()
    for name in robot_names():
        assert registry.robot_dims(name) == {"NDOF": robot(name).ndof}


def test_building_the_arms_model_in_a_live_spawns_init_lets_the_due_cycles_run_between_its_joints():
    loaded = load_robot("puma560", REPO, 0.001, {})
    cycle_points: list[float] = []
    with cycles_meanwhile(cycle_points.append):  # the executive's, in a live spawn: here, each is counted
        model = arm_model(loaded.arm, loaded.ee)
    assert model.njoints - 1 == len(cycle_points) == 6 and cycle_points == [0] * 6
