"""Joint trajectory generator (TR Figure 8): a smooth reference from where the arm is to q_d.

Each joint moves with bounded velocity and acceleration. Every cycle it steers towards the
largest speed from which steps of a·dt can still stop at the goal,
v (v + a·dt) / (2a) = |e|, i.e. v = sqrt((a·dt/2)² + 2a|e|) − a·dt/2 (the discrete-time
braking curve; the continuous sqrt(2a|e|) overshoots), capped by v_max. A joint lands exactly
on the goal only from a speed one acceleration step can stop, so the limits hold on every
cycle, arrival included.

It starts from the arm's measured position and velocity, so a trajectory that takes over a moving
arm (a restarted RTPU, a switch mid-move) brakes it along the curve instead of commanding a stop.
From a speed above max_velocity it slows at max_acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass

from modules._braking import BrakingLaw
from pbo_runtime import InVar, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class JointTrajectoryParams:
    max_velocity: float = param(1.0, above=0, at_most=100)  # rad/s, every joint
    max_acceleration: float = param(4.0, above=0, at_most=1e4)  # rad/s^2, every joint

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
    qd_m = InVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s: the reference's first velocity")
    q_r = OutVar("q_r", shape=("NDOF",), doc="reference joint position this cycle, rad")
    qd_r = OutVar("qd_r", shape=("NDOF",), doc="reference joint velocity this cycle, rad/s")

    def init(self, params: JointTrajectoryParams) -> None:
        self._law = BrakingLaw(self.q_r.shape[0], params.max_velocity, params.max_acceleration, self.period)

    def on(self) -> None:
        self.q_r = self.q_m  # start from where the arm is, as fast as it goes
        self.qd_r = self.qd_m

    def cycle(self) -> Status:
        self._law.step(self.q_d, self.q_r, self.qd_r)
        return Status.CONTINUE
