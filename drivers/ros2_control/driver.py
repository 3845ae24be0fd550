"""An arm behind ros2_control, driven over DDS: its `/joint_states` in, effort or position commands out.

The driver `robot_torque` (`mode: torque`) or `robot_position` (`mode: position`) opens instead
of the simulated arm's (`devices: {arm: {driver: ros2_control, mode: torque}}`), so pbo's robot
interface, with its limits and its freshness rules, drives any arm that has a ros2_control
driver: the measured state comes from the robot's `sensor_msgs/msg/JointState` topic (joints
taken by name, in `joints`' order), and each `write_torque` (`write_position`) goes out as the
`std_msgs/msg/Float64MultiArray` a forward command controller takes
(`/forward_effort_controller/commands`, `/forward_position_controller/commands`), both as a ROS 2
node's topics on the DDS domain `domain` (-1: ROS_DOMAIN_ID, else 0).

No call of a cycle touches DDS, and no DDS work runs in the RTPU's process: a process of the
driver's own (drivers/ros2_control/dds_side.py, through `DdsProcess`) takes each
JointState into a record both share; opening the driver waits for the first (up to 5 s, else it
fails saying so), so no command is ever computed from a state never read. `read_state` copies the
newest out (no lock: a copy torn by a write in progress is dropped, the one before kept) and
returns its header stamp as the arm's time, so a `/joint_states` that stops is a plant that
stopped: the robot interface holds after `stall_after` seconds and the run says so; so it does
when that process ends, which the run says on stderr too. Once started, the process runs just
below every executive (`keep_up`): the arm's state is an input the robot interface needs fresh, and
behind every ordinary process of a loaded machine it would come late. `write_torque` writes the command into
another record and wakes the process (an eventfd write), which publishes it. With the brakes
engaged (the task off, held, in ERROR) no command goes out: the ros2_control side must then hold the
arm (a controller's command timeout or the drive's brakes), as a real drive holds when its commands
stop.

The arm's constants (ARM, EE) are the plant's robot: the subsystem's `plant:` names the same
robot model the ros2_control side drives. Needs the 'ros2' extra (cyclonedds).
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from drivers.mujoco_arm.registers import DeviceError, attach_registers
from drivers.ros2_control.dds_side import PUBLISHED, RECEIVED, REFUSED, state_size
from pbo_runtime import DdsProcess, DeviceDriver, ModuleError, ros2_messages, sleep_while_cycling

_OPTIONS = ("mode", "joint_states", "commands", "joints", "domain", "stall_after")
FIRST_STATE_PATIENCE = 5.0  # s the driver's opening waits for the first JointState (within the supervisor's 10 s for a spawn)


#: the forward command controller each mode's commands go to, unless `commands` names another topic
COMMAND_TOPICS = {"torque": "/forward_effort_controller/commands", "position": "/forward_position_controller/commands"}


class Ros2ControlArm(DeviceDriver):
    """options: `mode` (torque or position), `joint_states` (/joint_states), `commands` (the mode's forward
    controller: COMMAND_TOPICS), `joints` (names, default joint1..jointN), `domain` (-1), `stall_after`
    (s of silence before the arm counts as stopped, 0.01)."""

    KIND = "arm"  # what robot_torque opens, as mujoco_arm is
    OPTIONS = _OPTIONS
    OPTION_DEFAULTS: ClassVar[Mapping[str, Any]] = {
        "mode": "torque", "joint_states": "/joint_states", "commands": COMMAND_TOPICS["torque"],
        "joints": None, "domain": -1, "stall_after": 0.01,
    }

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise ValueError(f"unknown ros2_control driver option(s) {unknown}; valid options: {', '.join(_OPTIONS)}")
        if options.get("mode", "torque") not in COMMAND_TOPICS:
            raise ValueError("ros2_control driver mode must be torque (an effort controller) or position (a position "
                             f"controller), got: {options['mode']!r}")
        for key in ("joint_states", "commands"):
            topic = options.get(key, cls.OPTION_DEFAULTS[key])
            if not isinstance(topic, str) or not topic.strip("/"):
                raise ValueError(f"ros2_control driver option {key} must be a ROS 2 topic name, got: {topic!r}")
        joints = options.get("joints")
        if joints is not None and (not isinstance(joints, list) or not all(isinstance(j, str) and j for j in joints)
                                   or len(set(joints)) != len(joints)):
            raise ValueError(f"ros2_control driver option joints must be a list of distinct joint names, got: {joints!r}")
        domain = options.get("domain", -1)
        if not isinstance(domain, int) or isinstance(domain, bool) or not -1 <= domain <= 232:
            raise ValueError(f"ros2_control driver option domain must be an integer in [-1, 232], got: {domain!r}")
        stall = options.get("stall_after", cls.OPTION_DEFAULTS["stall_after"])
        if isinstance(stall, bool) or not isinstance(stall, (int, float)) or not 0 < stall <= 10:
            raise ValueError(f"ros2_control driver option stall_after must be seconds in (0, 10], got: {stall!r}")

    @classmethod
    def outside_device(cls, options: Mapping[str, Any]) -> str:
        """The arm it drives, as its commands' topic on its DDS domain: two devices naming one drive one arm."""
        domain = int(options.get("domain", -1))
        if domain < 0:  # as ros2_messages.domain_id reads it, without the 'ros2' extra
            text = os.environ.get("ROS_DOMAIN_ID", "").strip()
            domain = int(text) if text.isdigit() else 0
        topic = "/" + str(options.get("commands", cls.OPTION_DEFAULTS["commands"])).strip("/")
        return f"the arm commanded on {topic} (DDS domain {domain})"

    def __init__(self, registers: str, options: Mapping[str, Any]) -> None:
        super().__init__(registers, options)
        self.check_options(self.options)
        ros2 = ros2_messages("the ros2_control driver")

        self.mode: str = self.options.get("mode", "torque")
        regs = attach_registers(registers)  # the plant's robot: its constants only
        try:
            self._arm_table, self._ee = regs.arm.copy(), regs.ee.copy()
            self.ndof: int = regs.layout.ndof
        finally:
            regs.release()
        self.timestep: float = float(self.options.get("stall_after", 0.01)) / 3  # the robot interface's stall bound: 3 of these
        self._names = list(self.options.get("joints") or [f"joint{i + 1}" for i in range(self.ndof)])
        if len(self._names) != self.ndof:
            raise DeviceError(f"ros2_control driver: joints names {len(self._names)} joints, the robot has {self.ndof}")
        self._finite = np.zeros(self.ndof, dtype=bool)  # per element of a command: finite (filled per write)
        self._braked = True
        self._faults: list[dict[str, Any]] = []
        domain = ros2.domain_id(int(self.options.get("domain", -1)))
        setup = {"domain": domain, "joint_states": self.options.get("joint_states", "/joint_states"),
                 "commands": self.options.get("commands", COMMAND_TOPICS[self.mode]), "joints": self._names}
        try:
            self._dds = DdsProcess("drivers.ros2_control.dds_side", setup, [state_size(self.ndof), self.ndof],
                                   "ros2_control driver: its DDS",
                                   "the arm's state is stale from now on, and no command goes out", keep_up=True)
        except ModuleError as exc:
            raise DeviceError(str(exc)) from None
        self._state, self._command = self._dds.records
        self._state_sequence, self._read = self._state.sequence, self._state.read
        self._copy = np.zeros(state_size(self.ndof))  # the record copied out, kept only when whole
        self._kept = np.zeros(state_size(self.ndof))  # the newest whole copy: stamp, q, qd
        self._q, self._qd = self._kept[1:1 + self.ndof], self._kept[1 + self.ndof:]
        self._taken = 0  # the sequence number of the copy kept
        self._begin_command, self._end_command = self._command.begin, self._command.end
        self._command_values, self._wake = self._command.values, self._dds.wake
        self._wait_for_the_first_state(domain)

    @property
    def received(self) -> int:
        """JointStates taken."""
        return int(self._dds.counters[RECEIVED])

    @property
    def refused(self) -> int:
        """JointStates that lacked one of the joints."""
        return int(self._dds.counters[REFUSED])

    @property
    def published(self) -> int:
        """Commands published."""
        return int(self._dds.counters[PUBLISHED])

    def _wait_for_the_first_state(self, domain: int) -> None:
        """Open only an arm whose state is known: a command computed from a state never read would move it."""
        deadline = time.monotonic() + FIRST_STATE_PATIENCE
        while self.received == 0:
            if self._dds.ended:
                self.close()
                raise DeviceError(self._dds.ended)
            if time.monotonic() > deadline:
                self.close()
                topic = self.options.get("joint_states", "/joint_states")
                raise DeviceError(f"ros2_control driver: no JointState of the joints {self._names} on {topic} "
                                  f"(DDS domain {domain}) within {FIRST_STATE_PATIENCE:g} s: is the robot's "
                                  "ros2_control (its joint_state_broadcaster) running on that domain?")
            sleep_while_cycling(0.01)

    # constants --------------------------------------------------------------------------------

    def arm(self) -> np.ndarray:
        return self._arm_table.copy()

    def end_effector(self) -> np.ndarray:
        return self._ee.copy()

    # per cycle: no allocation, no DDS ------------------------------------------------------------

    def read_state(self, q_out: np.ndarray, qd_out: np.ndarray) -> float:
        """The newest JointState's positions and velocities; its stamp, s (0 before the first)."""
        if self._state_sequence[0] != self._taken and (taken := self._read(self._copy)) > 0:
            np.copyto(self._kept, self._copy)
            self._taken = taken
        np.copyto(q_out, self._q)
        np.copyto(qd_out, self._qd)
        stamp: float = self._kept[0]
        return stamp

    def write_torque(self, tau: np.ndarray) -> None:
        """Send joint efforts, N m, to the forward effort controller (with the brakes released). Torque mode only."""
        self._send("torque", tau)

    def write_position(self, q_cmd: np.ndarray) -> None:
        """Send joint positions, rad, to the forward position controller (with the brakes released). Position mode only."""
        self._send("position", q_cmd)

    def _send(self, mode: str, command: np.ndarray) -> None:
        if mode != self.mode:
            raise DeviceError(f"ros2_control driver: write_{mode} on an arm opened in {self.mode} mode (its option mode)")
        if np.count_nonzero(np.isfinite(command, out=self._finite)) != self.ndof:  # a non-finite command never goes out
            raise DeviceError(f"ros2_control driver: write_{mode} refused a command that is not finite ({command.tolist()})")
        if self._braked:
            return
        self._begin_command()
        np.copyto(self._command_values, command)
        self._end_command()
        self._wake()

    def release_brakes(self) -> None:
        self._braked = False

    def engage_brakes(self) -> None:
        self._braked = True  # no more commands: the ros2_control side holds the arm

    def brake_for_fault(self, message: str, command: str, at: float) -> None:
        self.engage_brakes()
        if len(self._faults) < 10:
            self._faults.append({"fault": message, "command": command, "at": at})

    def figures(self) -> dict[str, Any]:
        figures: dict[str, Any] = {"joint_states": self.received, "commands": self.published, "refused": self.refused}
        if self._dds.ended:
            figures["dds_process"] = self._dds.ended
        if self._faults:
            figures.update({**self._faults[0], "faults": list(self._faults)})
        return figures

    def close_now(self) -> Any:
        self._braked = True
        self._dds.hang_up()
        return self._dds.close

    def close(self) -> None:
        self.close_now()()
