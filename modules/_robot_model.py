"""What the model-based modules compute with the arm's Pinocchio model (built by `pbo_runtime.arm_model`).

Control modules read the `ARM` and `EE` constants (from the arm driver, through state variables)
and build their model with `pbo_runtime.arm_model`, so they compute with the same arm the plant
simulates without importing `drivers`. Its q is the plant's joint vector; its frames are
`joint<i>`, `link<i>` and the end effector `ee`.
"""

from __future__ import annotations

import numpy as np
import pinocchio

#: Name of the operational frame at the end effector.
END_EFFECTOR_FRAME = "ee"


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
