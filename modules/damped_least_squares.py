"""Damped least squares inverse kinematics (TR Figure 13; Wampler, Nakamura and Hanafusa).

The drop-in replacement for resolved_rate (Figure 12) when the arm may pass near a singularity:
same ports, and every cycle, from q_m and the desired pose x_d,

    e    = (p_d - p_m, log3(R_d R_m^T))                   the pose error in the base frame
    qd_r = J^T (J J^T + lambda^2 I)^-1 (gain * e)

with lambda^2 = damping^2 + variable damping, the variable part (Nakamura and Hanafusa)

    lambda_v^2 = max_damping^2 (1 - (w / manipulability_threshold)^2)   if w < threshold, else 0
    w = sqrt(det(J J^T))                                                 Yoshikawa's manipulability

so far from singularities (w >= threshold, damping = 0) it is exact resolved rate, and near one
it trades accuracy along the lost direction for bounded joint speeds: with lambda > 0,
|qd_r| <= gain |e| / (2 lambda) whatever J is. qd_r is then scaled down as a whole so no joint
exceeds max_joint_speed. For an arm with fewer than 6 joints J J^T is singular, w = 0, and the
full damping always applies.

Poses are (6,): position m, then a rotation vector rad (axis * angle). The module computes the
kinematics itself from the model built once in `init` from the out-consts ARM and EE. Real-time
notes: the cycle allocates no arrays of its own, but `numpy.linalg.det` and `numpy.linalg.solve`
(6 x 6) and the Pinocchio calls allocate inside the library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modules._robot_model import END_EFFECTOR_FRAME
from modules.resolved_rate import ResolvedRate
from pbo_runtime import param


@dataclass(frozen=True)
class DampedLeastSquaresParams:
    gain: float = param(5.0, above=0, at_most=1e4)  # 1/s: the pose error's decay rate away from singularities
    damping: float = param(0.0, at_least=0, at_most=10)  # lambda applied everywhere (units of J: m and rad)
    max_damping: float = param(0.05, at_least=0, at_most=10)  # lambda_max of the variable damping, reached at w = 0
    manipulability_threshold: float = param(0.01, at_least=0, at_most=10)  # w0: below it the variable damping grows
    max_joint_speed: float = param(2.0, above=0, at_most=math.inf)  # rad/s: no joint of qd_r exceeds this
    frame: str = END_EFFECTOR_FRAME  # the operational frame whose pose x_d gives

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain) and self.gain > 0):
            raise ValueError(f"gain must be a finite number > 0, got: {self.gain}")
        for name in ("damping", "max_damping", "manipulability_threshold"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got: {value}")
        if (self.max_damping > 0) != (self.manipulability_threshold > 0):
            raise ValueError(
                "max_damping and manipulability_threshold must both be > 0 (variable damping) or both 0, "
                f"got: {self.max_damping}, {self.manipulability_threshold}"
            )
        if self.damping == 0 and self.max_damping == 0:
            raise ValueError("damping or max_damping must be > 0, or J J^T is singular at a singularity")
        if not self.max_joint_speed > 0:
            raise ValueError(f"max_joint_speed must be > 0, got: {self.max_joint_speed}")
        if not self.frame:
            raise ValueError("frame must name a frame of the arm, got: ''")


class DampedLeastSquares(ResolvedRate):
    """qd_r = J^T (J J^T + lambda^2 I)^-1 gain (x_d - x_m), bounded near singularities.

    Same ports and pose error as resolved_rate (Figures 12 and 13 differ only in this solve).
    """

    Params = DampedLeastSquaresParams  # type: ignore[assignment]

    def init(self, params: DampedLeastSquaresParams) -> None:  # type: ignore[override]
        super().init(params)  # type: ignore[arg-type]
        self._damping_squared = params.damping**2
        self._max_damping_squared = params.max_damping**2
        self._threshold = params.manipulability_threshold
        self._solution = np.zeros(6)
        self._gram = np.zeros((6, 6))  # J J^T, then J J^T + lambda^2 I
        self._diagonal = self._gram.reshape(-1)[::7]  # a view of its diagonal
        self.damping_squared = 0.0  # lambda^2 of the last cycle (for logs and tests)
        self.manipulability = 0.0  # w of the last cycle

    def damping_for(self, manipulability: float) -> float:
        """lambda^2 at manipulability w: the fixed part plus the variable part."""
        lam2 = self._damping_squared
        if manipulability < self._threshold:
            lam2 += self._max_damping_squared * (1.0 - (manipulability / self._threshold) ** 2)
        return lam2

    def _solve(self, velocity: np.ndarray) -> None:
        gram, jacobian = self._gram, self._jacobian
        np.matmul(jacobian, jacobian.T, out=gram)
        self.manipulability = w = math.sqrt(max(float(np.linalg.det(gram)), 0.0))
        self.damping_squared = lam2 = self.damping_for(w)
        np.add(self._diagonal, lam2, out=self._diagonal)
        np.copyto(self._solution, np.linalg.solve(gram, velocity))
        np.matmul(jacobian.T, self._solution, out=self.qd_r)
