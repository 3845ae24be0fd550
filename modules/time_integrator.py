"""Time integrator (TR Figure 13): a reference joint position from a reference joint velocity.

    on:     q_r = q_m                       start where the arm is (bumpless)
    cycle:  q_r = q_r + qd_r * period       forward Euler at the task's own period

It closes the loop of a rate controller (resolved rate, damped least squares) onto a
position-mode robot interface. q_r integrates its own previous value, not q_m, so the
reference does not inherit the servo's tracking lag; `max_lead` keeps it within that many
radians of q_m on every joint (an anti-windup for when the arm is held back), by default
unlimited. While the actuators are held (`actuators_held`: a stopped plant, a stale command,
the table lock held) it integrates nothing, and once they are not it starts again from q_m.

Real-time safe cycle: no allocation, no library calls that allocate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbo_runtime import InVar, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class TimeIntegratorParams:
    max_lead: float = param(math.inf, above=0, at_most=math.inf)  # rad: |q_r - q_m| never exceeds this on any joint

    def __post_init__(self) -> None:
        if not self.max_lead > 0:
            raise ValueError(f"max_lead must be > 0, got: {self.max_lead}")


class TimeIntegrator(PortBasedObject):
    """q_r += qd_r * period, starting from q_m when turned on."""

    Params = TimeIntegratorParams

    qd_r = InVar("qd_r", shape=("NDOF",), doc="reference joint velocity, rad/s")
    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad: where q_r starts")
    q_r = OutVar("q_r", shape=("NDOF",), doc="reference joint position, rad")

    def init(self, params: TimeIntegratorParams) -> None:
        n = self.q_r.shape[0]
        self._lead = params.max_lead
        self._step = np.zeros(n)
        self._low = np.zeros(n)
        self._high = np.zeros(n)

    def on(self) -> None:
        self._held = False
        self.q_r = self.q_m

    def cycle(self) -> Status:
        if self.actuators_held:  # the arm does not follow: the reference must not run on without it
            self._held = True
            return Status.CONTINUE
        q_r = self.q_r
        if self._held:
            self._held = False
            np.copyto(q_r, self.q_m)
        np.multiply(self.qd_r, self.period, out=self._step)
        np.add(q_r, self._step, out=q_r)
        if self._lead < math.inf:
            np.subtract(self.q_m, self._lead, out=self._low)
            np.add(self.q_m, self._lead, out=self._high)
            np.clip(q_r, self._low, self._high, out=q_r)
        return Status.CONTINUE
