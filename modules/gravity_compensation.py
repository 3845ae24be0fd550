"""Gravity compensation: the joint torques that hold the arm still against gravity.

    tau_g = scale * g(q_m)

g is Pinocchio's `computeGeneralizedGravity` on the model built once in `init` from the robot
interface's out-consts ARM and EE (TR §4.3), so the module serves whatever arm is attached. A
building block for the torque-mode configurations of the TR (Figures 8 and 14): add tau_g to a
PD controller's torque with a join, or use it on its own to let an operator move the arm by hand.
`scale` < 1 compensates only part of the weight (e.g. for an uncertain payload).

Real-time notes: the cycle allocates no arrays of its own; the Pinocchio call returns a view the
binding allocates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio

from modules._model_based import ModelBased
from pbo_runtime import InVar, OutVar, Status, param


@dataclass(frozen=True)
class GravityCompensationParams:
    scale: float = param(1.0, at_least=0, at_most=10)  # fraction of the model's gravity torque to output

    def __post_init__(self) -> None:
        if not (math.isfinite(self.scale) and self.scale >= 0):
            raise ValueError(f"scale must be a finite number >= 0, got: {self.scale}")


class GravityCompensation(ModelBased):
    """tau_g = scale * g(q_m), with g from Pinocchio."""

    Params = GravityCompensationParams

    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    tau_g = OutVar("tau_g", shape=("NDOF",), doc="gravity torque, N m")

    def init(self, params: GravityCompensationParams) -> None:
        self.build_model()
        self._scale = params.scale

    def on(self) -> None:
        self._compute()

    def cycle(self) -> Status:
        self._compute()
        return Status.CONTINUE

    def _compute(self) -> None:
        gravity = pinocchio.computeGeneralizedGravity(self._model, self._data, self.q_m)
        np.multiply(gravity, self._scale, out=self.tau_g)
