"""Joint trajectory generator (TR Figure 8): a smooth reference from where the arm is to q_d.

Each joint moves with bounded velocity and acceleration: it accelerates towards the largest
speed from which it can still stop at the goal, v = sign(e) * min(v_max, sqrt(2 a_max |e|)),
and the reference snaps onto the goal once it is within one step of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pbo_runtime import InVar, OutVar, PortBasedObject, Status


@dataclass(frozen=True)
class JointTrajectoryParams:
    max_velocity: float = 1.0  # rad/s, every joint
    max_acceleration: float = 4.0  # rad/s^2, every joint

    def __post_init__(self) -> None:
        if self.max_velocity <= 0 or self.max_acceleration <= 0:
            raise ValueError(
                f"max_velocity and max_acceleration must be > 0, got: {self.max_velocity}, {self.max_acceleration}"
            )


class JointTrajectory(PortBasedObject):
    """Velocity- and acceleration-limited joint reference generator. Real-time safe cycle."""

    Params = JointTrajectoryParams

    q_d = InVar("q_d", shape=("NDOF",), doc="desired joint position (the goal), rad")
    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad: where the reference starts")
    q_r = OutVar("q_r", shape=("NDOF",), doc="reference joint position this cycle, rad")
    qd_r = OutVar("qd_r", shape=("NDOF",), doc="reference joint velocity this cycle, rad/s")

    def init(self, params: JointTrajectoryParams) -> None:
        n = self.q_r.shape[0]
        self._v_max = params.max_velocity
        self._a_step = params.max_acceleration * self.period
        self._two_a = 2.0 * params.max_acceleration
        self._error = np.zeros(n)
        self._speed = np.zeros(n)
        self._change = np.zeros(n)
        self._arrived = np.zeros(n, dtype=bool)
        self._snap = 0.5 * params.max_acceleration * self.period**2

    def on(self) -> None:
        self.q_r = self.q_m  # start from where the arm is, at rest
        self.qd_r = 0.0

    def cycle(self) -> Status:
        e, v, dv, q_r, qd_r, dt = self._error, self._speed, self._change, self.q_r, self.qd_r, self.period
        np.subtract(self.q_d, q_r, out=e)
        # the fastest speed that can still stop at the goal, capped by v_max, signed towards it
        np.abs(e, out=v)
        np.multiply(v, self._two_a, out=v)
        np.sqrt(v, out=v)
        np.minimum(v, self._v_max, out=v)
        np.copysign(v, e, out=v)
        np.subtract(v, qd_r, out=dv)
        np.clip(dv, -self._a_step, self._a_step, out=dv)
        np.add(qd_r, dv, out=qd_r)
        np.multiply(qd_r, dt, out=dv)
        np.add(q_r, dv, out=q_r)
        # on the goal: stop exactly there instead of dithering around it
        np.abs(e, out=v)
        np.less_equal(v, self._snap + abs(self._a_step) * dt, out=self._arrived)
        np.copyto(q_r, self.q_d, where=self._arrived)
        np.copyto(qd_r, 0.0, where=self._arrived)
        return Status.CONTINUE
