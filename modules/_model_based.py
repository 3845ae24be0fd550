"""Base of the modules that compute with the arm's model (TR §4.3: swap the robot, swap the model).

They take the robot interface's out-consts NDOF, DH and DYN as in-consts and build their
Pinocchio model from them once, in `init`; `build_model` is that step.
"""

from __future__ import annotations

import numpy as np

from modules._robot_model import pinocchio_model
from pbo_runtime import InConst, PortBasedObject


class ModelBased(PortBasedObject):
    """Declares the robot's consts; `build_model()` makes `self._model` and `self._data` from them."""

    ndof = InConst("NDOF", dtype="int32", doc="number of joints")
    dh = InConst("DH", shape=("NDOF", 4), doc="DH rows (theta offset, d, a, alpha)")
    dyn = InConst("DYN", shape=("NDOF", 11), doc="mass, COM, inertia about COM, armature per link")

    def build_model(self) -> None:
        self._model = pinocchio_model(np.asarray(self.dh), np.asarray(self.dyn))
        self._data = self._model.createData()
