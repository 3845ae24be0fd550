"""Position-mode robot interface (TR Figures 12 and 13): the arm as a position-controlled robot.

Like `robot_torque` it is the only module that talks to the arm and publishes the robot's
constants NDOF, DH and DYN as out-consts and the measured joint state every cycle; but its input
is a joint position reference `q_r`, which the arm's own joint servo tracks (the simulated
arm's driver opened with `mode: position`). This is the interface the TR's visual servoing
configuration drives: the controllers above it compute where the joints should be, not torques.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pbo_runtime import InVar, ModuleError, OutConst, OutVar, PortBasedObject, Status


@dataclass(frozen=True)
class RobotPositionParams:
    device: str = "arm"  # the YAML device this task opens (listed in its resources), mode: position


class RobotPosition(PortBasedObject):
    """Position-mode robot interface over a joint-level arm driver in position mode.

    `on` commands the position the arm is at before it releases the brakes, so the arm does not
    jump to a stale reference; `off` and `kill` engage the brakes. While the configuration is
    illegal, `stable_cycle` holds the position the arm had when it became so and ignores `q_r`.
    Real-time safe cycle: two driver calls, no allocation.
    """

    Params = RobotPositionParams

    ndof = OutConst("NDOF", dtype="int32", doc="number of joints")
    dh = OutConst("DH", shape=("NDOF", 4), doc="DH rows (theta offset, d, a, alpha), m and rad")
    dyn = OutConst("DYN", shape=("NDOF", 11), doc="mass, COM, inertia about COM, armature per link (SI)")
    q_m = OutVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    qd_m = OutVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s")
    q_r = InVar("q_r", shape=("NDOF",), doc="joint position reference the arm's servo tracks, rad")

    def init(self, params: RobotPositionParams) -> None:
        self._arm = self.open_device(params.device)
        mode = getattr(self._arm, "mode", None)
        if mode != "position":
            raise ModuleError(
                f"the arm on device '{params.device}' is opened in {mode} mode; RobotPosition needs the device's "
                "option mode: position"
            )
        if self._arm.ndof != self.q_m.shape[0]:
            raise ModuleError(
                f"the arm on device '{params.device}' has {self._arm.ndof} joints, but the configuration says NDOF = {self.q_m.shape[0]}"
            )
        self.ndof = self._arm.ndof
        self.dh = self._arm.dh()
        self.dyn = self._arm.dynamics()
        self._read = self._arm.read_state
        self._write = self._arm.write_position
        self._hold = np.zeros(self._arm.ndof)  # the position stable_cycle holds
        self._holding = False

    def on(self) -> None:
        self._read(self.q_m, self.qd_m)
        self._write(self.q_m)  # hold where the arm is: q_r may be stale or another arm's
        self._arm.release_brakes()

    def cycle(self) -> Status:
        self._holding = False
        self._write(self.q_r)
        self._read(self.q_m, self.qd_m)
        return Status.CONTINUE

    def stable_cycle(self) -> Status:
        """Locally stable while the configuration is illegal: hold the position of that moment."""
        if not self._holding:
            self._holding = True
            self._read(self.q_m, self.qd_m)
            np.copyto(self._hold, self.q_m)
        self._write(self._hold)
        self._read(self.q_m, self.qd_m)
        return Status.CONTINUE

    def off(self) -> None:
        self._arm.engage_brakes()

    def kill(self) -> None:
        arm = getattr(self, "_arm", None)
        if arm is not None:
            arm.engage_brakes()
