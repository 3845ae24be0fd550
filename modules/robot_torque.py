"""Torque-mode robot interface (TR Figure 8): the only module that talks to the arm.

It publishes the robot's constants NDOF, ARM and EE as out-consts (TR §4.3: swap this module
and the rest of the task set reconfigures itself for another robot), the measured joint
state every cycle, and sends the control signal `tau_u` to the arm's driver.
"""

from __future__ import annotations

from dataclasses import dataclass

from modules._robot_interface import RobotInterface
from pbo_runtime import InVar, Status


@dataclass(frozen=True)
class RobotTorqueParams:
    device: str = "arm"  # the YAML device this task opens (listed in its resources)


class RobotTorque(RobotInterface):
    """Torque-mode robot interface over a joint-level arm driver.

    Brakes are released on `on` and engaged on `off` and `kill`, so the arm holds still
    whenever no controller drives it, and while the plant has stopped stepping. Real-time safe
    cycle: two driver calls, no allocation.
    """

    Params = RobotTorqueParams
    DEVICES = {"device": {"mode": "torque"}}

    tau_u = InVar("tau_u", shape=("NDOF",), doc="joint torque command, N m")

    def init(self, params: RobotTorqueParams) -> None:
        self._write = self.open_arm(params.device, mode="torque").write_torque

    def on(self) -> None:
        self._read(self.q_m, self.qd_m)
        self.watch_plant_from_now()
        self._arm.release_brakes()

    def cycle(self) -> Status:
        if not self.plant_moving(self._read(self.q_m, self.qd_m)):
            self._hold()  # the plant stopped stepping: a torque now would be applied on a state nobody saw
            return Status.STABLE
        if self._holding:  # back from locally stable behaviour: a controller drives the arm again
            self._holding = False
            self._arm.release_brakes()
        self._write(self.tau_u)
        return Status.CONTINUE

    def _hold(self) -> None:
        if not self._holding:
            self._holding = True
            self._arm.engage_brakes()

    def stable_cycle(self) -> Status:
        """Locally stable while the configuration is illegal or tau_u is stale: the brakes hold the arm still."""
        self._hold()
        self._read(self.q_m, self.qd_m)
        return Status.CONTINUE
