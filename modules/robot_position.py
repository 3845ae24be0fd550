"""Position-mode robot interface (TR Figures 12 and 13): the arm as a position-controlled robot.

Like `robot_torque` it is the only module that talks to the arm and publishes the robot's
constants NDOF, ARM and EE as out-consts and the measured joint state every cycle; but its input
is a joint position reference `q_r`, which the arm's own joint servo tracks (the simulated
arm's driver opened with `mode: position`). This is the interface the TR's visual servoing
configuration drives: the controllers above it compute where the joints should be, not torques.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modules._robot_interface import RobotInterface
from pbo_runtime import InVar, Status


@dataclass(frozen=True)
class RobotPositionParams:
    device: str = "arm"  # the YAML device this task opens (listed in its resources), mode: position


class RobotPosition(RobotInterface):
    """Position-mode robot interface over a joint-level arm driver in position mode.

    `on` commands the position the arm is at before it releases the brakes, so the arm does not
    jump to a stale reference; `off` and `kill` engage the brakes. While the configuration is
    illegal, `stable_cycle` holds the position the arm had when it became so and ignores `q_r`.
    Real-time safe cycle: two driver calls, no allocation.
    """

    Params = RobotPositionParams
    DEVICES = {"device": {"mode": "position"}}

    q_r = InVar("q_r", shape=("NDOF",), doc="joint position reference the arm's servo tracks, rad")

    def init(self, params: RobotPositionParams) -> None:
        self._write = self.open_arm(params.device, mode="position").write_position
        self._hold = np.zeros(self._arm.ndof)  # the position stable_cycle holds

    def on(self) -> None:
        self._read(self.q_m, self.qd_m)
        self.watch_plant_from_now()
        self._write(self.q_m)  # hold where the arm is: q_r may be stale or another arm's
        self._arm.release_brakes()

    def cycle(self) -> Status:
        if not self.plant_moving(self._read(self.q_m, self.qd_m)):
            self._hold_still()  # the plant stopped stepping: hold what it last showed
            return Status.STABLE
        self._holding = False
        self._write(self.q_r)
        return Status.CONTINUE

    def stable_cycle(self) -> Status:
        """Locally stable while the configuration is illegal or q_r is stale: hold the position of that moment."""
        self._read(self.q_m, self.qd_m)
        self._hold_still()
        return Status.CONTINUE

    def _hold_still(self) -> None:
        if not self._holding:
            self._holding = True
            np.copyto(self._hold, self.q_m)
        self._write(self._hold)
