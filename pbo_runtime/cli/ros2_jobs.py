"""`pbo ros2 jobs JOB`: a ROS 2 node whose messages start a job of a live run, each with its values as the object.

A process of its own, beside the run (no DDS in any RTPU): it subscribes to a ROS 2 topic as a
ROS 2 node would (`pbo_jobs` on `ros_discovery_info`, ROS 2's default QoS, the domain
ROS_DOMAIN_ID names), and for each message asks the run's supervisor for `pbo job JOB VALUES`:
a `std_msgs/msg/Float64MultiArray`'s `data`, or a `trajectory_msgs/msg/JointTrajectory`'s last
point's `positions` (in `--joint-names`' order when the message names its joints). The
supervisor checks the object as for an operator (its size, its type's range) and switches to the
job's configuration; a refusal is printed and the node goes on listening.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from rich.console import Console

from pbo_runtime.cli.exits import EXIT_CONFIG
from pbo_runtime.errors import PboError
from pbo_runtime.ipc.control import BadRequest, CommandRefused, ControlClient
from pbo_runtime.links.ros2 import ros2_messages

TYPES = ("trajectory_msgs/msg/JointTrajectory", "std_msgs/msg/Float64MultiArray")
WAIT = 1_000_000_000  # ns a wait for a message lasts before it looks again (a Ctrl-C is seen between two)


def serve(args: argparse.Namespace, console: Console, errors: Console) -> int:
    ros2 = ros2_messages("pbo ros2 jobs")
    try:
        topic = ros2.check_topic(args.topic or f"/pbo/{args.job}")
    except ValueError as exc:
        errors.print(f"error: --topic: {exc}", markup=False)
        return EXIT_CONFIG
    client = ControlClient.connect(args.subsystem, args.run)
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    participant = DomainParticipant(ros2.domain_id(args.domain))
    kind = ros2.MESSAGES[args.type]
    reader = DataReader(participant, Topic(participant, ros2.dds_topic(topic), kind, qos=ros2.ros2_qos()), qos=ros2.ros2_qos())
    node = ros2.announce_node(participant, "pbo_jobs", readers=[reader])  # noqa: F841 (kept: later nodes get its sample)
    waitset = WaitSet(participant)
    waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))
    console.print(f"listening on {topic} ({args.type}, DDS domain {ros2.domain_id(args.domain)}): each message starts "
                  f"job '{args.job}' of '{client.subsystem}' (run {client.run_id})", markup=False)
    console.file.flush()
    while True:
        waitset.wait(WAIT)
        for sample in reader.take(N=16):
            if not isinstance(sample, kind):
                continue  # a writer's end (DDS's invalid sample), not a message
            if _start(client, args, ros2, sample, console, errors) and args.once:
                return 0


def _start(client: ControlClient, args: argparse.Namespace, ros2: Any, message: Any, console: Console, errors: Console) -> bool:
    """Ask for the job with the message's values; say what the supervisor answered. True: started."""
    if isinstance(message, ros2.Float64MultiArray):
        count = len(message.data)
    else:
        count = len(message.points[-1].positions) if message.points else 0
    names = list(args.joint_names or [f"joint{i + 1}" for i in range(count)])
    values = ros2.goal_values(message, names)
    if not values or not all(math.isfinite(v) for v in values):
        errors.print(f"refused a message: no finite values for the joints {names}", markup=False)
        return False
    try:
        reply = client.call("job", {"job": args.job, "object": values})
    except (BadRequest, CommandRefused) as exc:
        errors.print(f"refused: {exc}", markup=False)
        return False
    except PboError as exc:
        raise PboError(f"the run ended, or its supervisor does not answer: {exc}") from None
    console.print(f"job '{reply.get('job', args.job)}' started with {[round(v, 6) for v in values]} "
                  f"(configuration '{reply.get('configuration')}')", markup=False)
    console.file.flush()
    return True
