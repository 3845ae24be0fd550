"""Position-mode robot interface (TR Figures 12 and 13): the arm as a position-controlled robot.

Like `robot_torque` it is the only module that talks to the arm and publishes the robot's
constants NDOF, ARM and EE as out-consts and the measured joint state every cycle; but its input
is a joint position reference `q_r`, which the arm's own joint servo tracks (the simulated
arm's driver opened with `mode: position`). This is the interface the TR's visual servoing
configuration drives: the controllers above it compute where the joints should be, not torques.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from modules._robot_interface import RobotInterface
from modules._robot_limits import POSITION_TOLERANCE
from pbo_runtime import InVar, Status, param


@dataclass(frozen=True)
class RobotPositionParams:
    device: str = "arm"  # the YAML device this task opens (listed in its resources), mode: position
    position_tolerance: float = param(
        POSITION_TOLERANCE, at_least=0, at_most=1.0)  # rad (m): how far past its range a joint may go before it is a fault


class RobotPosition(RobotInterface):
    """Position-mode robot interface over a joint-level arm driver in position mode.

    `on` commands the position the arm is at before it releases the brakes, so the arm does not
    jump to a stale reference; `off` and `kill` engage the brakes. While the configuration is
    illegal, `stable_cycle` holds the position the arm had when it became so and ignores `q_r`.
    Every position commanded is within the joint's range and within its velocity limit times the
    period of the one before (where the robot gives a velocity limit); a joint past its velocity
    limit or range is a fault that brakes the arm. Real-time safe cycle: two driver calls and the
    limit checks, no allocation.
    """

    Params = RobotPositionParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {"device": {"kind": "arm", "mode": "position"}}

    q_r = InVar("q_r", shape=("NDOF",), doc="joint position reference the arm's servo tracks, rad")

    def init(self, params: RobotPositionParams) -> None:
        self._write = self.open_arm(params.device, "position", position_tolerance=params.position_tolerance).write_position
        n = self._arm.ndof
        self._hold = np.zeros(n)  # the position stable_cycle holds
        self._command = np.zeros(n)  # the position last commanded, within the limits
        self._step = self._limits.velocity * self.period  # the most a command moves in a period (inf: no velocity limit)

    def on(self) -> None:
        self._read(self.q_m, self.qd_m)
        self.watch_plant_from_now()
        self._limits.allow_from(self.q_m)
        self._command_held(self.q_m)  # hold where the arm is: q_r may be stale or another arm's
        self._arm.release_brakes()

    def cycle(self) -> Status:
        if not self.plant_moving(self._read(self.q_m, self.qd_m)):
            self._hold_still()  # the plant stopped stepping: hold what it last showed
            return Status.STABLE
        self._holding = False
        fault = self.diverged("q_r")
        if fault is not None:
            return fault
        self._limits.limit_position(self.q_r, self._command, self._step, out=self._command)
        self._write(self._command)
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
        self._command_held(self._hold)

    def _command_held(self, q: np.ndarray) -> None:
        """Command `q` as it is, within the range: the arm is already there."""
        np.maximum(q, self._limits.q_min, out=self._command)
        np.minimum(self._command, self._limits.q_max, out=self._command)
        self._write(self._command)
