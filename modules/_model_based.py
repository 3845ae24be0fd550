"""Base of the modules that compute with the arm's model (TR §4.3: swap the robot, swap the model).

They take the robot interface's out-consts NDOF, ARM and EE as in-consts and build their
Pinocchio model from them once, in `init` (`pbo_runtime.arm_model`); `build_model` is that step.
"""

from __future__ import annotations


from pbo_runtime import Arm, InConst, PortBasedObject, arm_model


class ModelBased(PortBasedObject):
    """Declares the robot's consts; `build_model()` makes `self._model` and `self._data` from them."""

    ndof = InConst("NDOF", dtype="int32", doc="number of joints")
    arm_table = InConst("ARM", shape=("NDOF", Arm.WIDTH), doc="the arm's joint table (pbo_runtime.ARM_COLUMNS)")
    end_effector = InConst("EE", shape=(Arm.EE_WIDTH,), doc="where the end effector is (pbo_runtime.EE_COLUMNS)")

    def build_model(self) -> None:
        self._model = arm_model(self.arm_table, self.end_effector)
        self._data = self._model.createData()
