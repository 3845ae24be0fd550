"""ROS 2 joint states out: the arm's joints as `sensor_msgs/msg/JointState` on a ROS 2 topic, over DDS.

Every cycle it copies `q_m`, `qd_m` and the effort into a buffer allocated in `init`, with the
Unix time of the copy, and wakes its publisher thread (an eventfd write); the cycle does no DDS
call. The thread, running below the RTPU's executive, builds the message (names `joint_names`,
or `joint1`..`jointN` as `arm_model` names the joints) and writes it as a ROS 2 node's publisher
would: DDS topic `rt/<topic>`, type `sensor_msgs::msg::dds_::JointState_`, ROS 2's default QoS, on
the domain `domain` (-1: ROS_DOMAIN_ID, else 0). A thread that falls behind publishes the newest
copy once for the cycles it missed (`skipped` counts them). Needs the 'ros2' extra (cyclonedds).
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass

import numpy as np
from numpy import copyto

from pbo_runtime import InVar, PortBasedObject, Status, below_the_cycle, param, ros2_messages


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
        self._rows = np.zeros((3, joints))  # position, velocity, effort: the cycle's copy
        self._copies = tuple(zip(sources, self._rows, strict=True))  # (port, its row): the views made once
        self._stamp = np.zeros(1, dtype=np.int64)  # its Unix time, ns
        self._lock = threading.Lock()
        self._acquire, self._release = self._lock.acquire, self._lock.release
        self._wake = os.eventfd(0, os.EFD_CLOEXEC)
        self._stopping = False
        self.published = 0
        self.skipped = 0  # cycles whose copy was replaced before the thread published it

        from cyclonedds.domain import DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        self._participant: DomainParticipant | None = DomainParticipant(ros2.domain_id(params.domain))
        topic = Topic(self._participant, ros2.dds_topic(params.topic), ros2.JointState, qos=ros2.ros2_qos())
        writer = DataWriter(self._participant, topic, qos=ros2.ros2_qos())
        message = ros2.JointState(header=ros2.Header(frame_id=params.frame_id), name=names)
        self._thread = threading.Thread(target=self._publish, args=(writer, message), daemon=True,
                                        name=f"ros2-{self.task_name}")
        self._thread.start()

    def cycle(self) -> Status:
        (position, position_row), (velocity, velocity_row), (effort, effort_row) = self._copies
        self._acquire()  # (bound once: `with lock` makes its method objects each time)
        copyto(position_row, position)
        copyto(velocity_row, velocity)
        copyto(effort_row, effort)
        self._stamp[0] = time.time_ns()
        self._release()
        os.eventfd_write(self._wake, 1)
        return Status.CONTINUE

    def kill(self) -> None:
        self._stopping = True
        os.eventfd_write(self._wake, 1)
        self.hand_off(self._close, f"closing the ROS 2 publisher of {self.task_name}")

    def _close(self) -> None:
        self._thread.join()
        os.close(self._wake)
        self._participant = None  # deleting it ends its DDS entities

    def _publish(self, writer, message) -> None:  # type: ignore[no-untyped-def]
        below_the_cycle()
        staging = np.zeros_like(self._rows)
        stamp = message.header.stamp
        while True:
            wakes = os.eventfd_read(self._wake)  # waits without the GIL
            if self._stopping:
                return
            with self._lock:
                staging[...] = self._rows
                stamp_ns = int(self._stamp[0])
            stamp.sec, stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            message.position = staging[0].tolist()
            message.velocity = staging[1].tolist()
            message.effort = staging[2].tolist()
            writer.write(message)
            self.published += 1
            self.skipped += wakes - 1
