"""ROS 2 joint states out: the arm's joints as `sensor_msgs/msg/JointState` on a ROS 2 topic, over DDS.

Every cycle it copies `q_m`, `qd_m` and the effort, with the Unix time of the copy, into a record
it shares with its publisher process (modules/_joint_states_publisher.py, through `DdsProcess`)
and wakes that process; the cycle does no DDS call, and no DDS work or encoding runs in the RTPU's
process to take its GIL. If that process ends, the run says so on stderr and nothing is published.
The publisher, a ROS 2 node named `pbo_<task>`, builds the message (names `joint_names`, or
`joint1`..`jointN` as `arm_model` names the joints) and writes it as a ROS 2 node's publisher would:
DDS topic `rt/<topic>`, type `sensor_msgs::msg::dds_::JointState_`, ROS 2's default QoS, on the
domain `domain` (-1: ROS_DOMAIN_ID, else 0). A publisher that falls behind publishes the newest
record once for the cycles it missed. Needs the 'ros2' extra (cyclonedds).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from numpy import copyto

from modules._joint_states_publisher import record_size
from pbo_runtime import DdsProcess, InVar, PortBasedObject, Status, param, ros2_messages


@dataclass(frozen=True)
class Ros2JointStatesParams:
    topic: str = "/joint_states"  # the ROS 2 topic (DDS topic rt/joint_states)
    joint_names: tuple[str, ...] = ()  # the joints' names in the message, in q_m's order; none: joint1..jointN
    frame_id: str = ""  # the header's frame_id
    domain: int = param(-1, at_least=-1, at_most=232)  # the DDS domain; -1: ROS_DOMAIN_ID, else 0

    def __post_init__(self) -> None:
        if not isinstance(self.topic, str) or not self.topic:
            raise ValueError(f"topic must be a ROS 2 topic name, got: {self.topic!r}")
        if len(set(self.joint_names)) != len(self.joint_names) or not all(self.joint_names):
            raise ValueError(f"joint_names must be distinct, non-empty names, got: {list(self.joint_names)}")


class Ros2JointStates(PortBasedObject):
    """Publishes q_m, qd_m and tau as a ROS 2 `sensor_msgs/msg/JointState` every cycle (stamped, Unix time)."""

    Params = Ros2JointStatesParams
    q_m = InVar("q_m", shape=("NDOF",), doc="measured joint position, rad: the message's position")
    qd_m = InVar("qd_m", shape=("NDOF",), doc="measured joint velocity, rad/s: the message's velocity")
    tau = InVar("tau", shape=("NDOF",), doc="joint torque, N m: the message's effort")

    def init(self, params: Ros2JointStatesParams) -> None:
        ros2 = ros2_messages("the ros2_joint_states module")

        ros2.check_topic(params.topic)
        sources = self.bound_arrays[:3]
        joints = sources[0].size
        names = list(params.joint_names) or [f"joint{i + 1}" for i in range(joints)]
        if len(names) != joints:
            raise ValueError(f"joint_names must name the {joints} joints of q_m, got {len(names)}: {names}")
        setup = {"domain": ros2.domain_id(params.domain), "topic": params.topic, "names": names,
                 "frame_id": params.frame_id, "node": f"pbo_{self.task_name}"}
        self._publisher = DdsProcess("modules._joint_states_publisher", setup, [record_size(joints)],
                                     f"task '{self.task_name}': its JointState publisher", f"{params.topic} is not published")
        record = self._publisher.records[0]
        # (port, its row in the record): the views made once
        self._copies = tuple(zip(sources, record.values[1:].reshape(3, joints), strict=True))
        self._stamp = record.words[:1]  # the record's Unix time, ns
        self._begin, self._end, self._wake = record.begin, record.end, self._publisher.wake

    def cycle(self) -> Status:
        (position, position_row), (velocity, velocity_row), (effort, effort_row) = self._copies
        self._begin()
        copyto(position_row, position)
        copyto(velocity_row, velocity)
        copyto(effort_row, effort)
        self._stamp[0] = time.time_ns()
        self._end()
        self._wake()
        return Status.CONTINUE

    def kill(self) -> None:
        self.hand_off(self._publisher.close, f"closing the ROS 2 publisher of {self.task_name}")
