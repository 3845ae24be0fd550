"""The work a special-purpose processor can be downloaded (TR §4.6.3): routines by name.

A routine is built on the processor from the download's data (in `init`-time, once) and then
called per work item on a flat float64 input, writing a flat float64 output:

- `jacobian`: the forward kinematics and Jacobian of the arm the robot interface describes
  (data: ARM, EE, the arm's out-consts; option frame, default "ee"), for one joint vector q
  (NDOF inputs), giving x (6: position m, rotation vector rad) then J (6 x NDOF, row by row,
  LOCAL_WORLD_ALIGNED, linear rows first): what `fk_jacobian` computes on an RTPU.
- `jacobian_batch`: the same for `batch` joint vectors at once (inputs batch x NDOF, outputs
  batch x (6 + 6 NDOF)): a planner's or a sampler's batch of Jacobians.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pbo_runtime import arm_model

END_EFFECTOR_FRAME = "ee"


class Jacobian:
    """x and J of one frame of the arm, per joint vector; `batch` vectors a work item."""

    def __init__(self, arrays: Mapping[str, np.ndarray], options: Mapping[str, Any], batch: int = 1) -> None:
        import pinocchio  # the processor's own import: the driver never needs it

        missing = [name for name in ("ARM", "EE") if name not in arrays]
        if missing:
            raise ValueError(f"routine jacobian needs the arm's {' and '.join(missing)} (the robot interface's out-consts)")
        unknown = sorted(set(options) - {"frame", "batch"})
        if unknown:
            raise ValueError(f"unknown option(s) {unknown} of routine jacobian; valid options: frame, batch")
        self._pin = pinocchio
        self.model = arm_model(arrays["ARM"], arrays["EE"])
        self.data = self.model.createData()
        frame = str(options.get("frame", END_EFFECTOR_FRAME))
        if not self.model.existFrame(frame):
            raise ValueError(f"the arm has no frame {frame!r}; frames: ee, link1 ... link{self.model.nq}")
        self.frame = self.model.getFrameId(frame)
        self.batch = batch
        self.nq = self.model.nq
        self.item_out = 6 + 6 * self.nq
        self.in_size = batch * self.nq
        self.out_size = batch * self.item_out

    def run(self, inputs: np.ndarray, outputs: np.ndarray) -> None:
        pin, model, data, frame, nq, width = self._pin, self.model, self.data, self.frame, self.nq, self.item_out
        for k in range(self.batch):
            q = inputs[k * nq:(k + 1) * nq]
            out = outputs[k * width:(k + 1) * width]
            pin.computeJointJacobians(model, data, q)
            placement = pin.updateFramePlacement(model, data, frame)
            out[:3] = placement.translation
            out[3:6] = pin.log3(placement.rotation)
            out[6:] = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED).ravel()


def build(routine: str, arrays: Mapping[str, np.ndarray], options: Mapping[str, Any]) -> Jacobian:
    """The routine named `routine`, built from its download; ValueError naming the choices."""
    if routine == "jacobian":
        return Jacobian(arrays, {k: v for k, v in options.items() if k != "batch"}, 1)
    if routine == "jacobian_batch":
        batch = options.get("batch")
        if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
            raise ValueError(f"routine jacobian_batch needs option batch, a whole number >= 1, got: {batch!r}")
        return Jacobian(arrays, options, batch)
    raise ValueError(f"no routine {routine!r} on this processor; routines: {', '.join(ROUTINES)}")


ROUTINES = ("jacobian", "jacobian_batch")
