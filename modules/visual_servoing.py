"""Visual servoing interface (TR Figures 12 and 13): the desired Cartesian pose from what a camera sees.

A vision subsystem (the `camera` device) reports a moving target's pose; this module turns it
into the desired pose of the hand, every cycle:

    x_d[:3] = p_target + offset        the hand hovers `offset` (m, base frame) from the target
    x_d[3:] = orientation              a fixed rotation vector (param), or, without one, the
                                       hand's orientation x_m[3:] when the task was turned on

so the arm keeps its grip attitude and follows the target's position. An inverse kinematics
controller (resolved_rate, Figure 12, or damped_least_squares, Figure 13) takes x_d from here.
Real-time safe cycle: one driver call and two copies, no allocation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pbo_runtime import InVar, ModuleError, OutVar, PortBasedObject, Status, param


@dataclass(frozen=True)
class VisualServoingParams:
    device: str = "camera"  # the YAML device this task opens (listed in its resources)
    offset: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), at_least=-100, at_most=100)  # m: the hand's position relative to the target
    orientation: tuple[float, ...] = param(
        (), at_least=-10, at_most=10)  # rad, the hand's rotation vector; left out: keep x_m's at `on`

    def __post_init__(self) -> None:
        if len(self.offset) != 3 or not all(math.isfinite(v) for v in self.offset):
            raise ValueError(f"offset must be 3 finite numbers [dx, dy, dz] (m), got: {list(self.offset)}")
        if self.orientation and (len(self.orientation) != 3 or not all(math.isfinite(v) for v in self.orientation)):
            raise ValueError(
                f"orientation must be 3 finite numbers (a rotation vector, rad), or left out, got: {list(self.orientation)}"
            )


class VisualServoing(PortBasedObject):
    """x_d = (target position + offset, fixed orientation). Real-time safe cycle."""

    Params = VisualServoingParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {"device": {"kind": "camera"}}

    x_m = InVar("x_m", shape=(6,), doc="measured pose of the hand: position m, rotation vector rad")
    x_d = OutVar("x_d", shape=(6,), doc="desired pose of the hand: position m, rotation vector rad")

    def init(self, params: VisualServoingParams) -> None:
        self._camera = self.open_device(params.device)
        if not callable(getattr(self._camera, "read_target", None)):
            raise ModuleError(f"device '{params.device}' is not a camera (it has no read_target); give it driver: camera")
        self._read = self._camera.read_target
        self._offset = np.array(params.offset, dtype=np.float64)
        self._fixed = bool(params.orientation)
        self._orientation = np.array(params.orientation if self._fixed else (0.0, 0.0, 0.0), dtype=np.float64)
        self._target = np.zeros(6)
        self.target_time = 0.0  # sim time of the last frame the camera gave (for logs and tests)

    def on(self) -> None:
        if not self._fixed:
            np.copyto(self._orientation, self.x_m[3:])
        self._compute()

    def cycle(self) -> Status:
        self._compute()
        return Status.CONTINUE

    def _compute(self) -> None:
        self.target_time = self._read(self._target)
        x_d = self.x_d
        np.add(self._target[:3], self._offset, out=x_d[:3])
        np.copyto(x_d[3:], self._orientation)
