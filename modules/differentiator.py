"""Differentiator (TR Figure 7): the time derivative of any vector, by backward differences.

    on:     zd = 0, and remember z and the time         no derivative from a past it never saw
    cycle:  raw = (z - z_prev) / dt                      dt: the time since the last sample
            zd  = zd + alpha (raw - zd)                  alpha = dt / (smoothing + dt)

`z` and `zd` take their variables' shape (link them with `ports: {z: q_m, zd: qd_m}`; the TR's
z is a wild card for any variable). dt is the time between the two release times, not the
period, so a skipped cycle does not double the derivative; when two samples share a time the
period stands in. `smoothing` (s) is the time constant of a first-order low-pass on the
derivative, 0 (the default) for the raw difference. The first cycle after `on` differentiates
against the value read at `on`, so turning the task on while the signal is still gives zd = 0.

Real-time safe cycle: no allocation, no library calls that allocate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pbo_runtime import InVar, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class DifferentiatorParams:
    smoothing: float = param(0.0, at_least=0, at_most=3600)  # s: time constant of the low-pass on the derivative; 0: none

    def __post_init__(self) -> None:
        if not (math.isfinite(self.smoothing) and self.smoothing >= 0):
            raise ValueError(f"smoothing must be a finite number >= 0, got: {self.smoothing}")


class Differentiator(PortBasedObject):
    """zd = dz/dt by backward differences, optionally low-passed. Real-time safe cycle."""

    Params = DifferentiatorParams

    z = InVar("z", shape=None, doc="the signal (any shape; link it with ports: {z: <variable>})")
    zd = OutVar("zd", shape=None, doc="its time derivative, per second (the shape of z)")

    @classmethod
    def same_shape(cls, params: Any) -> tuple[tuple[str, ...], ...]:
        return (("z", "zd"),)  # `pbo check` refuses what init would

    def init(self, params: DifferentiatorParams) -> None:
        if self.z.shape != self.zd.shape:
            raise ValueError(f"z and zd must have the same shape, got: {list(self.z.shape)} and {list(self.zd.shape)}")
        self._smoothing = params.smoothing
        self._previous = np.zeros(self.z.shape)
        self._raw = np.zeros(self.z.shape)
        self._last_time = 0.0
        self._scalar = np.zeros(())  # 1/dt, then alpha: a 0-d array, as a Python float would be boxed per call

    def on(self) -> None:
        np.copyto(self._previous, self.z)
        self.zd.fill(0.0)
        self._last_time = self.time

    def cycle(self) -> Status:
        now = self.time
        dt = now - self._last_time
        if not dt > 0:
            dt = self.period
        raw = self._raw
        np.subtract(self.z, self._previous, out=raw)
        self._scalar.fill(1.0 / dt)
        np.multiply(raw, self._scalar, out=raw)
        zd = self.zd
        if self._smoothing > 0:
            np.subtract(raw, zd, out=raw)  # zd += alpha (raw - zd)
            self._scalar.fill(dt / (self._smoothing + dt))
            np.multiply(raw, self._scalar, out=raw)
            np.add(zd, raw, out=zd)
        else:
            np.copyto(zd, raw)
        np.copyto(self._previous, self.z)
        self._last_time = now
        return Status.CONTINUE
