"""Cartesian trajectory generator (TR Figure 7; the Cartesian interpolator of Figures 10 and 12).

A smooth Cartesian reference x_r from where the arm is (x_m, when turned on) to the desired pose
x_d. Each of the six components moves independently with bounded velocity and acceleration,
by the same discrete-time braking law as joint_trajectory: every cycle it steers towards the
largest speed from which steps of a·dt can still stop at the goal,
v = sqrt((a·dt/2)² + 2a|e|) - a·dt/2, capped by v_max, and it lands exactly on the goal only
from a speed one acceleration step can stop, so the limits hold on every cycle. The position
components (m) use the linear limits, the rotation-vector components (rad) the angular ones.

Poses are (6,): position m, then a rotation vector rad (axis * angle). The orientation part is
interpolated along the straight line between rotation vectors, which is not the geodesic
between the two orientations (close to it for small moves) and does not unwrap at an angle of
pi: keep goals within pi rad of the start, as a fresh `log3` gives. The reference velocity is
internal state (restarting at rest on every `on`).

Real-time safe cycle: no allocation, no library calls that allocate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modules._braking import BrakingLaw
from pbo_runtime import InVar, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class CartesianTrajectoryParams:
    max_linear_velocity: float = param(0.25, above=0, at_most=100)  # m/s, each of x, y, z
    max_linear_acceleration: float = param(1.0, above=0, at_most=1e4)  # m/s^2, each of x, y, z
    max_angular_velocity: float = param(1.0, above=0, at_most=100)  # rad/s, each rotation-vector component
    max_angular_acceleration: float = param(4.0, above=0, at_most=1e4)  # rad/s^2, each rotation-vector component

    def __post_init__(self) -> None:
        for name in ("max_linear_velocity", "max_linear_acceleration", "max_angular_velocity", "max_angular_acceleration"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got: {value}")


class CartesianTrajectory(PortBasedObject):
    """Velocity- and acceleration-limited Cartesian reference generator. Real-time safe cycle."""

    Params = CartesianTrajectoryParams

    x_d = InVar("x_d", shape=(6,), doc="desired pose (the goal): position m, then rotation vector rad")
    x_m = InVar("x_m", shape=(6,), doc="measured pose: where the reference starts")
    x_r = OutVar("x_r", shape=(6,), doc="reference pose this cycle: position m, then rotation vector rad")

    def init(self, params: CartesianTrajectoryParams) -> None:
        a = np.array([params.max_linear_acceleration] * 3 + [params.max_angular_acceleration] * 3)
        v_max = np.array([params.max_linear_velocity] * 3 + [params.max_angular_velocity] * 3)
        self._law = BrakingLaw(6, v_max, a, self.period)
        self._velocity = np.zeros(6)  # the reference's velocity, m/s and rad/s

    @property
    def velocity(self) -> np.ndarray:
        """The reference velocity of the last cycle (a copy)."""
        return self._velocity.copy()

    def on(self) -> None:
        self.x_r = self.x_m  # start from where the arm is, at rest
        self._velocity[:] = 0.0

    def cycle(self) -> Status:
        self._law.step(self.x_d, self.x_r, self._velocity)
        return Status.CONTINUE
