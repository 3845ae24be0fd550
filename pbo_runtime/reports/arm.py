"""Where an arm's joint frames are: forward kinematics of its DH rows with Pinocchio, for the monitor's drawing.

The HMI draws the arm as it moves from its measured joint positions (`q_m`): one point per joint
frame, base to end effector. The kinematics follow the robots' conventions
(`drivers.robots.description`, and the controllers' model in `modules._robot_model`): standard DH
rows (theta_offset, d, a, alpha), T_i = Rz(q_i + theta_offset_i) Tz(d_i) Tx(a_i) Rx(alpha_i); joint
i turns DH frame i-1 about its z axis. The runtime finds robots by name (`pbo.robots` entry points),
never by import, so the model is built here, kinematics only (no inertias: nothing is simulated).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pbo_runtime.config.model import Subsystem
from pbo_runtime.objects import registry


def _link(dh_row: np.ndarray) -> np.ndarray:
    """Tz(d) Tx(a) Rx(alpha): DH frame i seen from joint i's frame."""
    _, d, a, alpha = dh_row
    ca, sa = np.cos(alpha), np.sin(alpha)
    return np.array([[1.0, 0.0, 0.0, a], [0.0, ca, -sa, 0.0], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


class ArmFrames:
    """An arm's kinematic chain as a Pinocchio model: `positions(q)` gives its joint frames' origins."""

    def __init__(self, dh: Any, name: str = "arm") -> None:
        import pinocchio  # type: ignore[import-untyped]  # imported here: only a drawing of an arm needs Pinocchio

        dh = np.asarray(dh, dtype=np.float64)
        if dh.ndim != 2 or dh.shape[1] != 4 or dh.shape[0] < 1 or not np.all(np.isfinite(dh)):
            raise ValueError(f"arm '{name}': DH rows must be a finite (n, 4) array, got shape {dh.shape}")
        self.name = name
        self.dh = dh
        self.ndof = dh.shape[0]
        model = pinocchio.Model()
        parent, parent_link = 0, np.eye(4)
        for i, row in enumerate(dh, start=1):
            placement = parent_link @ _rot_z(row[0])
            parent = model.addJoint(parent, pinocchio.JointModelRZ(),
                                    pinocchio.SE3(placement[:3, :3].copy(), placement[:3, 3].copy()), f"joint{i}")
            parent_link = _link(row)
        self._tip = pinocchio.SE3(parent_link[:3, :3].copy(), parent_link[:3, 3].copy())  # DH frame n in the last joint's frame
        self._model = model
        self._data = model.createData()
        self._pinocchio = pinocchio

    def positions(self, q: Any) -> np.ndarray:
        """(ndof + 1, 3): the origins of joint frames 1..n (DH frames 0..n-1) and of DH frame n, the tool, in metres."""
        q = np.asarray(q, dtype=np.float64).reshape(-1)
        if q.shape != (self.ndof,):
            raise ValueError(f"arm '{self.name}' has {self.ndof} joints, got {q.size} joint positions")
        self._pinocchio.forwardKinematics(self._model, self._data, q)
        frames = [np.array(self._data.oMi[i].translation) for i in range(1, self.ndof + 1)]
        frames.append(np.array((self._data.oMi[self.ndof] * self._tip).translation))
        return np.vstack(frames)


def arm_of(subsystem: Subsystem) -> ArmFrames:
    """The arm the subsystem's plant simulates (its `plant: {model: ...}`, a `pbo.robots` entry point).

    ValueError saying why there is none to draw.
    """
    if subsystem.plant is None:
        raise ValueError(f"'{subsystem.name}' has no plant: there is no arm to draw (a file with plant: {{model: ...}} has one)")
    description = registry.load(registry.ROBOTS, subsystem.plant.model)()
    return ArmFrames(description.dh, subsystem.plant.model)
