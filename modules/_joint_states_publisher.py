"""The JointState publisher of `ros2_joint_states`: the DDS side, in a process of its own.

Run by the task as `python -m modules._joint_states_publisher` through `DdsProcess`: its one record
is the Unix time of the cycle's copy (ns, an int64 word) then position, velocity and effort, a row
each. At each wake it publishes the newest record once; wakes that came meanwhile fold into it
(counted in SKIPPED).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pbo_runtime import ros2_messages, serve_dds_process

PUBLISHED, SKIPPED = 0, 1  # the child's counters


def record_size(joints: int) -> int:
    """The record's values: the stamp's word, then 3 rows of `joints`."""
    return 1 + 3 * joints


def start(child: Any) -> None:
    """Make the node's writer; at each wake, publish the newest record."""
    setup = child.setup
    ros2 = ros2_messages("the ros2_joint_states module")
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    participant = DomainParticipant(setup["domain"])
    topic = Topic(participant, ros2.dds_topic(setup["topic"]), ros2.JointState, qos=ros2.ros2_qos())
    writer = DataWriter(participant, topic, qos=ros2.ros2_qos())
    child.keep(participant, ros2.announce_node(participant, setup["node"], writers=[writer]))
    record, counters, joints = child.records[0], child.counters, len(setup["names"])
    copy = np.zeros(record_size(joints))
    stamp_ns, rows = copy[:1].view(np.int64), copy[1:].reshape(3, joints)
    message = ros2.JointState(header=ros2.Header(frame_id=setup["frame_id"]), name=setup["names"])
    stamp = message.header.stamp
    last = [0]

    def publish() -> None:
        sequence = record.read_settled(copy)
        counters[SKIPPED] += max(0, (sequence - last[0]) // 2 - 1)
        last[0] = sequence
        stamp.sec, stamp.nanosec = divmod(int(stamp_ns[0]), 1_000_000_000)
        message.position, message.velocity, message.effort = rows[0].tolist(), rows[1].tolist(), rows[2].tolist()
        writer.write(message)
        counters[PUBLISHED] += 1

    child.on_wake = publish


if __name__ == "__main__":
    serve_dds_process(start)
