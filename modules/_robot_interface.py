"""What every robot interface module shares (TR §4.3): the arm's constants and measured state.

A robot interface is the only module that talks to the arm. It opens the arm's driver in
`init`, checks the joint count against the configuration, publishes NDOF, ARM and EE as
out-consts (so the rest of the task set configures itself for this robot), and engages the
brakes on `off` and `kill`. Subclasses add the command port and how the arm is commanded.

It also watches the plant: a measurement whose simulated time has not moved for
`PLANT_STALL_PERIODS` of the slower of the task and the plant's timestep (the plant process
stopped or starved) is not fresh, so the cycle holds the arm instead of commanding it and says
so (`Status.STABLE`) until the plant steps again.

Every command is clipped to the arm's limits before it reaches the driver, and leaving them is a
fault that brakes the arm (`_robot_limits`).
"""

from __future__ import annotations

from typing import Any

from modules._robot_limits import POSITION_TOLERANCE, SATURATION_BOUND, ArmLimits
from pbo_runtime import Arm, ModuleError, OutConst, OutVar, PortBasedObject, Status

PLANT_STALL_PERIODS = 3  # cycles (or plant steps, if slower) without a new step before the plant counts as stalled


class RobotInterface(PortBasedObject):
    """Base of robot_torque and robot_position: consts, measured state, brakes."""

    ndof = OutConst("NDOF", dtype="int32", doc="number of joints")
    arm_table = OutConst(
        "ARM", shape=("NDOF", Arm.WIDTH), doc="the arm's joint table: a row per joint (pbo_runtime.ARM_COLUMNS, SI)"
    )
    end_effector = OutConst("EE", shape=(Arm.EE_WIDTH,), doc="where the end effector is (pbo_runtime.EE_COLUMNS, m)")
    q_m = OutVar("q_m", shape=("NDOF",), doc="measured joint position, rad")
    qd_m = OutVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s")

    def open_arm(self, device: str, mode: str | None = None, saturation_bound: float = SATURATION_BOUND,
                 position_tolerance: float = POSITION_TOLERANCE) -> Any:
        """Open the arm, check its mode and joints, publish its constants, make its limits
        (`self._limits`); binds `self._read`."""
        self._arm = self.open_device(device)
        if mode is not None and getattr(self._arm, "mode", None) != mode:
            raise ModuleError(
                f"the arm on device '{device}' is opened in {getattr(self._arm, 'mode', None)} mode; "
                f"{type(self).__name__} needs the device's option mode: {mode}"
            )
        if self._arm.ndof != self.q_m.shape[0]:
            raise ModuleError(
                f"the arm on device '{device}' has {self._arm.ndof} joints, but the configuration says NDOF = {self.q_m.shape[0]}"
            )
        self.ndof = self._arm.ndof
        arm = self._arm.arm()
        self.arm_table = arm
        if not saturation_bound > 0 or not position_tolerance >= 0:
            raise ModuleError(f"saturation_bound must be > 0 s and position_tolerance >= 0, got: {saturation_bound!r}, "
                              f"{position_tolerance!r}")
        self._limits = ArmLimits(arm, self.period, saturation_bound, position_tolerance)
        self.end_effector = self._arm.end_effector()
        self._read = self._arm.read_state
        self._measured = self.q_m, self.qd_m  # the ports' arrays, the task's for its life: no port lookup per cycle
        self._holding = False
        self._plant_stall_after = PLANT_STALL_PERIODS * max(self.period, getattr(self._arm, "timestep", 0.0))
        self._last_sim_time = -1.0
        self._sim_time_seen_at = 0.0
        return self._arm

    def plant_moving(self, sim_time: float, now: float | None = None) -> bool:
        """False once the plant's simulated time has stood still past the stall bound (no allocation);
        `now`: the cycle's time, where the caller has read it already."""
        if now is None:
            now = self.time
        if sim_time != self._last_sim_time:
            self._last_sim_time = sim_time
            self._sim_time_seen_at = now
            return True
        return now - self._sim_time_seen_at <= self._plant_stall_after

    def diverged(self, command: str) -> Status | None:
        """ERROR, the arm braked, if the measured state left the arm's limits; None while within them."""
        if not self._limits.outside(*self._measured):
            return None
        return self.divergence_fault(self._limits.divergence_message(self.q_m, self.qd_m), command)

    def divergence_fault(self, message: str, command: str) -> Status:
        """Brake the arm for a divergence and say which: the run's summary names the writer of `command`."""
        self._arm.brake_for_fault(message, command, self.time)
        return self.fault(message)

    def watch_plant_from_now(self) -> None:
        """On `on`: the stall bound counts from this moment, not from before the task was off."""
        self._last_sim_time = -1.0

    def off(self) -> None:
        self._arm.engage_brakes()

    def error(self, exc: BaseException | None) -> Status:
        """A cycle failed (the driver refused a non-finite command, the plant stopped answering):
        the brakes hold the arm, which must not keep the last command, and the task waits in ERROR."""
        self._arm.engage_brakes()
        return Status.ERROR

    def kill(self) -> None:
        arm = getattr(self, "_arm", None)
        if arm is not None:
            arm.engage_brakes()
