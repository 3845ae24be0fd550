"""Where an arm's joint frames are: forward kinematics of its `ARM` and `EE` constants, for the monitor's drawing.

The HMI draws the arm as it moves from its measured joint positions (`q_m`): one point per joint
frame, base to end effector. The constants are the ones the robot interface published in the run's
table, so the drawing is of the arm the plant simulates, whichever file described it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pbo_runtime.objects.arm import END_EFFECTOR_FRAME, arm_model


class ArmFrames:
    """An arm's kinematic tree as a Pinocchio model: `positions(q)` gives its joint frames' origins."""

    def __init__(self, arm: Any, ee: Any, name: str = "arm") -> None:
        import pinocchio  # imported here: only a drawing of an arm needs Pinocchio

        try:
            self._model = arm_model(arm, ee, name)
        except ValueError as exc:
            raise ValueError(f"arm '{name}': {exc}") from None
        self.name = name
        self.ndof = int(self._model.nq)
        self._data = self._model.createData()
        self._ee = self._model.getFrameId(END_EFFECTOR_FRAME)
        self._pinocchio = pinocchio

    def positions(self, q: Any) -> np.ndarray:
        """(ndof + 1, 3): the origins of joint frames 1..n and of the end effector, in metres."""
        q = np.asarray(q, dtype=np.float64).reshape(-1)
        if q.shape != (self.ndof,):
            raise ValueError(f"arm '{self.name}' has {self.ndof} joints, got {q.size} joint positions")
        self._pinocchio.forwardKinematics(self._model, self._data, q)
        frames = [np.array(self._data.oMi[i].translation) for i in range(1, self.ndof + 1)]
        frames.append(np.array(self._pinocchio.updateFramePlacement(self._model, self._data, self._ee).translation))
        return np.vstack(frames)
