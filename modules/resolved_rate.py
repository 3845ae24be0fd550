"""Resolved-rate inverse kinematics (TR Figure 12, "inverse kinematics"; Whitney's resolved rate).

Every cycle, from the measured joint position q_m and the desired pose x_d:

    e    = (p_d - p_m, log3(R_d R_m^T))     the pose error in the base frame
    qd_r = J^+ (gain * e)                   J^+ the Moore-Penrose pseudo-inverse of J(q_m)

then qd_r is scaled down as a whole (its direction kept) so no joint exceeds max_joint_speed.
Integrated (by the time integrator or a velocity-mode robot) the error decays as exp(-gain t)
away from singularities. Near one, J^+ amplifies the error along the lost direction by
1/sigma_min: the joint speeds blow up and only the max_joint_speed cap holds them; the damped
least squares module (Figure 13) is the reconfigurable alternative that stays bounded.

Poses are (6,): position m, then a rotation vector rad (axis * angle), as fk_jacobian publishes.
The module computes the kinematics itself from the model built once in `init` from the robot
interface's out-consts ARM and EE. Real-time notes: the cycle allocates no arrays of its own,
but `numpy.linalg.pinv` (an SVD) and the Pinocchio calls allocate inside the library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modules._model_based import ModelBased
from modules._robot_model import (
    END_EFFECTOR_FRAME,
    frame_id,
    frame_pose_and_jacobian,
    limit_speed,
    pose_error,
)
from pbo_runtime import InVar, OutVar, Status, param


@dataclass(frozen=True)
class ResolvedRateParams:
    gain: float = param(5.0, above=0, at_most=1e4)  # 1/s: the pose error's decay rate
    max_joint_speed: float = param(2.0, above=0, at_most=math.inf)  # rad/s: no joint of qd_r exceeds this
    frame: str = END_EFFECTOR_FRAME  # the operational frame whose pose x_d gives

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain) and self.gain > 0):
            raise ValueError(f"gain must be a finite number > 0, got: {self.gain}")
        if not self.max_joint_speed > 0:
            raise ValueError(f"max_joint_speed must be > 0, got: {self.max_joint_speed}")
        if not self.frame:
            raise ValueError("frame must name a frame of the arm, got: ''")


class ResolvedRate(ModelBased):
    """qd_r = J^+ gain (x_d - x_m), speed-limited. Not for use near singularities (see DLS)."""

    Params = ResolvedRateParams

    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    x_d = InVar("x_d", shape=(6,), doc="desired pose: position m, then rotation vector rad, base frame")
    qd_r = OutVar("qd_r", shape=("NDOF",), doc="reference joint velocity, rad/s")

    def init(self, params: ResolvedRateParams) -> None:
        n = int(self.ndof)
        self.build_model()
        self._frame = frame_id(self._model, params.frame)
        self._gain, self._max_speed = params.gain, params.max_joint_speed
        self._x = np.zeros(6)
        self._error = np.zeros(6)
        self._jacobian = np.zeros((6, n))
        self._pinv = np.zeros((n, 6))
        self._scratch = np.zeros(n)

    def on(self) -> None:
        # At rest until the first cycle, which runs at the same boundary: an SVD here would only
        # lengthen the switch that turns this task on, before any cycle of the boundary runs.
        self.qd_r[:] = 0.0

    def cycle(self) -> Status:
        self._compute()
        return Status.CONTINUE

    def _compute(self) -> None:
        """The pose error, scaled by the gain, through the inverse kinematics of `_solve`."""
        frame_pose_and_jacobian(self._model, self._data, self._frame, self.q_m, self._x, self._jacobian)
        e = pose_error(self.x_d, self._x, self._error)
        np.multiply(e, self._gain, out=e)
        self._solve(e)
        limit_speed(self.qd_r, self._max_speed, self._scratch)

    def _solve(self, velocity: np.ndarray) -> None:
        """qd_r for a Cartesian velocity: the pseudo-inverse (unbounded near a singularity)."""
        np.copyto(self._pinv, np.linalg.pinv(self._jacobian))
        np.matmul(self._pinv, velocity, out=self.qd_r)
