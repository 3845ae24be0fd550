"""Inverse dynamics (TR Figure 7; the second half of the computed torque controller, Figure 14).

    tau_u = M(q_m) qdd_r + C(q_m, qd_m) qd_m + g(q_m)

computed with Pinocchio's recursive Newton-Euler algorithm (`rnea`) on the model built once in
`init` from the robot interface's out-consts ARM and EE. The rotor inertia (ARM column `armature`,
`model.armature`) is part of M: Pinocchio 4 `rnea` adds armature * qdd itself; with a Pinocchio
whose `rnea` ignores it (probed once at init) the module adds it. Feed qdd_r from a PD law on
the joint error plus the trajectory's acceleration and the arm's error dynamics become linear
(computed torque). `max_torque` saturates each joint's output symmetrically.

Real-time notes: the cycle allocates no arrays of its own; `pinocchio.rnea` returns a view the
binding allocates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio

from modules._model_based import ModelBased
from modules._robot_model import rnea_includes_armature
from pbo_runtime import InVar, OutVar, Status, param


@dataclass(frozen=True)
class InverseDynamicsParams:
    max_torque: float = param(math.inf, above=0, at_most=math.inf)  # N m, every joint: |tau_u| is clipped to this

    def __post_init__(self) -> None:
        if not self.max_torque > 0:
            raise ValueError(f"max_torque must be > 0, got: {self.max_torque}")


class InverseDynamics(ModelBased):
    """tau_u = RNEA(q_m, qd_m, qdd_r), rotor inertia included, clipped to max_torque."""

    Params = InverseDynamicsParams
    ACCELERATION_INPUT = "qdd_r"  # a joint controller feeding it is checked as a computed-torque loop

    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    qd_m = InVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s")
    qdd_r = InVar("qdd_r", shape=("NDOF",), doc="reference joint acceleration, rad/s^2")
    tau = OutVar("tau_u", shape=("NDOF",), doc="joint torque command, N m")

    def init(self, params: InverseDynamicsParams) -> None:
        self.build_model()
        self._armature = None if rnea_includes_armature(self._model) else self._model.armature.copy()
        self._max = params.max_torque
        self._term = np.zeros(int(self.ndof))

    def on(self) -> None:
        self._compute()

    def cycle(self) -> Status:
        self._compute()
        return Status.CONTINUE

    def _compute(self) -> None:
        tau = self.tau
        np.copyto(tau, pinocchio.rnea(self._model, self._data, self.q_m, self.qd_m, self.qdd_r))
        if self._armature is not None:
            np.multiply(self._armature, self.qdd_r, out=self._term)
            np.add(tau, self._term, out=tau)
        if self._max < math.inf:
            np.clip(tau, -self._max, self._max, out=tau)
