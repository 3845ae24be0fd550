"""Torque-mode robot interface (TR Figure 8): the only module that talks to the arm.

It publishes the robot's constants NDOF, ARM and EE as out-consts (TR §4.3: swap this module
and the rest of the task set reconfigures itself for another robot), the measured joint
state every cycle, and sends the control signal `tau_u` to the arm's driver.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from modules._robot_interface import RobotInterface
from modules._robot_limits import POSITION_TOLERANCE, SATURATION_BOUND
from pbo_runtime import InVar, Status, param


@dataclass(frozen=True)
class RobotTorqueParams:
    device: str = "arm"  # the YAML device this task opens (listed in its resources)
    saturation_bound: float = param(
        SATURATION_BOUND, above=0, at_most=10.0)  # s: a torque at its effort limit longer than this is a fault
    position_tolerance: float = param(
        POSITION_TOLERANCE, at_least=0, at_most=1.0)  # rad (m): how far past its range a joint may go before it is a fault


class RobotTorque(RobotInterface):
    """Torque-mode robot interface over a joint-level arm driver.

    Brakes are released on `on` and engaged on `off` and `kill`, so the arm holds still
    whenever no controller drives it, and while the plant has stopped stepping. `tau_u` is clipped
    to the effort limits before the driver; a torque at its limit past `saturation_bound` (held there, or
    coming back to it in a limit cycle), or a joint past its velocity limit or range, is a fault that
    brakes the arm. Real-time safe cycle:
    two driver calls and the limit checks, no allocation.
    """

    Params = RobotTorqueParams
    DEVICES: ClassVar[Mapping[str, Mapping[str, Any]]] = {"device": {"kind": "arm", "mode": "torque"}}

    tau_u = InVar("tau_u", shape=("NDOF",), doc="joint torque command, N m")

    def init(self, params: RobotTorqueParams) -> None:
        self._write = self.open_arm(params.device, "torque", params.saturation_bound, params.position_tolerance).write_torque
        self._tau = np.zeros(self._arm.ndof)  # tau_u within the effort limits: what the driver is given
        self._tau_u = self.tau_u  # the port's array, the task's for its life

    def on(self) -> None:
        self._read(self.q_m, self.qd_m)
        self.watch_plant_from_now()
        self._limits.reset()
        self._limits.allow_from(self.q_m)
        self._arm.release_brakes()

    def cycle(self) -> Status:
        now = self.time
        if not self.plant_moving(self._read(*self._measured), now):
            self._hold()  # the plant stopped stepping: a torque now would be applied on a state nobody saw
            return Status.STABLE
        if self._holding:  # back from locally stable behaviour: a controller drives the arm again
            self._holding = False
            self._arm.release_brakes()
        fault = self.diverged("tau_u")
        if fault is not None:
            return fault
        limits = self._limits
        if limits.saturate_torque(self._tau_u, self._tau, now) and limits.saturated_too_long():
            return self.divergence_fault(limits.saturation_message(self.tau_u, "tau_u", self.period, self.time), "tau_u")
        self._write(self._tau)
        return Status.CONTINUE

    def _hold(self) -> None:
        if not self._holding:
            self._holding = True
            self._limits.reset()
            self._arm.engage_brakes()

    def stable_cycle(self) -> Status:
        """Locally stable while the configuration is illegal or tau_u is stale: the brakes hold the arm still."""
        self._hold()
        self._read(self.q_m, self.qd_m)
        return Status.CONTINUE
