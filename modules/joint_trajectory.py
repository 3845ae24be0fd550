"""Joint trajectory generator (TR Figure 8): a smooth reference from where the arm is to q_d.

Each joint moves with bounded velocity and acceleration. Every cycle it steers towards the
largest speed from which steps of a·dt can still stop at the goal,
v (v + a·dt) / (2a) = |e|, i.e. v = sqrt((a·dt/2)² + 2a|e|) − a·dt/2 (the discrete-time
braking curve; the continuous sqrt(2a|e|) overshoots), capped by v_max. A joint lands exactly
on the goal only from a speed one acceleration step can stop, so the limits hold on every
cycle, arrival included.
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
        a, dt = params.max_acceleration, self.period
        self._v_max = params.max_velocity
        self._a_step = a * dt
        self._a_step_tolerance = a * dt * (1 + 1e-9)
        self._two_a = 2.0 * a
        self._half_step = 0.5 * a * dt
        self._half_step_squared = self._half_step**2
        self._snap = a * dt**2
        self._error = np.zeros(n)
        self._speed = np.zeros(n)
        self._change = np.zeros(n)
        self._slow = np.zeros(n, dtype=bool)
        self._near = np.zeros(n, dtype=bool)

    def on(self) -> None:
        self.q_r = self.q_m  # start from where the arm is, at rest
        self.qd_r = 0.0

    def cycle(self) -> Status:
        e, v, dv, q_r, qd_r, dt = self._error, self._speed, self._change, self.q_r, self.qd_r, self.period
        np.subtract(self.q_d, q_r, out=e)
        # the fastest speed from which steps of a·dt still stop at the goal, signed towards it
        np.abs(e, out=v)
        np.multiply(v, self._two_a, out=v)
        np.add(v, self._half_step_squared, out=v)
        np.sqrt(v, out=v)
        np.subtract(v, self._half_step, out=v)
        np.minimum(v, self._v_max, out=v)
        np.copysign(v, e, out=v)
        # may this joint land this cycle? only from a speed one acceleration step can stop
        np.abs(qd_r, out=dv)
        np.less_equal(dv, self._a_step_tolerance, out=self._slow)
        np.subtract(v, qd_r, out=dv)
        np.clip(dv, -self._a_step, self._a_step, out=dv)
        np.add(qd_r, dv, out=qd_r)
        np.multiply(qd_r, dt, out=dv)
        np.add(q_r, dv, out=q_r)
        np.subtract(self.q_d, q_r, out=e)
        np.abs(e, out=e)
        np.less_equal(e, self._snap, out=self._near)
        np.logical_and(self._slow, self._near, out=self._near)
        np.copyto(q_r, self.q_d, where=self._near)
        np.copyto(qd_r, 0.0, where=self._near)
        return Status.CONTINUE
