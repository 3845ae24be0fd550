"""The subscriber of `ros2_goal`: the DDS side, in a process of its own.

Run by the task as `python -m modules._ros2_goal_subscriber` through `DdsProcess`. It subscribes as
a ROS 2 node would and writes each message's values (`goal_values`: a Float64MultiArray's `data`, a
JointTrajectory's last point's `positions` in the output's joint order) into its one record, sized
as the task's output. A message of another size, or with a value that is not finite, is refused:
counted, never written, and said on the run's stderr (the first, then each tenfold count).
"""

from __future__ import annotations

import math
from typing import Any

from pbo_runtime import ros2_messages, serve_dds_process

RECEIVED, REFUSED = 0, 1  # the child's counters


def start(child: Any) -> None:
    """Make the node's reader; write each message it takes into the record."""
    setup = child.setup
    ros2 = ros2_messages("the ros2_goal module")
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    participant = DomainParticipant(setup["domain"])
    kind = ros2.MESSAGES[setup["type"]]
    topic = Topic(participant, ros2.dds_topic(setup["topic"]), kind, qos=ros2.ros2_qos())
    reader = DataReader(participant, topic, qos=ros2.ros2_qos())
    child.keep(participant, ros2.announce_node(participant, setup["node"], readers=[reader]))  # `ros2 node list` sees it
    record, counters, names = child.records[0], child.counters, setup["names"]
    size = record.values.size

    def take(message: Any) -> None:
        values = ros2.goal_values(message, names)
        if len(values) != size or not all(math.isfinite(v) for v in values):
            child.refuse(REFUSED, lambda refused: f"{setup['who']} refused a {setup['type']} on {setup['topic']} "
                                                  f"({refusal(message, values, names)}); {refused} refused so far")
            return
        record.begin()
        record.values[:] = values
        record.end()
        counters[RECEIVED] += 1

    child.take_in_thread(participant, reader, kind, take)


def refusal(message: Any, values: list[float], names: list[str]) -> str:
    """Why a message was refused, in a few words."""
    if len(values) == len(names):
        return f"a value that is not finite: {values}"
    if not values and not isinstance(message, ros2_messages("the ros2_goal module").Float64MultiArray):
        return f"no point, or joints other than {names}"
    return f"{len(values)} values, the output takes {len(names)}"


if __name__ == "__main__":
    serve_dds_process(start)
