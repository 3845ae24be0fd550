"""ROS 2 goal in: the newest `std_msgs/msg/Float64MultiArray` or `trajectory_msgs/msg/JointTrajectory`
of a ROS 2 topic into a state variable (a goal, or the object of a job), over DDS.

A process of its own (modules/_ros2_goal_subscriber.py, through `DdsProcess`, at SCHED_OTHER)
subscribes as a ROS 2 node would (DDS topic `rt/<topic>`, the type's `pkg::msg::dds_::Type_` name,
ROS 2's default QoS, on `domain`; -1: ROS_DOMAIN_ID, else 0) and writes each message's values into
a record both share: a Float64MultiArray's `data`, a JointTrajectory's last point's `positions`
(the trajectory's end, in `joint_names`' order when the message names the joints). The cycle does
no DDS call and takes no lock: when the record's sequence number moved, it copies the record out
(a copy torn by a write in progress is dropped and taken the next cycle). A message of another
size than the output is refused (counted in `refused`, said on stderr), never written.

Before the first message the output keeps its initial value. `fresh_within` (seconds, 0: never)
bounds how long it may go without a new message, on this task's own clock from the cycle that got
the last one: past it, before the first message too, its cycle returns `Status.STABLE`, so the
critical tasks of its configuration hold until a message comes (docs/faults.md). A goal sent once
(`ros2 topic pub --once`) wants 0; a stream of set points, a bound. If the subscriber process
ends, the run says so on stderr and the output is stale from then on, whatever the bound.
Needs the 'ros2' extra.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy import copyto

from modules._ros2_goal_subscriber import REFUSED
from pbo_runtime import DdsProcess, OutVar, PortBasedObject, Status, param, ros2_messages

TYPES = ("std_msgs/msg/Float64MultiArray", "trajectory_msgs/msg/JointTrajectory")


@dataclass(frozen=True)
class Ros2GoalParams:
    topic: str = "/pbo/q_d"  # the ROS 2 topic (DDS topic rt/pbo/q_d)
    type: str = TYPES[0]  # the message type: std_msgs/msg/Float64MultiArray or trajectory_msgs/msg/JointTrajectory
    joint_names: tuple[str, ...] = ()  # a JointTrajectory's joints in the output's order; none: joint1..jointN
    fresh_within: float = param(0.0, at_least=0, at_most=3600)  # s without a new message before the critical tasks hold; 0: never
    domain: int = param(-1, at_least=-1, at_most=232)  # the DDS domain; -1: ROS_DOMAIN_ID, else 0

    def __post_init__(self) -> None:
        if not isinstance(self.topic, str) or not self.topic:
            raise ValueError(f"topic must be a ROS 2 topic name, got: {self.topic!r}")
        if self.type not in TYPES:
            raise ValueError(f"type must be one of {', '.join(TYPES)}, got: {self.type!r}")
        if len(set(self.joint_names)) != len(self.joint_names) or not all(self.joint_names):
            raise ValueError(f"joint_names must be distinct, non-empty names, got: {list(self.joint_names)}")
        if not math.isfinite(self.fresh_within) or self.fresh_within < 0:
            raise ValueError(f"fresh_within must be seconds >= 0 (0: never), got: {self.fresh_within!r}")


class Ros2Goal(PortBasedObject):
    """Writes the newest message of `topic` to `value` every cycle it brings one (`ports: {value: q_d}`)."""

    Params = Ros2GoalParams
    value = OutVar("value", shape=None, doc="the values of the newest message (a goal, or a job's object)")

    def init(self, params: Ros2GoalParams) -> None:
        ros2 = ros2_messages("the ros2_goal module")

        ros2.check_topic(params.topic)
        self._value = self.bound_arrays[0]
        size = self._value.size
        names = list(params.joint_names) or [f"joint{i + 1}" for i in range(size)]
        if len(names) != size:
            raise ValueError(f"joint_names must name the {size} values of the output, got {len(names)}: {names}")
        self._fresh_within = float(params.fresh_within) if params.fresh_within > 0 else math.inf
        self._new_at = -math.inf
        setup = {"domain": ros2.domain_id(params.domain), "topic": params.topic, "type": params.type, "names": names,
                 "node": f"pbo_{self.task_name}", "who": f"task '{self.task_name}'"}
        self._subscriber = DdsProcess("modules._ros2_goal_subscriber", setup, [size],
                                      f"task '{self.task_name}': its ROS 2 subscriber",
                                      f"{params.topic} is a stale input from now on")
        self._record = self._subscriber.records[0]
        self._sequence = self._record.sequence  # the record's number: moved when a message came
        self._read = self._record.read
        self._copy = np.zeros(size)  # the record copied out, kept only when whole
        self._value_flat = self._value.reshape(-1)  # a view of the output, made once
        self._taken = 0  # the sequence number of the values last written out (0: none yet)

    @property
    def refused(self) -> int:
        """Messages of another size than the output (or not finite), never written."""
        return int(self._subscriber.counters[REFUSED])

    def on(self) -> None:
        self._new_at = -math.inf if self._taken == 0 else self.time  # a bound counts from now, not from before off

    def cycle(self) -> Status:
        if self._sequence[0] != self._taken and (taken := self._read(self._copy)) > 0:
            copyto(self._value_flat, self._copy)
            self._taken = taken
            self._new_at = self.time
        if self.time - self._new_at > self._fresh_within or self._subscriber.ended:
            return Status.STABLE  # no new message for too long, or none can come: what this task writes is stale
        return Status.CONTINUE

    def kill(self) -> None:
        self._subscriber.hang_up()
        self.hand_off(self._subscriber.close, f"closing the ROS 2 subscription of {self.task_name}")
