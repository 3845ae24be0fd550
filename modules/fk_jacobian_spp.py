"""Forward kinematics and Jacobian on a special-purpose processor (TR §4.6.3; Figures 10, 12, 13).

What `fk_jacobian` computes, downloaded to a floating-point accelerator (the `spp` device)
instead of computed on the RTPU: `init` downloads the routine `jacobian` with the arm the robot
interface describes (ARM, EE) and the frame; each cycle posts q_m and publishes the newest
result, x_m and J:

    x_m = (p, log3(R))   position in the base frame, then orientation as a rotation vector
    J   = (6, NDOF)      LOCAL_WORLD_ALIGNED, linear-velocity rows first

The processor runs beside the task, never waited on: a result answers an earlier cycle's q_m
(its age, in cycles, is 1 when the processor kept up). The module decides what a late result
means: up to `max_age` cycles it publishes the newest it has; past that, the task goes to ERROR
with the reason, which names a dead processor as such ("the special-purpose processor (pid N)
died (killed by SIGKILL)"), and publishes nothing stale. `on` waits (bounded) for the answer to
the current q_m, so x_m and J are right from the first cycle.
Real-time safe cycle: one driver call and two copies, no allocation.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from modules._model_based import ModelBased
from modules._robot_model import END_EFFECTOR_FRAME
from pbo_runtime import InVar, ModuleError, OutVar, Status, param

# seconds from the processor's newest result that a task finding it too old gives, once, on its way to
# ERROR, a processor killed a moment ago to end: its death is then what the task's error says, not its lateness
DEATH_GRACE = 0.05


@dataclass(frozen=True)
class FkJacobianSppParams:
    device: str = "spp"  # the YAML device this task opens (listed in its resources): driver spp
    frame: str = END_EFFECTOR_FRAME  # the operational frame: "ee" or "link1" ... "link<NDOF>"
    max_age: int = param(25, at_least=1, at_most=1_000_000)  # cycles: an older result is an error, never published

    def __post_init__(self) -> None:
        if not self.frame:
            raise ValueError("frame must name a frame of the arm, got: ''")
        if isinstance(self.max_age, bool) or not isinstance(self.max_age, int) or self.max_age < 1:
            raise ValueError(f"max_age must be a whole number of cycles >= 1, got: {self.max_age!r}")


class FkJacobianSpp(ModelBased):
    """Forward kinematics and Jacobian of the arm, computed on a special-purpose processor."""

    Params = FkJacobianSppParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {"device": {"kind": "spp"}}

    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    x_m = OutVar("x_m", shape=(6,), doc="measured pose: position m, then rotation vector rad, base frame")
    jacobian = OutVar("J", shape=(6, "NDOF"), doc="frame Jacobian, LOCAL_WORLD_ALIGNED, linear rows first")

    @classmethod
    def check_links(cls, params: Any, shapes: Mapping[str, tuple[int, ...]], dims: Mapping[str, int],
                    channels: Mapping[str, int], options: Mapping[str, Mapping[str, Any]]) -> None:
        """The frame (ModelBased), and the processor's memory: x_m and J, 6 + 6 NDOF numbers, must fit it."""
        super().check_links(params, shapes, dims, channels, options)
        memory, n = options.get(params.device, {}).get("memory"), dims.get("NDOF")
        if isinstance(memory, int) and isinstance(n, int) and memory < 6 + 6 * n:
            raise ValueError(f"routine jacobian answers {6 + 6 * n} numbers (x_m and J of {n} joints), but device "
                             f"'{params.device}' has memory: {memory}; give it memory: {6 + 6 * n} or more")

    def init(self, params: FkJacobianSppParams) -> None:
        self._device = params.device
        self._max_age = params.max_age
        self._spp = self.open_device(params.device)
        if not callable(getattr(self._spp, "download", None)):
            raise ModuleError(f"device '{params.device}' is not a special-purpose processor (it has no download); "
                              "give it driver: spp")
        n = int(self.ndof)
        _, size = self._spp.download("jacobian", {"ARM": self.arm_table, "EE": self.end_effector}, frame=params.frame)
        if size != 6 + 6 * n:
            raise ModuleError(f"device '{params.device}': routine jacobian gives {size} numbers, expected {6 + 6 * n}")
        self._call = self._spp.call
        self._result = np.zeros(size)
        self._pose = self._result[:6]
        self._jacobian = self._result[6:].reshape(6, n)  # a view: the result is row by row
        self.age = 0  # the age of the result published last, in cycles (for logs and tests)

    def on(self) -> None:
        self._spp.call_and_wait(self.q_m, self._result)
        self.age = 0
        self._publish()

    def cycle(self) -> Status:
        age = self._call(self.q_m, self._result)
        self.age = age
        if 0 < age <= self._max_age:
            self._publish()
            return Status.CONTINUE
        fault = self._spp.await_death(DEATH_GRACE)
        if fault:
            return self.fault(f"device '{self._device}': {fault}")
        return self.fault(f"device '{self._device}': its newest result is {age} cycles old, more than max_age "
                          f"{self._max_age}: the special-purpose processor does not keep up with this task's period")

    def _publish(self) -> None:
        np.copyto(self.x_m, self._pose)
        np.copyto(self.jacobian, self._jacobian)
