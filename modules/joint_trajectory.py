"""Joint trajectory generator (TR Figure 8): a smooth reference from where the arm is to q_d.

Each joint moves with bounded velocity and acceleration. Every cycle it steers towards the
largest speed from which steps of a·dt can still stop at the goal,
v (v + a·dt) / (2a) = |e|, i.e. v = sqrt((a·dt/2)² + 2a|e|) - a·dt/2 (the discrete-time
braking curve; the continuous sqrt(2a|e|) overshoots), capped by v_max. A joint lands exactly
on the goal only from a speed one acceleration step can stop, so the limits hold on every
cycle, arrival included.

On `on` it goes on from the reference in the table when that reference drives the arm now
(written within TAKE_OVER_WITHIN_PERIODS of its periods, the actuators not held: a switch
mid-move, a restart that took no time on the simulated clock), so the path goes on as planned.
Otherwise it starts from the arm's measured position and velocity (a restart on the real clock,
where the robot interface held the arm on its brakes meanwhile), and from a moving arm brakes
along the curve instead of commanding a stop. From a speed above max_velocity it slows at
max_acceleration.

While the actuators are held (`actuators_held`: the plant stopped, the controller's torque
stale, the table lock held) the reference holds still where it is, instead of running on to the
goal without the arm; once they are not, it starts again from the measured state, as on `on`.
"""

from __future__ import annotations

from dataclasses import dataclass

from modules._braking import BrakingLaw
from pbo_runtime import InVar, OutVar, PortBasedObject, Status, param

TAKE_OVER_WITHIN_PERIODS = 2.0  # a reference written longer ago than this no longer drives the arm


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
        self._ports = self.q_d, self.q_r, self.qd_r  # the ports' arrays, the task's for its life: no port lookup per cycle

    def on(self) -> None:
        self._held = False
        age = self.time - self.written_at("q_r")
        if self.actuators_held or age > TAKE_OVER_WITHIN_PERIODS * self.period:
            self._start_from_measured()
        # else: q_r and qd_r, read from the table before `on`, go on where they are

    def _start_from_measured(self) -> None:
        self.q_r = self.q_m  # start from where the arm is, as fast as it goes
        self.qd_r = self.qd_m

    def cycle(self) -> Status:
        if self.actuators_held:
            if not self._held:
                self._held = True
                self.qd_r[:] = 0.0  # the reference stands still with the arm
            return Status.CONTINUE
        if self._held:
            self._held = False
            self._start_from_measured()
        self._law.step(*self._ports)
        return Status.CONTINUE
