"""The arm's limits as the robot interface enforces them: saturation of every command, and divergence.

Every limit comes from the `ARM` table the arm's driver gives (the robot's description, tightened
by the plant options, never widened: docs/robots.md). Each cycle the robot interface clips the
command to them before the driver, so no value past a limit reaches the arm: a torque to the
joint's effort limit; a position to the joint's range, moving at most the velocity limit in a
period. It also watches for divergence: a torque command at its effort limit (in either direction)
for longer than `saturation_bound`, a measured velocity past its limit (where the robot gives one)
by more than `VELOCITY_TOLERANCE`, or a measured position past its range by more than
`position_tolerance`. The time at the limit is a leaky count: a cycle at it adds, a cycle within
drains `DRAIN_SLOWER` times slower, so a loop in a limit cycle (its torque swinging from one limit
to the other faster than the bound) is caught as surely as a torque held at one.
Divergence is a fault: the interface returns ERROR with a message naming the joint and the limit,
its `error` component engages the brakes, and the driver keeps the message for the run's summary
(a `fault:` line naming the task that wrote the command).

Every array is made here, once; the per-cycle checks are ufuncs into them (no allocation), called
with their output positional (an `out=` costs a call more than six joints' operation does), but for
`maximum` and `minimum`, which numpy takes it from only as `out=`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy import absolute, add, copyto, greater, greater_equal, isfinite, maximum, minimum, multiply, subtract

from modules._ufuncs import count_nonzero
from pbo_runtime import Arm

#: How long a command may stay at its limit before it is a fault, s (a module parameter).
SATURATION_BOUND = 0.05
#: How far past its range a measured position may be before it is a fault, rad (m for a slide
#: joint): the simulated joint limits are soft, and a joint driven against its stop goes a little past.
POSITION_TOLERANCE = 0.02
#: How far past its velocity limit a measured velocity may be before it is a fault, as a share of
#: the limit: a servo or a controller tracking a reference at the limit overshoots it a little.
VELOCITY_TOLERANCE = 0.1
#: A cycle whose command is within its limit takes this many times less off a joint's count than a
#: cycle at the limit adds: a command that keeps coming back to its limit fills the count however
#: briefly it leaves it, while one back within for good drains it.
DRAIN_SLOWER = 2


class ArmLimits:
    """Per-joint limit arrays of one arm, and the per-cycle saturation and divergence checks."""

    def __init__(self, arm: np.ndarray, period: float, saturation_bound: float, position_tolerance: float) -> None:
        n = arm.shape[0]
        self.ndof = n
        self.slide = arm[:, Arm.TYPE] == Arm.SLIDE
        self.effort = arm[:, Arm.EFFORT].copy()
        self.effort_low = -self.effort
        limited = arm[:, Arm.LIMITED] > 0
        self.q_min = np.where(limited, arm[:, Arm.Q_MIN], -np.inf)
        self.q_max = np.where(limited, arm[:, Arm.Q_MAX], np.inf)
        self.velocity = np.where(arm[:, Arm.VELOCITY] > 0, arm[:, Arm.VELOCITY], np.inf)
        self._velocity_fault = self.velocity * (1.0 + VELOCITY_TOLERANCE)
        self.position_tolerance = position_tolerance
        low, high = arm[:, Arm.Q_MIN], arm[:, Arm.Q_MAX]
        self._q_centre = np.where(limited, 0.5 * (low + high), 0.0)
        self._q_reach = np.where(limited, 0.5 * (high - low) + position_tolerance, np.inf)
        self.saturation_bound = saturation_bound
        # cycles a command may stay saturated: past this many in a row it is a fault
        self.saturated_cycles_allowed = max(1, math.ceil(saturation_bound / period - 1e-9))
        # each joint's leaky count, in cycles at the limit times DRAIN_SLOWER: a cycle at its limit adds
        # DRAIN_SLOWER, one within takes 1 off (never below 0); past the bound's worth it is a fault
        self.saturation_count = np.zeros(n, dtype=np.int64)
        self._count_bound = np.full(n, self.saturated_cycles_allowed * DRAIN_SLOWER, dtype=np.int64)
        self._rise = np.full(n, DRAIN_SLOWER + 1, dtype=np.int64)  # a cycle at the limit: +DRAIN_SLOWER after the drain of 1
        self._one = np.ones(n, dtype=np.int64)
        self._zero = np.zeros(n, dtype=np.int64)
        self._step = np.zeros(n, dtype=np.int64)
        self.at_limit = np.zeros(n, dtype=np.int64)  # cycles each joint's command was at its limit since every count was 0
        self._counting = False  # some joint's count is not 0
        self._since = 0.0  # when the counts left 0 (the run's time): what the message's "of the last" spans
        self._counted = np.zeros(n, dtype=np.int64)
        self._scratch = np.zeros(n)
        self._flags = np.zeros(n, dtype=bool)
        self._long = np.zeros(n, dtype=bool)
        self._q_step_high = np.zeros(n)
        # the measured state as one array: position from the range's centre, then velocity; and
        # how far from zero each may be (one comparison checks both)
        self._state = np.zeros(2 * n)
        self._state_bound = np.concatenate([self._q_reach, self._velocity_fault])
        self._state_flags = np.zeros(2 * n, dtype=bool)
        self._state_q, self._state_qd = self._state[:n], self._state[n:]  # views made once: a slice per cycle allocates

    # per cycle: no allocation --------------------------------------------------------------------

    def saturate_torque(self, tau: np.ndarray, out: np.ndarray, now: float = 0.0) -> bool:
        """`out` = `tau` clipped to the effort limits; each joint at or past its limit (either sign)
        adds to its count towards the saturation bound, one within drains it, slower. True when a
        joint is at its limit. `now` is the cycle's time, for the fault's message."""
        flags = self._flags
        absolute(tau, self._scratch)
        greater_equal(self._scratch, self.effort, flags)
        if not count_nonzero(flags):  # the usual cycle: nothing to clip (a NaN is left for the driver to refuse)
            out[...] = tau  # (an assignment: copyto's dispatch costs more than six joints' copy)
            if self._counting:
                self._drain()
            return False
        # not a command to clip: the driver refuses it as it is
        if count_nonzero(isfinite(tau, self._long)) != self.ndof:
            copyto(out, tau)
            return False
        maximum(tau, self.effort_low, out=out)  # np.clip's Python layers allocate
        minimum(out, self.effort, out=out)
        counted, count = self._counted, self.saturation_count
        copyto(counted, flags)  # as integers: a ufunc mixing bool and int64 allocates a cast buffer
        multiply(counted, self._rise, self._step)
        add(count, self._step, count)
        subtract(count, self._one, count)
        maximum(count, self._zero, out=count)
        add(self.at_limit, counted, self.at_limit)
        if not self._counting:
            self._counting = True
            self._since = now
        return True

    def _drain(self) -> None:
        """A cycle with every command within its limit: each count drains by one; at 0 they start afresh."""
        count = self.saturation_count
        subtract(count, self._one, count)
        maximum(count, self._zero, out=count)
        if not count_nonzero(count):
            self.at_limit.fill(0)
            self._counting = False

    def limit_position(self, q_r: np.ndarray, previous: np.ndarray, step: np.ndarray, out: np.ndarray) -> None:
        """`out` = `q_r` within `step` of `previous` (the velocity limit over a period) and within the
        range; `q_r` as it is when it is not finite, for the driver to refuse."""
        if count_nonzero(isfinite(q_r, self._flags)) != self.ndof:
            copyto(out, q_r)
            return
        low, high = self._scratch, self._q_step_high
        subtract(previous, step, low)
        add(previous, step, high)
        maximum(q_r, low, out=out)
        minimum(out, high, out=out)
        maximum(out, self.q_min, out=out)
        minimum(out, self.q_max, out=out)

    def saturated_too_long(self) -> bool:
        """Whether a joint's count has passed the bound (after `saturate_torque`)."""
        return bool(count_nonzero(greater(self.saturation_count, self._count_bound, self._long)))

    def outside(self, q: np.ndarray, qd: np.ndarray) -> bool:
        """Whether a measured velocity is past its limit or a position past its range and the tolerance."""
        state = self._state
        subtract(q, self._q_centre, self._state_q)
        self._state_qd[...] = qd
        absolute(state, state)
        return bool(count_nonzero(greater(state, self._state_bound, self._state_flags)))

    def allow_from(self, q: np.ndarray) -> None:
        """At `on`: a joint already past its range (braked there after a fault) may be driven back,
        not further out: its bound is where it is now, until the next `on`."""
        n = self.ndof
        self._state_bound[:n] = np.maximum(self._q_reach, np.abs(q - self._q_centre))

    def reset(self) -> None:
        """No command is being saturated (on, a hold): the bound counts afresh."""
        self.saturation_count.fill(0)
        self.at_limit.fill(0)
        self._counting = False

    # once, at a fault: what is wrong, in words --------------------------------------------------------

    def units(self, joint: int) -> tuple[str, str, str]:
        """(force, position, velocity) units of `joint`."""
        return ("N", "m", "m/s") if self.slide[joint] else ("N m", "rad", "rad/s")

    def saturation_message(self, tau: np.ndarray, port: str, period: float, now: float = 0.0) -> str:
        """The fault of the joint whose count is highest: its limit, how long at it, what was asked."""
        joint = int(np.argmax(self.saturation_count))
        unit = self.units(joint)[0]
        held = int(self.at_limit[joint]) * period
        span = max(now - self._since + period, held)
        bound, limit = f"the saturation bound of {self.saturation_bound * 1e3:.0f} ms", f"{self.effort[joint]:.4g} {unit}"
        if held >= span - 0.5 * period:  # at the limit every cycle
            return (f"joint {joint + 1}: the torque command '{port}' stayed at its effort limit of {limit} for "
                    f"{held * 1e3:.0f} ms, past {bound} (it asked {tau[joint]:.4g} {unit}); the arm is braked")
        return (f"joint {joint + 1}: the torque command '{port}' kept coming back to its effort limit of ±{limit}: at it "
                f"{held * 1e3:.0f} ms of the last {span * 1e3:.0f} ms, past {bound} (a limit cycle: is the loop within "
                f"its stability bound? pbo check says; it asked {tau[joint]:.4g} {unit}); the arm is braked")

    def divergence_message(self, q: np.ndarray, qd: np.ndarray) -> str:
        """The fault of the first joint past a velocity limit, else past its range."""
        for joint in range(self.ndof):
            _, position, velocity = self.units(joint)
            if abs(qd[joint]) > self._velocity_fault[joint]:
                return (f"joint {joint + 1}: measured velocity {qd[joint]:.4g} {velocity} is past its limit of "
                        f"{self.velocity[joint]:.4g} {velocity} (tolerance {VELOCITY_TOLERANCE:.0%}); the arm is braked")
        for joint in range(self.ndof):
            _, position, _ = self.units(joint)
            if abs(q[joint] - self._q_centre[joint]) > self._q_reach[joint]:
                return (f"joint {joint + 1}: measured position {q[joint]:.4g} {position} is past its range "
                        f"[{self.q_min[joint]:.4g}, {self.q_max[joint]:.4g}] {position} (tolerance "
                        f"{self.position_tolerance:g}); the arm is braked")
        return "the arm left its limits; the arm is braked"
