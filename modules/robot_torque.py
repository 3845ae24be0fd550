"""Torque-mode robot interface (TR Figure 8): the only module that talks to the arm.

It publishes the robot's constants NDOF, DH and DYN as out-consts (TR §4.3: swap this module
and the rest of the task set reconfigures itself for another robot), the measured joint
state every cycle, and sends the control signal `tau_u` to the arm's driver.
"""

from __future__ import annotations

from dataclasses import dataclass

from pbo_runtime import InVar, ModuleError, OutConst, OutVar, PortBasedObject, Status


@dataclass(frozen=True)
class RobotTorqueParams:
    device: str = "arm"  # the YAML device this task opens (listed in its resources)


class RobotTorque(PortBasedObject):
    """Torque-mode robot interface over a joint-level arm driver.

    Brakes are released on `on` and engaged on `off` and `kill`, so the arm holds still
    whenever no controller drives it. Real-time safe cycle: two driver calls, no allocation.
    """

    Params = RobotTorqueParams

    ndof = OutConst("NDOF", dtype="int32", doc="number of joints")
    dh = OutConst("DH", shape=("NDOF", 4), doc="DH rows (theta offset, d, a, alpha), m and rad")
    dyn = OutConst("DYN", shape=("NDOF", 11), doc="mass, COM, inertia about COM, armature per link (SI)")
    q_m = OutVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    qd_m = OutVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s")
    tau_u = InVar("tau_u", shape=("NDOF",), doc="joint torque command, N m")

    def init(self, params: RobotTorqueParams) -> None:
        self._arm = self.open_device(params.device)
        if self._arm.ndof != self.q_m.shape[0]:
            raise ModuleError(
                f"the arm on device '{params.device}' has {self._arm.ndof} joints, but the configuration says NDOF = {self.q_m.shape[0]}"
            )
        self.ndof = self._arm.ndof
        self.dh = self._arm.dh()
        self.dyn = self._arm.dynamics()
        self._read = self._arm.read_state
        self._write = self._arm.write_torque
        self._holding = False

    def on(self) -> None:
        self._read(self.q_m, self.qd_m)
        self._arm.release_brakes()

    def cycle(self) -> Status:
        if self._holding:  # back from locally stable behaviour: a controller drives the arm again
            self._holding = False
            self._arm.release_brakes()
        self._write(self.tau_u)
        self._read(self.q_m, self.qd_m)
        return Status.CONTINUE

    def stable_cycle(self) -> Status:
        """Locally stable while the configuration is illegal: the brakes hold the arm still."""
        if not self._holding:
            self._holding = True
            self._arm.engage_brakes()
        self._read(self.q_m, self.qd_m)
        return Status.CONTINUE

    def off(self) -> None:
        self._arm.engage_brakes()

    def kill(self) -> None:
        arm = getattr(self, "_arm", None)
        if arm is not None:
            arm.engage_brakes()
