"""The plant's MuJoCo model and the controllers' Pinocchio model are the same arm.

Both are built from one RobotDescription's DH and DYN arrays by independent code
(`drivers.robots.mjcf` and `modules._robot_model`); these tests hold them to each other.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio
import pytest

from drivers.robots import RobotDescription, robot, to_mjcf
from modules._robot_model import END_EFFECTOR_FRAME, forward_kinematics_dh, pinocchio_model

TIMESTEP = 0.001


@pytest.fixture(scope="module")
def puma() -> RobotDescription:
    return robot("puma560")


@pytest.fixture(scope="module")
def mj(puma: RobotDescription) -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(to_mjcf(puma, TIMESTEP))
    return model, mujoco.MjData(model)


@pytest.fixture(scope="module")
def pin(puma: RobotDescription) -> tuple[pinocchio.Model, pinocchio.Data]:
    model = pinocchio_model(puma.dh, puma.dyn)
    return model, model.createData()


def random_states(puma: RobotDescription, count: int = 20, seed: int = 560):
    """States strictly inside the joint limits, so no limit constraint acts in MuJoCo."""
    rng = np.random.default_rng(seed)
    lower, upper = puma.joint_limits[:, 0], puma.joint_limits[:, 1]
    margin = 0.05
    for _ in range(count):
        q = rng.uniform(lower + margin, upper - margin)
        yield q, rng.uniform(-2.0, 2.0, puma.ndof), rng.uniform(-5.0, 5.0, puma.ndof)


def test_pinocchio_rnea_agrees_with_mujoco_inverse_dynamics(puma, mj, pin) -> None:
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    for q, qd, qdd in random_states(puma):
        mj_data.qpos[:], mj_data.qvel[:], mj_data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(mj_model, mj_data)
        assert mj_data.nefc == 0, "a joint limit was active; the states must avoid them"
        # MuJoCo's inverse dynamics includes the joint damping (a passive force); Pinocchio's has none.
        tau = pinocchio.rnea(pin_model, pin_data, q, qd, qdd) + puma.damping * qd
        np.testing.assert_allclose(mj_data.qfrc_inverse, tau, rtol=0, atol=1e-6)


def test_armature_is_part_of_both_models(puma, mj, pin) -> None:
    mj_model, _ = mj
    pin_model, _ = pin
    np.testing.assert_array_equal(mj_model.dof_armature, puma.dyn[:, 10])
    np.testing.assert_array_equal(pin_model.armature, puma.dyn[:, 10])


def test_mass_matrices_agree(puma, mj, pin) -> None:
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    full = np.zeros((puma.ndof, puma.ndof))
    for q, _, _ in random_states(puma):
        mj_data.qpos[:] = q
        mujoco.mj_forward(mj_model, mj_data)
        mujoco.mj_fullM(mj_model, mj_data, full)
        upper = pinocchio.crba(pin_model, pin_data, q)
        pin_mass = np.triu(upper) + np.triu(upper, 1).T
        np.testing.assert_allclose(full, pin_mass, rtol=0, atol=1e-9)


def test_joint_frames_agree_between_pinocchio_and_mujoco_bodies(puma, mj, pin) -> None:
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    for q, _, _ in random_states(puma):
        mj_data.qpos[:] = q
        mujoco.mj_kinematics(mj_model, mj_data)
        pinocchio.forwardKinematics(pin_model, pin_data, q)
        for i in range(1, puma.ndof + 1):
            body = mj_model.body(f"link{i}").id
            np.testing.assert_allclose(pin_data.oMi[i].translation, mj_data.xpos[body], atol=1e-12)
            np.testing.assert_allclose(pin_data.oMi[i].rotation, mj_data.xmat[body].reshape(3, 3), atol=1e-12)


def test_end_effector_is_the_last_dh_frame_in_all_three(puma, mj, pin) -> None:
    mj_model, mj_data = mj
    pin_model, pin_data = pin
    frame = pin_model.getFrameId(END_EFFECTOR_FRAME)
    site = mj_model.site("ee").id
    for q, _, _ in random_states(puma):
        expected = forward_kinematics_dh(puma.dh, q)
        pinocchio.framesForwardKinematics(pin_model, pin_data, q)
        np.testing.assert_allclose(pin_data.oMf[frame].homogeneous, expected, atol=1e-12)
        mj_data.qpos[:] = q
        mujoco.mj_kinematics(mj_model, mj_data)
        np.testing.assert_allclose(mj_data.site_xpos[site], expected[:3, 3], atol=1e-12)
        np.testing.assert_allclose(mj_data.site_xmat[site].reshape(3, 3), expected[:3, :3], atol=1e-12)


def test_dh_kinematics_reproduce_the_published_puma_reach(puma) -> None:
    # Corke's p560.fkine(qz): (a2 + a3, -d3, d4), tool z pointing up (z1 is -y0, so d3 goes to -y).
    pose = forward_kinematics_dh(puma.dh, np.zeros(6))
    np.testing.assert_allclose(pose[:3, 3], [0.4521, -0.15005, 0.4318], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 2], [0.0, 0.0, 1.0], atol=1e-12)


def test_gravity_load_matches_corkes_published_value(puma, pin) -> None:
    # Corke's p560.gravload(qz) = [0 37.4837 0.2489 0 0 0]; our changes to link 1 and to link 3's
    # Izz must not move it.
    pin_model, pin_data = pin
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
