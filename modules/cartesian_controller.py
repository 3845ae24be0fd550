"""Cartesian controller (TR Figure 7; the controller of the Cartesian teleoperation, Figure 10).

A PD law on the pose error gives the Cartesian command, and the Jacobian maps it to the joints,
for the inverse dynamics module to turn into torques (resolved acceleration control, Luh, Walker
and Paul):

    e      = (p_r - p_m, log3(R_r R_m^T))             the pose error in the base frame
    xd_m   = J qd_m                                   the measured Cartesian velocity
    xdd_u  = kp e + kd (xd_r - xd_m)                  the Cartesian command (m/s^2, rad/s^2): the
                                                      force per unit mass of the operational space
    qdd_r  = J^T (J J^T + damping^2 I)^-1 xdd_u       its joint acceleration (damped, so bounded
                                                      near a singularity), scaled down as a whole
                                                      to at most max_joint_acceleration

With inverse dynamics after it, the hand's error obeys e'' + kd e' + kp e = 0 (critically damped
at kd = 2 sqrt(kp)) away from singularities, up to the J' qd term this module leaves to the
feedback (small at teleoperation speeds). The reference velocity xd_r is the interpolator's; its
rotation part is the rotation vector's rate, taken as the angular velocity (exact for rotations
about a fixed axis, close for the small steps of a teleoperated reference).

The module takes x_m and J from the forward kinematics and Jacobian module, as the figure draws
it, so it builds no model of its own. Real-time notes: the cycle allocates no arrays of its own,
but `pinocchio.log3`/`exp3` (in the pose error) and `numpy.linalg.solve` (6 x 6) allocate small
results inside the libraries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modules._robot_model import limit_speed, pose_error
from pbo_runtime import InVar, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class CartesianControllerParams:
    kp: float = param(100.0, at_least=0, at_most=1e6)  # 1/s^2: stiffness of the hand's error dynamics
    kd: float = param(20.0, at_least=0, at_most=1e4)  # 1/s: damping (2 sqrt(kp): critically damped)
    damping: float = param(0.01, above=0, at_most=10)  # lambda of the Jacobian's damped inverse (m and rad)
    max_joint_acceleration: float = param(math.inf, above=0, at_most=math.inf)  # rad/s^2: no joint of qdd_r exceeds this

    def __post_init__(self) -> None:
        for name in ("kp", "kd"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got: {value}")
        if not (math.isfinite(self.damping) and self.damping > 0):
            raise ValueError(f"damping must be a finite number > 0, got: {self.damping}")
        if not self.max_joint_acceleration > 0:
            raise ValueError(f"max_joint_acceleration must be > 0, got: {self.max_joint_acceleration}")


class CartesianController(PortBasedObject):
    """xdd_u = kp e + kd (xd_r - J qd_m); qdd_r its damped-inverse joint acceleration."""

    Params = CartesianControllerParams

    x_r = InVar("x_r", shape=(6,), doc="reference pose: position m, then rotation vector rad")
    xd_r = InVar("xd_r", shape=(6,), doc="reference velocity: m/s, then rad/s")
    x_m = InVar("x_m", shape=(6,), doc="measured pose: position m, then rotation vector rad")
    jacobian = InVar("J", shape=(6, "NDOF"), doc="hand Jacobian, linear rows first (base frame)")
    qd_m = InVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s")
    xdd_u = OutVar("xdd_u", shape=(6,), doc="Cartesian command: acceleration m/s^2, then rad/s^2")
    qdd_r = OutVar("qdd_r", shape=("NDOF",), doc="reference joint acceleration, rad/s^2")

    def init(self, params: CartesianControllerParams) -> None:
        n = self.qd_m.shape[0]
        self._kp, self._kd = params.kp, params.kd
        self._damping_squared = params.damping**2
        self._max_acceleration = params.max_joint_acceleration
        self._error = np.zeros(6)
        self._velocity = np.zeros(6)
        self._gram = np.zeros((6, 6))
        self._diagonal = self._gram.reshape(-1)[::7]  # a view of its diagonal
        self._solution = np.zeros(6)
        self._scratch = np.zeros(n)

    def on(self) -> None:
        self._compute()

    def cycle(self) -> Status:
        self._compute()
        return Status.CONTINUE

    def _compute(self) -> None:
        jacobian, command, velocity = self.jacobian, self.xdd_u, self._velocity
        pose_error(self.x_r, self.x_m, self._error)
        np.matmul(jacobian, self.qd_m, out=velocity)
        np.subtract(self.xd_r, velocity, out=velocity)
        np.multiply(velocity, self._kd, out=velocity)
        np.multiply(self._error, self._kp, out=command)
        np.add(command, velocity, out=command)
        np.matmul(jacobian, jacobian.T, out=self._gram)
        np.add(self._diagonal, self._damping_squared, out=self._diagonal)
        np.copyto(self._solution, np.linalg.solve(self._gram, command))
        np.matmul(jacobian.T, self._solution, out=self.qdd_r)
        if self._max_acceleration < math.inf:
            limit_speed(self.qdd_r, self._max_acceleration, self._scratch)
