"""The arm's constants as the state table carries them, and the Pinocchio model made from them.

A robot interface publishes two out-consts: `ARM`, one row per joint, and `EE`, the end effector.
The plant makes both from the MuJoCo model it compiled from the robot's file (a URDF, an MJCF, or
a built-in robot's generated MJCF), so a controller that builds its model with `arm_model`
computes with the arm the plant simulates, whatever file described it and however MuJoCo read
that file. Rows are in MuJoCo's joint order, a parent always before its children.

Units: m, rad, kg, kg m², N m (N) and N m s/rad (N s/m) for hinge (slide) joints.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pbo_runtime.objects.waits import sleep_while_cycling

#: The columns of one `ARM` row. A joint's frame is its body's frame moved to the joint's anchor,
#: placed in its parent joint's frame (or the world's, parent -1) with every joint at zero.
ARM_COLUMNS = (
    "parent",  # the row of the joint this one moves with, -1 for the world
    "type",  # HINGE or SLIDE
    "x", "y", "z",  # the joint frame's origin in the parent joint's frame
    "qw", "qx", "qy", "qz",  # its orientation there, a unit quaternion
    "ax", "ay", "az",  # the joint axis in its own frame, a unit vector
    "mass",  # the body and everything welded to it
    "cx", "cy", "cz",  # their centre of mass in the joint frame
    "ixx", "iyy", "izz", "ixy", "ixz", "iyz",  # their inertia about that centre, joint frame axes
    "armature",  # rotor inertia reflected through the gearing
    "damping",  # viscous friction
    "limited",  # 1 if the joint has a position range, else 0 (q_min and q_max are then 0)
    "q_min", "q_max",  # the range
    "effort",  # the actuator's torque (force) limit, > 0
    "velocity",  # the speed limit the file gives, 0 when it gives none
)

#: The layout of `EE`: the row of the joint the end effector moves with, then its placement in that
#: joint's frame (origin, unit quaternion w x y z).
EE_COLUMNS = ("parent", "x", "y", "z", "qw", "qx", "qy", "qz")


class Arm:
    """Where each quantity is in an `ARM` row and in `EE`: `arm[:, Arm.MASS]`, `arm[j, Arm.AXIS]`."""

    WIDTH = len(ARM_COLUMNS)
    PARENT, TYPE = 0, 1
    POSITION, ORIENTATION, AXIS = slice(2, 5), slice(5, 9), slice(9, 12)
    MASS, COM, INERTIA = 12, slice(13, 16), slice(16, 22)
    ARMATURE, DAMPING, LIMITED, Q_MIN, Q_MAX, EFFORT, VELOCITY = 22, 23, 24, 25, 26, 27, 28
    HINGE, SLIDE = 0.0, 1.0  # the values of TYPE
    EE_WIDTH = len(EE_COLUMNS)


#: The operational frame at the end effector in an `arm_model`; joint i's frames are `joint<i>`
#: (the joint) and `link<i>` (its body), i from 1.
END_EFFECTOR_FRAME = "ee"
GRAVITY = (0.0, 0.0, -9.81)

#: What a robot file's name ends with: a URDF, or an MJCF.
ROBOT_SUFFIXES = (".urdf", ".xml", ".mjcf")
#: Plant options that change the robot itself (the rest change the world around it).
ROBOT_OPTIONS = ("ee", "q0", "torque_limits", "velocity_limits", "joint_limits")


def is_robot_file(model: str) -> bool:
    """Whether a plant's `model:` names a robot file (a path or a package:// URI), not a registered robot."""
    return model.startswith("package://") or model.lower().endswith(ROBOT_SUFFIXES) or "/" in model


def check_arm(arm: Any, ee: Any) -> tuple[np.ndarray, np.ndarray]:
    """`arm` and `ee` as float arrays, or ValueError naming the first thing that is not a valid arm."""
    arm = np.asarray(arm, dtype=np.float64)
    ee = np.asarray(ee, dtype=np.float64).reshape(-1)
    if arm.ndim != 2 or arm.shape[1] != Arm.WIDTH or arm.shape[0] < 1:
        raise ValueError(f"ARM must have shape (NDOF, {Arm.WIDTH}), got: {arm.shape}")
    if ee.shape != (Arm.EE_WIDTH,):
        raise ValueError(f"EE must have shape ({Arm.EE_WIDTH},), got: {ee.shape}")
    if not (np.all(np.isfinite(arm)) and np.all(np.isfinite(ee))):
        raise ValueError("ARM and EE must be finite")
    for row in range(arm.shape[0]):
        parent = arm[row, Arm.PARENT]
        if parent != int(parent) or not -1 <= parent < row:
            raise ValueError(f"ARM row {row}: parent must be -1 or an earlier row, got: {parent:g}")
        if arm[row, Arm.TYPE] not in (Arm.HINGE, Arm.SLIDE):
            raise ValueError(
                f"ARM row {row}: type must be {Arm.HINGE:g} (hinge) or {Arm.SLIDE:g} (slide), got: {arm[row, Arm.TYPE]:g}"
            )
        if arm[row, Arm.MASS] < 0 or arm[row, Arm.EFFORT] <= 0:
            raise ValueError(f"ARM row {row}: mass must be >= 0 and effort > 0")
    if ee[0] != int(ee[0]) or not -1 <= ee[0] < arm.shape[0]:
        raise ValueError(f"EE: parent must be -1 or a row of ARM, got: {ee[0]:g}")
    return arm, ee


