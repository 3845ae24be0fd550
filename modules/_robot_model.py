"""The controllers' rigid-body model of the arm, built with Pinocchio from the plant's DH and DYN.

Control modules read the `DH` and `DYN` constants (from the arm driver, through state variables)
and build their model here, so they compute with the same arm the plant simulates without
importing `drivers`. Conventions (as `drivers.robots.description`): standard DH rows
(theta_offset, d, a, alpha), T_i = Rz(q_i+theta_offset) Tz(d) Tx(a) Rx(alpha); DYN rows
(mass, cx, cy, cz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz, armature) with COM and inertia about the COM in
DH link frame i. Joint i's frame is DH frame i-1 turned by Rz(q_i+theta_offset_i), so Pinocchio's
q equals the DH joint vector.
"""

from __future__ import annotations

import numpy as np
import pinocchio

#: Name of the operational frame at the last DH frame (frame n).
END_EFFECTOR_FRAME = "ee"


def _link_transform(dh_row: np.ndarray) -> np.ndarray:
    """Tz(d) Tx(a) Rx(alpha): DH frame i seen from the joint-i frame."""
    _, d, a, alpha = dh_row
    ca, sa = np.cos(alpha), np.sin(alpha)
    return np.array([[1.0, 0.0, 0.0, a], [0.0, ca, -sa, 0.0], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def _se3(transform: np.ndarray) -> pinocchio.SE3:
    return pinocchio.SE3(transform[:3, :3].copy(), transform[:3, 3].copy())


def _check_shapes(dh: np.ndarray, dyn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    dh = np.asarray(dh, dtype=np.float64)
    dyn = np.asarray(dyn, dtype=np.float64)
    if dh.ndim != 2 or dh.shape[1] != 4:
        raise ValueError(f"dh must have shape (n, 4), got: {dh.shape}")
    if dyn.shape != (dh.shape[0], 11):
        raise ValueError(f"dyn must have shape ({dh.shape[0]}, 11) to match dh, got: {dyn.shape}")
    return dh, dyn


def pinocchio_model(dh: np.ndarray, dyn: np.ndarray) -> pinocchio.Model:
    """A chain of revolute-Z joints `joint<i>`, armature in `model.armature`, gravity -9.81 z.

    Made at `init`, never in `cycle`: building the model allocates.
    """
    dh, dyn = _check_shapes(dh, dyn)
    model = pinocchio.Model()
    model.name = "dh_arm"
    parent = 0
    parent_link = np.eye(4)  # the base frame is DH frame 0
    for i, (dh_row, dyn_row) in enumerate(zip(dh, dyn), start=1):
        placement = parent_link @ _rot_z(dh_row[0])
        joint = model.addJoint(parent, pinocchio.JointModelRZ(), _se3(placement), f"joint{i}")
        link = _link_transform(dh_row)
        rotation, offset = link[:3, :3], link[:3, 3]
        mass, cx, cy, cz, ixx, iyy, izz, ixy, ixz, iyz, _ = dyn_row
        inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        model.appendBodyToJoint(
            joint,
            pinocchio.Inertia(mass, rotation @ np.array([cx, cy, cz]) + offset, rotation @ inertia @ rotation.T),
            pinocchio.SE3.Identity(),
        )
        model.addBodyFrame(f"link{i}", joint, pinocchio.SE3.Identity(), int(model.nframes - 1))
        parent, parent_link = joint, link
    model.addFrame(
        pinocchio.Frame(END_EFFECTOR_FRAME, parent, _se3(parent_link), pinocchio.FrameType.OP_FRAME)
    )
    model.armature[:] = dyn[:, 10]
    model.gravity = pinocchio.Motion(np.array([0.0, 0.0, -9.81]), np.zeros(3))
    return model


def forward_kinematics_dh(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The 4x4 pose of DH frame n in the base frame: the plain product of the DH transforms."""
    dh = np.asarray(dh, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (dh.shape[0],):
        raise ValueError(f"q must have shape ({dh.shape[0]},) to match dh, got: {q.shape}")
    pose = np.eye(4)
    for dh_row, qi in zip(dh, q):
        pose = pose @ _rot_z(qi + dh_row[0]) @ _link_transform(dh_row)
    return pose


# --- helpers for the Cartesian modules (fk_jacobian, resolved_rate, damped_least_squares) -------
# Pose vectors x are (6,): position xyz in the base frame, then the orientation as a rotation
# vector (axis * angle, `pinocchio.log3` of the rotation matrix). Jacobians are (6, n) in
# LOCAL_WORLD_ALIGNED: the frame's linear velocity (rows 0-2) and angular velocity (rows 3-5),
# both expressed in the base frame. Pinocchio's bindings allocate small result objects, so
# these helpers are cheap but not allocation-free.


def frame_id(model: pinocchio.Model, frame: str) -> int:
    """The index of the operational frame `frame`, or ValueError naming the frames there are."""
    if not model.existFrame(frame):
        names = ", ".join(f.name for f in model.frames if f.name != "universe")
        raise ValueError(f"frame must be one of the model's frames ({names}), got: {frame!r}")
    return int(model.getFrameId(frame))


def frame_pose_and_jacobian(
    model: pinocchio.Model, data: pinocchio.Data, frame: int, q: np.ndarray, x_out: np.ndarray, jacobian_out: np.ndarray
) -> None:
    """Write the pose vector of `frame` at `q` into x_out (6,) and its Jacobian into jacobian_out (6, n)."""
    pinocchio.computeJointJacobians(model, data, q)  # also does the forward kinematics
    placement = pinocchio.updateFramePlacement(model, data, frame)
    x_out[:3] = placement.translation
    x_out[3:] = pinocchio.log3(placement.rotation)
    jacobian_out[:] = pinocchio.getFrameJacobian(model, data, frame, pinocchio.LOCAL_WORLD_ALIGNED)


def pose_error(x_d: np.ndarray, x_m: np.ndarray, out: np.ndarray) -> np.ndarray:
    """The error that takes pose x_m to x_d, in the base frame: p_d - p_m, then log3(R_d R_m^T).

    Commanding the frame's LOCAL_WORLD_ALIGNED twist K * error turns R_m about the error's axis
    straight towards R_d (the geodesic), whatever the angle.
    """
    np.subtract(x_d[:3], x_m[:3], out=out[:3])
    out[3:] = pinocchio.log3(pinocchio.exp3(x_d[3:]) @ pinocchio.exp3(x_m[3:]).T)
    return out


def rnea_includes_armature(model: pinocchio.Model) -> bool:
    """Whether this Pinocchio's `rnea` adds `model.armature * a` (4.x does; some older ones do not).

    Probed once, at init: the torque for a unit acceleration with the armature set and zeroed.
    """
    if not np.any(model.armature):
        return True  # nothing to add either way
    probe = pinocchio.Model(model)
    q, v, a = pinocchio.neutral(model), np.zeros(model.nv), np.ones(model.nv)
    with_armature = pinocchio.rnea(model, model.createData(), q, v, a).copy()
    probe.armature[:] = 0.0
    without = pinocchio.rnea(probe, probe.createData(), q, v, a).copy()
    return bool(np.allclose(with_armature - without, model.armature, rtol=1e-9, atol=1e-12))


def limit_speed(qd: np.ndarray, max_speed: float, scratch: np.ndarray) -> None:
    """Scale qd in place so no joint exceeds max_speed, keeping its direction (and so the
    direction of the Cartesian motion it makes). `scratch` is a buffer of qd's shape."""
    np.abs(qd, out=scratch)
    peak = scratch.max()
    if peak > max_speed:
        np.multiply(qd, max_speed / peak, out=qd)
