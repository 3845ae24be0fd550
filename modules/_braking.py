"""The velocity- and acceleration-limited motion law shared by the trajectory generators.

Every cycle each component steers towards the largest speed from which steps of a·dt can still
stop at the goal, v (v + a·dt) / (2a) = |e|, i.e. v = sqrt((a·dt/2)² + 2a|e|) - a·dt/2 (the
discrete-time braking curve; the continuous sqrt(2a|e|) overshoots), capped by v_max; it lands
exactly on the goal only from a speed one acceleration step can stop, so both limits hold on
every cycle, arrival included. Limits may differ per component (linear and angular parts of a
pose). Real-time safe: every buffer is made in the constructor.
"""

from __future__ import annotations

import numpy as np

from modules._ufuncs import clip


class BrakingLaw:
    """Advances a reference (position, velocity) one step of `dt` towards a goal, in place."""

    def __init__(self, size: int, max_velocity: float | np.ndarray, max_acceleration: float | np.ndarray, dt: float) -> None:
        a = np.broadcast_to(np.asarray(max_acceleration, dtype=float), (size,)).copy()
        self._v_max = np.broadcast_to(np.asarray(max_velocity, dtype=float), (size,)).copy()
        self._dt = dt
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

    def step(self, goal: np.ndarray, position: np.ndarray, velocity: np.ndarray) -> None:
        e, v, dv = self._error, self._speed, self._change
        np.subtract(goal, position, out=e)
        # the fastest speed from which steps of a·dt still stop at the goal, signed towards it
        np.abs(e, out=v)
        np.multiply(v, self._two_a, out=v)
        np.add(v, self._half_step_squared, out=v)
        np.sqrt(v, out=v)
        np.subtract(v, self._half_step, out=v)
        np.minimum(v, self._v_max, out=v)
        np.copysign(v, e, out=v)
        # may this component land this cycle? only from a speed one acceleration step can stop
        np.abs(velocity, out=dv)
        np.less_equal(dv, self._a_step_tolerance, out=self._slow)
        np.subtract(v, velocity, out=dv)
        clip(dv, self._a_step_down, self._a_step, out=dv)
        np.add(velocity, dv, out=velocity)
        np.multiply(velocity, self._dt, out=dv)
        np.add(position, dv, out=position)
        np.subtract(goal, position, out=e)
        np.abs(e, out=e)
        np.less_equal(e, self._snap, out=self._near)
        np.logical_and(self._slow, self._near, out=self._near)
        np.copyto(position, goal, where=self._near)
        np.copyto(velocity, 0.0, where=self._near)
