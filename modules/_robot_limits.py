"""The arm's limits as the robot interface enforces them: saturation of every command, and divergence.

Every limit comes from the `ARM` table the arm's driver gives (the robot's description, tightened
by the plant options, never widened: docs/robots.md). Each cycle the robot interface clips the
command to them before the driver, so no value past a limit reaches the arm: a torque to the
joint's effort limit; a position to the joint's range, moving at most the velocity limit in a
period. It also watches for divergence: a torque command at its effort limit for longer than
`saturation_bound`, a measured velocity past its limit (where the robot gives one) by more than
`VELOCITY_TOLERANCE`, or a measured position past its range by more than `position_tolerance`.
Divergence is a fault: the interface returns ERROR with a message naming the joint and the limit,
its `error` component engages the brakes, and the driver keeps the message for the run's summary
(a `fault:` line naming the task that wrote the command).

Every array is made here, once; the per-cycle checks are ufuncs into them (no allocation).
"""

from __future__ import annotations

import math

import numpy as np

from pbo_runtime import Arm

#: How long a command may stay at its limit before it is a fault, s (a module parameter).
SATURATION_BOUND = 0.05
#: How far past its range a measured position may be before it is a fault, rad (m for a slide
#: joint): the simulated joint limits are soft, and a joint driven against its stop goes a little past.
POSITION_TOLERANCE = 0.02
#: How far past its velocity limit a measured velocity may be before it is a fault, as a share of
#: the limit: a servo or a controller tracking a reference at the limit overshoots it a little.
VELOCITY_TOLERANCE = 0.1


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
        self._allowed = np.full(n, self.saturated_cycles_allowed, dtype=np.int64)
        self.saturated_for = np.zeros(n, dtype=np.int64)  # consecutive cycles each joint's command was at its limit
        self._counting = False  # some joint's count is not 0
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

    def saturate_torque(self, tau: np.ndarray, out: np.ndarray) -> bool:
        """`out` = `tau` clipped to the effort limits; each joint at or past its limit counts a
        cycle towards the saturation bound, one within it starts its count again. True when a
        joint is at its limit."""
        flags = self._flags
        np.abs(tau, out=self._scratch)
        np.greater_equal(self._scratch, self.effort, out=flags)
        if not np.count_nonzero(flags):  # the usual cycle: nothing to clip (a NaN is left for the driver to refuse)
            np.copyto(out, tau)
            if self._counting:
                self.saturated_for.fill(0)
                self._counting = False
            return False
        if np.count_nonzero(np.isfinite(tau, out=self._long)) != self.ndof:  # not a command to clip: the driver refuses it as it is
            np.copyto(out, tau)
            return False
        np.maximum(tau, self.effort_low, out=out)  # np.clip's Python layers allocate
        np.minimum(out, self.effort, out=out)
        counted = self._counted
        np.copyto(counted, flags)  # as integers: a ufunc mixing bool and int64 allocates a cast buffer
        np.multiply(self.saturated_for, counted, out=self.saturated_for)
        np.add(self.saturated_for, counted, out=self.saturated_for)
        self._counting = True
        return True

    def limit_position(self, q_r: np.ndarray, previous: np.ndarray, step: np.ndarray, out: np.ndarray) -> None:
        """`out` = `q_r` within `step` of `previous` (the velocity limit over a period) and within the
        range; `q_r` as it is when it is not finite, for the driver to refuse."""
        if np.count_nonzero(np.isfinite(q_r, out=self._flags)) != self.ndof:
            np.copyto(out, q_r)
            return
        low, high = self._scratch, self._q_step_high
        np.subtract(previous, step, out=low)
        np.add(previous, step, out=high)
        np.maximum(q_r, low, out=out)
        np.minimum(out, high, out=out)
        np.maximum(out, self.q_min, out=out)
        np.minimum(out, self.q_max, out=out)

    def saturated_too_long(self) -> bool:
        """Whether a joint's command has stayed at its limit past the bound (after `clip`)."""
        return bool(np.count_nonzero(np.greater(self.saturated_for, self._allowed, out=self._long)))

    def outside(self, q: np.ndarray, qd: np.ndarray) -> bool:
        """Whether a measured velocity is past its limit or a position past its range and the tolerance."""
        state = self._state
        np.subtract(q, self._q_centre, out=self._state_q)
        np.copyto(self._state_qd, qd)
        np.abs(state, out=state)
        return bool(np.count_nonzero(np.greater(state, self._state_bound, out=self._state_flags)))

    def allow_from(self, q: np.ndarray) -> None:
        """At `on`: a joint already past its range (braked there after a fault) may be driven back,
        not further out: its bound is where it is now, until the next `on`."""
        n = self.ndof
        self._state_bound[:n] = np.maximum(self._q_reach, np.abs(q - self._q_centre))

    def reset(self) -> None:
        """No command is being saturated (on, a hold): the bound counts afresh."""
        self.saturated_for.fill(0)
        self._counting = False

    # once, at a fault: what is wrong, in words --------------------------------------------------------

    def units(self, joint: int) -> tuple[str, str, str]:
        """(force, position, velocity) units of `joint`."""
        return ("N", "m", "m/s") if self.slide[joint] else ("N m", "rad", "rad/s")

    def saturation_message(self, tau: np.ndarray, port: str, period: float) -> str:
        """The fault of the joint saturated longest: its limit, for how long, what was asked."""
        joint = int(np.argmax(self.saturated_for))
        unit = self.units(joint)[0]
        held = self.saturated_for[joint] * period
        return (f"joint {joint + 1}: the torque command '{port}' stayed at its effort limit of {self.effort[joint]:.4g} "
                f"{unit} for {held * 1e3:.0f} ms, past the saturation bound of {self.saturation_bound * 1e3:.0f} ms "
                f"(it asked {tau[joint]:.4g} {unit}); the arm is braked")

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