def inertia_matrix(six: np.ndarray) -> np.ndarray:
    """The symmetric 3x3 matrix of (ixx, iyy, izz, ixy, ixz, iyz)."""
    ixx, iyy, izz, ixy, ixz, iyz = six
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def arm_model(arm: Any, ee: Any, name: str = "arm") -> Any:
    """The arm as a `pinocchio.Model`: joints `joint<i>`, bodies `link<i>`, operational frame `ee`,
    armature, limits and gravity as in `GRAVITY`; its q is the plant's joint vector.

    Made at `init`, never in `cycle`: building a model allocates.
    """
    import pinocchio  # here: `pbo check` never needs it

    arm, ee = check_arm(arm, ee)
    model = pinocchio.Model()
    model.name = name
    joint_ids: list[int] = []
    for row, values in enumerate(arm):
        parent = int(values[Arm.PARENT])
        placement = _se3(pinocchio, values[Arm.POSITION], values[Arm.ORIENTATION])
        joint = _joint_model(pinocchio, values[Arm.TYPE], values[Arm.AXIS])
        joint_id = model.addJoint(joint_ids[parent] if parent >= 0 else 0, joint, placement, f"joint{row + 1}")
        inertia = pinocchio.Inertia(float(values[Arm.MASS]), values[Arm.COM].copy(), inertia_matrix(values[Arm.INERTIA]))
        model.appendBodyToJoint(joint_id, inertia, pinocchio.SE3.Identity())
        model.addBodyFrame(f"link{row + 1}", joint_id, pinocchio.SE3.Identity(), int(model.nframes - 1))
        joint_ids.append(joint_id)
        sleep_while_cycling(0)  # in a live spawn's init, the RTPU's due cycles run between two joints
    parent = int(ee[0])
    model.addFrame(pinocchio.Frame(END_EFFECTOR_FRAME, joint_ids[parent] if parent >= 0 else 0,
                                   _se3(pinocchio, ee[1:4], ee[4:8]), pinocchio.FrameType.OP_FRAME))
    model.armature[:] = arm[:, Arm.ARMATURE]
    limited = arm[:, Arm.LIMITED] > 0
    model.lowerPositionLimit[:] = np.where(limited, arm[:, Arm.Q_MIN], -np.inf)
    model.upperPositionLimit[:] = np.where(limited, arm[:, Arm.Q_MAX], np.inf)
    model.effortLimit[:] = arm[:, Arm.EFFORT]
    model.velocityLimit[:] = np.where(arm[:, Arm.VELOCITY] > 0, arm[:, Arm.VELOCITY], np.inf)
    model.gravity = pinocchio.Motion(np.array(GRAVITY), np.zeros(3))
    return model


def _se3(pinocchio: Any, position: np.ndarray, quaternion: np.ndarray) -> Any:
    w, x, y, z = quaternion
    rotation = pinocchio.Quaternion(float(w), float(x), float(y), float(z)).normalized().toRotationMatrix()
    return pinocchio.SE3(rotation, position.copy())


def _joint_model(pinocchio: Any, kind: float, axis: np.ndarray) -> Any:
    """An axis-aligned joint where the axis is one (cheaper in every algorithm), else an unaligned one."""
    axis = axis / np.linalg.norm(axis)
    aligned = {(1.0, 0.0, 0.0): "X", (0.0, 1.0, 0.0): "Y", (0.0, 0.0, 1.0): "Z"}
    for direction, letter in aligned.items():
        if np.allclose(axis, direction, atol=1e-12):
            return getattr(pinocchio, f"JointModel{'R' if kind == Arm.HINGE else 'P'}{letter}")()
    if kind == Arm.HINGE:
        return pinocchio.JointModelRevoluteUnaligned(axis)
    return pinocchio.JointModelPrismaticUnaligned(axis)
