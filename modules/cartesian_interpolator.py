"""Cartesian interpolator (TR Figure 7; between the trackball or the vision subsystem and the
controller in Figures 10, 12 and 13).

The desired pose x_d comes from a slower source (a trackball at 100 Hz, a vision subsystem at
30 Hz) and changes in steps; the controller wants a reference that moves a little every one of
its cycles. Each new sample of x_d (a value that differs from the last one seen) starts a straight
segment from the current reference x_r to that sample, to be covered in `sample_period` (the
period of the task that writes x_d); each cycle moves x_r along it by the segment's velocity
times the time since the last cycle, and lands exactly on the sample:

    new sample:  v = (x_d - x_r) / sample_period, its position part scaled down (direction kept)
                 to at most max_linear_velocity, its rotation part to max_angular_velocity
    every cycle: x_r = x_r + clip(x_d - x_r, -|v| dt, |v| dt),  xd_r = that step / dt

So x_r is x_d delayed by about one sample and made continuous, xd_r is its velocity (for a
controller's feedforward), and neither speed limit is ever exceeded. Turned on, x_r starts at
x_m (where the arm is) and xd_r at 0. A jump larger than the limits allow in one sample is
followed at the limit; the cartesian_trajectory module is the one that also limits acceleration.

Poses are (6,): position m, then a rotation vector rad (axis * angle). The rotation part is
interpolated along the straight line between rotation vectors, not the geodesic (close to it for
the small steps between samples).

Real-time safe cycle: no allocation, no library calls that allocate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbo_runtime import InVar, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class CartesianInterpolatorParams:
    sample_period: float = param(0.01, above=0, at_most=3600)  # s: how often x_d changes (the period of the task that writes it)
    max_linear_velocity: float = param(0.5, above=0, at_most=100)  # m/s, of the position part as a whole
    max_angular_velocity: float = param(2.0, above=0, at_most=100)  # rad/s, of the rotation-vector part as a whole

    def __post_init__(self) -> None:
        for name in ("sample_period", "max_linear_velocity", "max_angular_velocity"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got: {value}")


class CartesianInterpolator(PortBasedObject):
    """x_r: the samples of x_d joined by straight, speed-limited segments. Real-time safe cycle."""

    Params = CartesianInterpolatorParams

    x_d = InVar("x_d", shape=(6,), doc="desired pose, changing in steps: position m, then rotation vector rad")
    x_m = InVar("x_m", shape=(6,), doc="measured pose: where x_r starts when turned on")
    x_r = OutVar("x_r", shape=(6,), doc="reference pose this cycle: position m, then rotation vector rad")
    xd_r = OutVar("xd_r", shape=(6,), doc="reference velocity: m/s, then rad/s (rotation-vector rate)")

    def init(self, params: CartesianInterpolatorParams) -> None:
        # scalars the cycle multiplies by, as 0-d arrays: a Python float would be boxed into one per call
        self._inverse_sample = np.full((), 1.0 / params.sample_period)
        self._dt = np.zeros(())
        self._inverse_dt = np.zeros(())
        self._scale = np.zeros(())
        self._max_linear = params.max_linear_velocity
        self._max_angular = params.max_angular_velocity
        self._sample = np.zeros(6)  # the last sample of x_d seen
        self._speed = np.zeros(6)  # |v| per component of the current segment
        self._parts = ((self._speed[:3], self._max_linear), (self._speed[3:], self._max_angular))  # views, made once
        self._limit = np.zeros(6)
        self._squared = np.zeros(())  # |part|^2, written in place by np.dot
        self._step = np.zeros(6)
        self._changed = np.zeros(6, dtype=bool)
        self._last_time = 0.0

    def on(self) -> None:
        self.x_r = self.x_m
        self.xd_r.fill(0.0)
        self._last_time = self.time
        self._start_segment()

    def cycle(self) -> Status:
        now = self.time
        dt = now - self._last_time
        if not dt > 0:
            dt = self.period
        self._last_time = now
        np.not_equal(self.x_d, self._sample, out=self._changed)
        if np.count_nonzero(self._changed):
            self._start_segment()
        step, limit = self._step, self._limit
        np.subtract(self._sample, self.x_r, out=step)
        self._dt.fill(dt)
        self._inverse_dt.fill(1.0 / dt)
        np.multiply(self._speed, self._dt, out=limit)
        np.minimum(step, limit, out=step)
        np.negative(limit, out=limit)
        np.maximum(step, limit, out=step)
        np.add(self.x_r, step, out=self.x_r)
        np.multiply(step, self._inverse_dt, out=self.xd_r)
        return Status.CONTINUE

    def _start_segment(self) -> None:
        """Take x_d as the new sample: the speeds that reach it in one sample period, limited."""
        sample, speed = self._sample, self._speed
        np.copyto(sample, self.x_d)
        np.subtract(sample, self.x_r, out=speed)
        np.abs(speed, out=speed)
        np.multiply(speed, self._inverse_sample, out=speed)
        for part, top in self._parts:
            np.dot(part, part, out=self._squared)
            norm = math.sqrt(self._squared)
            if norm > top:
                self._scale.fill(top / norm)
                np.multiply(part, self._scale, out=part)
