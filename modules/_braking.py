"""The velocity- and acceleration-limited motion law shared by the trajectory generators.

Every cycle each component steers towards the largest speed from which steps of a·dt can still
stop at the goal, v (v + a·dt) / (2a) = |e|, i.e. v = sqrt((a·dt/2)² + 2a|e|) - a·dt/2 (the
discrete-time braking curve; the continuous sqrt(2a|e|) overshoots), capped by v_max; it lands
exactly on the goal only from a speed one acceleration step can stop, so both limits hold on
every cycle, arrival included. Limits may differ per component (linear and angular parts of a
pose). Real-time safe: every buffer is made in the constructor. The step's ufuncs are called with
their output positional (but `minimum`, which numpy takes it from only as `out=`) and with arrays,
never Python numbers (each `out=` and each number costs a call more than a six-element operation does).
"""

from __future__ import annotations

import numpy as np
from numpy import absolute, add, copysign, copyto, less_equal, logical_and, minimum, multiply, sqrt, subtract

from modules._ufuncs import clip, count_nonzero


class BrakingLaw:
    """Advances a reference (position, velocity) one step of `dt` towards a goal, in place."""

    def __init__(self, size: int, max_velocity: float | np.ndarray, max_acceleration: float | np.ndarray, dt: float) -> None:
        a = np.broadcast_to(np.asarray(max_acceleration, dtype=float), (size,)).copy()
        self._v_max = np.broadcast_to(np.asarray(max_velocity, dtype=float), (size,)).copy()
        self._dt = np.full(size, dt)
        self._a_step = a * dt
        self._a_step_down = -self._a_step
        self._a_step_tolerance = a * dt * (1 + 1e-9)
        self._two_a = 2.0 * a
        self._half_step = 0.5 * a * dt
        self._half_step_squared = self._half_step**2
        self._snap = a * dt**2
        self._error = np.zeros(size)
        self._speed = np.zeros(size)
        self._change = np.zeros(size)
        self._slow = np.zeros(size, dtype=bool)
        self._near = np.zeros(size, dtype=bool)
        self._zero = np.zeros(size)

    def step(self, goal: np.ndarray, position: np.ndarray, velocity: np.ndarray) -> None:
        e, v, dv, slow, near = self._error, self._speed, self._change, self._slow, self._near
        subtract(goal, position, e)
        if not count_nonzero(e) and not count_nonzero(velocity):
            # At the goal and still (a NaN or an infinity is never that): the step below would land
            # every component on the goal at rest again, as these two copies do.
            position[...] = goal
            velocity[...] = 0.0
            return
        # the fastest speed from which steps of a·dt still stop at the goal, signed towards it
        absolute(e, v)
        multiply(v, self._two_a, v)
        add(v, self._half_step_squared, v)
        sqrt(v, v)
        subtract(v, self._half_step, v)
        minimum(v, self._v_max, out=v)
        copysign(v, e, v)
        # may this component land this cycle? only from a speed one acceleration step can stop
        absolute(velocity, dv)
        less_equal(dv, self._a_step_tolerance, slow)
        subtract(v, velocity, dv)
        clip(dv, self._a_step_down, self._a_step, dv)
        add(velocity, dv, velocity)
        multiply(velocity, self._dt, dv)
        add(position, dv, position)
        subtract(goal, position, e)
        absolute(e, e)
        less_equal(e, self._snap, near)
        logical_and(slow, near, near)
        copyto(position, goal, where=near)
        copyto(velocity, self._zero, where=near)
