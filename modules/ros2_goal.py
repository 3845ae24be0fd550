"""ROS 2 goal in: the newest `std_msgs/msg/Float64MultiArray` or `trajectory_msgs/msg/JointTrajectory`
of a ROS 2 topic into a state variable (a goal, or the object of a job), over DDS.

A thread of its own, running below the RTPU's executive, subscribes as a ROS 2 node would (DDS
topic `rt/<topic>`, the type's `pkg::msg::dds_::Type_` name, ROS 2's default QoS, on `domain`;
-1: ROS_DOMAIN_ID, else 0) and copies each message's values into a buffer allocated in `init`:
a Float64MultiArray's `data`, a JointTrajectory's last point's `positions` (the trajectory's end,
in `joint_names`' order when the message names the joints). The cycle does no DDS call: it copies
the newest values into its output when a new message came. A message of another size than the
output is refused (counted in `refused`), never written.

Before the first message the output keeps its initial value. `fresh_within` (seconds, 0: never)
bounds how long it may go without a new message, on this task's own clock from the cycle that got
the last one: past it, before the first message too, its cycle returns `Status.STABLE`, so the
critical tasks of its configuration hold until a message comes (docs/faults.md). A goal sent once
(`ros2 topic pub --once`) wants 0; a stream of set points, a bound. Needs the 'ros2' extra.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from numpy import copyto

from pbo_runtime import OutVar, PortBasedObject, Status, below_the_cycle, param, ros2_messages

TYPES = ("std_msgs/msg/Float64MultiArray", "trajectory_msgs/msg/JointTrajectory")
WAIT = 1_000_000_000  # ns the thread waits for a message or its kill before it looks again


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
        self._names = list(params.joint_names) or [f"joint{i + 1}" for i in range(size)]
        if len(self._names) != size:
            raise ValueError(f"joint_names must name the {size} values of the output, got {len(self._names)}: {self._names}")
        self._staging = np.zeros(size)  # the thread's newest values
        self._value_flat = self._value.reshape(-1)  # a view of the output, made once
        self._lock = threading.Lock()
        self._acquire, self._release = self._lock.acquire, self._lock.release
        self._received = 0  # messages the thread copied in
        self._taken = 0  # of them, the count when the cycle last copied out
        self.refused = 0  # messages of another size than the output
        self._fresh_within = float(params.fresh_within) if params.fresh_within > 0 else math.inf
        self._new_at = -math.inf
        self._stopping = False

        from cyclonedds.core import GuardCondition, InstanceState, ReadCondition, SampleState, ViewState, WaitSet
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self._participant: DomainParticipant | None = DomainParticipant(ros2.domain_id(params.domain))
        kind = ros2.MESSAGES[params.type]
        topic = Topic(self._participant, ros2.dds_topic(params.topic), kind, qos=ros2.ros2_qos())
        reader = DataReader(self._participant, topic, qos=ros2.ros2_qos())
        # kept: `ros2 node list` sees it
        self._node = ros2.announce_node(self._participant, f"pbo_{self.task_name}", readers=[reader])
        self._waitset = WaitSet(self._participant)  # its wait releases the GIL: the thread sleeps until a message or kill
        self._waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))
        self._wake = GuardCondition(self._participant)
        self._waitset.attach(self._wake)
        self._thread = threading.Thread(target=self._receive, args=(reader, kind, ros2.goal_values), daemon=True,
                                        name=f"ros2-{self.task_name}")
        self._thread.start()

    def on(self) -> None:
        self._new_at = -math.inf if self._received == 0 else self.time  # a bound counts from now, not from before off

    def cycle(self) -> Status:
        if self._received != self._taken:
            self._acquire()  # (bound once: `with lock` makes its method objects each time)
            copyto(self._value_flat, self._staging)
            self._taken = self._received
            self._release()
            self._new_at = self.time
        if self.time - self._new_at > self._fresh_within:
            return Status.STABLE  # no new message for too long: what this task writes is stale
        return Status.CONTINUE

    def kill(self) -> None:
        self._stopping = True
        self._wake.set(True)
        self.hand_off(self._close, f"closing the ROS 2 subscription of {self.task_name}")

    def _close(self) -> None:
        self._thread.join()
        self._node = None
        self._participant = None  # deleting it ends its DDS entities

    def _receive(self, reader, kind, values_of) -> None:  # type: ignore[no-untyped-def]
        below_the_cycle()
        size = self._staging.size
        while not self._stopping:
            self._waitset.wait(WAIT)
            for sample in reader.take(N=16):
                if not isinstance(sample, kind):
                    continue  # a writer's end (DDS's invalid sample), not a message
                values = values_of(sample, self._names)
                if len(values) != size or not all(math.isfinite(v) for v in values):
                    self.refused += 1
                    continue
                with self._lock:
                    self._staging[:] = values
                    self._received += 1
