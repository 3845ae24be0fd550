"""The `ARM` and `EE` constants of a compiled MuJoCo model: what the controllers' model is built from.

Read from the model the plant steps, after MuJoCo compiled it, so what a controller computes with
is what is simulated: a URDF's fixed links are lumped into the joint they move with, inertias
MuJoCo computed from geoms are included, and the joint angles are MuJoCo's own `qpos`. Every
placement is taken with all joints at zero (not at the model's reference pose `qpos0`), which is
what zero means to both MuJoCo's `qpos` and Pinocchio's q.
"""

from __future__ import annotations

import mujoco
import numpy as np

from pbo_runtime import Arm

_KIND = {int(mujoco.mjtJoint.mjJNT_HINGE): Arm.HINGE, int(mujoco.mjtJoint.mjJNT_SLIDE): Arm.SLIDE}


def _pose(position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = position
    return pose


def _quaternion(rotation: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation).reshape(9))
    return quat


class ArmTables:
    """`arm` (NDOF, Arm.WIDTH) and `ee` (Arm.EE_WIDTH,) of `model`, with the end effector at `ee_site`.

    `effort` and `velocity` (NDOF,) are the limits found beside the model (a URDF's `<limit>`, an
    actuator's range, a plant option): MuJoCo keeps only some of them.
    """

    def __init__(self, model: mujoco.MjModel, ee_site: int, effort: np.ndarray, velocity: np.ndarray) -> None:
        data = mujoco.MjData(model)
        data.qpos[:] = 0.0
        mujoco.mj_kinematics(model, data)
        n = model.njnt
        body_joint = np.full(model.nbody, -1)  # the joint each body moves with (its own, or an ancestor's)
        for body in range(1, model.nbody):
            own = model.body_jntadr[body]
            body_joint[body] = own if model.body_jntnum[body] == 1 else body_joint[model.body_parentid[body]]
        frames = []  # each joint's frame in the world, joints at zero
        for joint in range(n):
            body = model.jnt_bodyid[joint]
            rotation = data.xmat[body].reshape(3, 3)
            frames.append(_pose(data.xpos[body] + rotation @ model.jnt_pos[joint], rotation))
        self.arm = np.zeros((n, Arm.WIDTH))
        for joint in range(n):
            body = model.jnt_bodyid[joint]
            parent = body_joint[model.body_parentid[body]]
            in_parent = np.linalg.solve(frames[parent], frames[joint]) if parent >= 0 else frames[joint]
            row = self.arm[joint]
            row[Arm.PARENT] = parent
            row[Arm.TYPE] = _KIND[int(model.jnt_type[joint])]
            row[Arm.POSITION] = in_parent[:3, 3]
            row[Arm.ORIENTATION] = _quaternion(in_parent[:3, :3])
            row[Arm.AXIS] = model.jnt_axis[joint]
            dof = model.jnt_dofadr[joint]
            row[Arm.ARMATURE] = model.dof_armature[dof]
            row[Arm.DAMPING] = model.dof_damping[dof]
            if model.jnt_limited[joint]:
                row[Arm.LIMITED] = 1.0
                row[Arm.Q_MIN], row[Arm.Q_MAX] = model.jnt_range[joint]
            row[Arm.EFFORT] = effort[joint]
            row[Arm.VELOCITY] = velocity[joint]
            self._lump(model, data, body_joint, joint, frames[joint], row)
        site_body = model.site_bodyid[ee_site]
        owner = body_joint[site_body]
        site_pose = _pose(data.site_xpos[ee_site], data.site_xmat[ee_site].reshape(3, 3))
        in_owner = np.linalg.solve(frames[owner], site_pose) if owner >= 0 else site_pose
        self.ee = np.zeros(Arm.EE_WIDTH)
        self.ee[0] = owner
        self.ee[1:4] = in_owner[:3, 3]
        self.ee[4:8] = _quaternion(in_owner[:3, :3])

    @staticmethod
    def _lump(model: mujoco.MjModel, data: mujoco.MjData, body_joint: np.ndarray, joint: int,
              frame: np.ndarray, row: np.ndarray) -> None:
        """Mass, centre of mass and inertia of every body moving with `joint`, in its frame."""
        rotation_t, origin = frame[:3, :3].T, frame[:3, 3]
        mass, first_moment, about_origin = 0.0, np.zeros(3), np.zeros((3, 3))
        for body in np.flatnonzero(body_joint == joint):
            m = model.body_mass[body]
            if m == 0.0:
                continue
            com = rotation_t @ (data.xipos[body] - origin)
            principal = rotation_t @ data.ximat[body].reshape(3, 3)
            inertia = principal @ np.diag(model.body_inertia[body]) @ principal.T
            about_origin += inertia + m * (com @ com * np.eye(3) - np.outer(com, com))
            mass += m
            first_moment += m * com
        row[Arm.MASS] = mass
        if mass > 0:
            com = first_moment / mass
            about_com = about_origin - mass * (com @ com * np.eye(3) - np.outer(com, com))
            row[Arm.COM] = com
            row[Arm.INERTIA] = [
                about_com[0, 0],
                about_com[1, 1],
                about_com[2, 2],
                about_com[0, 1],
                about_com[0, 2],
                about_com[1, 2],
            ]
