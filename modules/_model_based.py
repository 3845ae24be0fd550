"""Base of the modules that compute with the arm's model (TR §4.3: swap the robot, swap the model).

They take the robot interface's out-consts NDOF, ARM and EE as in-consts and build their
Pinocchio model from them once, in `init` (`pbo_runtime.arm_model`); `build_model` is that step.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pbo_runtime import Arm, InConst, PortBasedObject, arm_model


def arm_frames(ndof: int) -> frozenset[str]:
    """The frames of the model `arm_model` builds for an arm of `ndof` joints, by name."""
    return frozenset(("universe", "ee", *(f"{part}{i}" for part in ("joint", "link") for i in range(1, ndof + 1))))


class ModelBased(PortBasedObject):
    """Declares the robot's consts; `build_model()` makes `self._model` and `self._data` from them."""

    ndof = InConst("NDOF", dtype="int32", doc="number of joints")
    arm_table = InConst("ARM", shape=("NDOF", Arm.WIDTH), doc="the arm's joint table (pbo_runtime.ARM_COLUMNS)")
    end_effector = InConst("EE", shape=(Arm.EE_WIDTH,), doc="where the end effector is (pbo_runtime.EE_COLUMNS)")

    @classmethod
    def check_links(cls, params: Any, shapes: Mapping[str, tuple[int, ...]], dims: Mapping[str, int],
                    channels: Mapping[str, int], options: Mapping[str, Mapping[str, Any]]) -> None:
        """A `frame` param names a frame of the model `arm_model` builds: ee, link<i>, joint<i>."""
        frame, n = getattr(params, "frame", None), dims.get("NDOF")
        if isinstance(frame, str) and frame and isinstance(n, int) and frame not in arm_frames(n):
            raise ValueError(
                f"frame must be one of the arm's frames (ee, link1 ... link{n}, joint1 ... joint{n}), got: {frame!r}"
            )

    def build_model(self) -> None:
        self._model = arm_model(self.arm_table, self.end_effector)
        self._data = self._model.createData()
