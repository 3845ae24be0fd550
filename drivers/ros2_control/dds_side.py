"""The ros2_control driver's DDS side, in a process of its own: the robot's JointStates in, commands out.

Run by the driver as `python -m drivers.ros2_control.dds_side` through `DdsProcess`. Record 0 (the
child writes it): the newest JointState's header stamp (s), then its positions and velocities, the
joints taken by name in the driver's order. Record 1 (the driver writes it, then wakes the child):
the newest command, published as a `std_msgs/msg/Float64MultiArray`. A JointState that lacks one of
the joints, or whose positions do not match its names, is refused: counted, and said on the run's
stderr (the first, then each tenfold count).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pbo_runtime import ros2_messages, serve_dds_process

RECEIVED, REFUSED, PUBLISHED = 0, 1, 2  # the child's counters


def state_size(joints: int) -> int:
    """Record 0's values: the stamp, then q and qd."""
    return 1 + 2 * joints


def start(child: Any) -> None:
    """Make the node's reader and writer; take each JointState into record 0, publish record 1 at each wake."""
    setup = child.setup
    ros2 = ros2_messages("the ros2_control driver")
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    participant = DomainParticipant(setup["domain"])
    qos = ros2.ros2_qos()
    reader = DataReader(participant, Topic(participant, ros2.dds_topic(setup["joint_states"]), ros2.JointState, qos=qos),
                        qos=qos)
    writer = DataWriter(participant, Topic(participant, ros2.dds_topic(setup["commands"]), ros2.Float64MultiArray, qos=qos),
                        qos=qos)
    child.keep(participant, ros2.announce_node(participant, "pbo_ros2_control", readers=[reader], writers=[writer]))
    (state, command), counters, names = child.records, child.counters, setup["joints"]
    joints = len(names)

    def take(sample: Any) -> None:
        try:
            order = [sample.name.index(name) for name in names]
            q = [sample.position[i] for i in order]
            qd = [sample.velocity[i] for i in order] if len(sample.velocity) == len(sample.name) else [0.0] * joints
        except (ValueError, IndexError):
            child.refuse(REFUSED, lambda refused: f"ros2_control driver: refused a JointState on {setup['joint_states']} "
                                                  f"(names {list(sample.name)}, {len(sample.position)} positions; it needs "
                                                  f"the joints {names}); {refused} refused so far")
            return
        state.begin()
        state.values[0] = sample.header.stamp.sec + sample.header.stamp.nanosec * 1e-9
        state.values[1:1 + joints] = q
        state.values[1 + joints:] = qd
        state.end()
        counters[RECEIVED] += 1

    child.take_in_thread(participant, reader, ros2.JointState, take)
    staging = np.zeros(joints)
    message = ros2.Float64MultiArray()

    def publish() -> None:
        command.read_settled(staging)
        message.data = staging.tolist()
        writer.write(message)
        counters[PUBLISHED] += 1

    child.on_wake = publish


if __name__ == "__main__":
    serve_dds_process(start)
