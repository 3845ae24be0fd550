"""A ROS 2 node's side of the DDS wire, for the bridge's tests: a Cyclone DDS participant of its own,
in a process of its own, with the message types declared as ROS 2's generated IDL declares them
(independently of pbo_runtime/links/ros2_messages.py) and ROS 2's default QoS.

    python -m tests.ros2_peer listen DOMAIN SECONDS           JointStates on rt/joint_states over a window
    python -m tests.ros2_peer goal DOMAIN SAFETY V1 V2 ...   publish a goal on rt/pbo/q_d until the arm holds it
    python -m tests.ros2_peer watch DOMAIN SAFETY V1 V2 ...  the same without publishing: until the arm holds V1 V2 ...
    python -m tests.ros2_peer publish DOMAIN TOPIC TYPE SECONDS V1 V2 ...   a message every 10 ms, then silence
      (JointTrajectory, JointState: the joints' numbers, then their positions)
    python -m tests.ros2_peer discovery DOMAIN NODE          the node on ros_discovery_info, its endpoints' topics

Each prints one JSON line with what it saw.
"""

import json
import sys
import time
from dataclasses import dataclass, field

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


# builtin_interfaces/msg/Time, std_msgs/msg/Header, sensor_msgs/msg/JointState, ... as rosidl's IDL has them
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: sequence[str]
    position: sequence[float64]
    velocity: sequence[float64]
    effort: sequence[float64]


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str
    size: uint32
    stride: uint32


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: sequence[MultiArrayDimension]
    data_offset: uint32


@dataclass
class Float64MultiArray(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: MultiArrayLayout
    data: sequence[float64]


@dataclass
class JointTrajectoryPoint(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectoryPoint_"):
    positions: sequence[float64]
    velocities: sequence[float64]
    accelerations: sequence[float64]
    effort: sequence[float64]
    time_from_start: Duration


@dataclass
class JointTrajectory(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectory_"):
    header: Header
    joint_names: sequence[str]
    points: sequence[JointTrajectoryPoint] = field(default_factory=list)


# rmw_dds_common/msg/Gid (Iron and later), NodeEntitiesInfo, ParticipantEntitiesInfo
@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: array[uint8, 16]


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: str
    node_name: str
    reader_gid_seq: sequence[Gid]
    writer_gid_seq: sequence[Gid]


@dataclass
class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid
    node_entities_info_seq: sequence[NodeEntitiesInfo]


QOS = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.Volatile, Policy.History.KeepLast(10))
FIRST_MESSAGE_NET = 60.0  # s to wait for the first message: a net for a run that never publishes, not a timing


def _reader(participant: DomainParticipant, topic: str, kind: type) -> DataReader:
    return DataReader(participant, Topic(participant, topic, kind, qos=QOS), qos=QOS)


def _writer(participant: DomainParticipant, topic: str, kind: type) -> DataWriter:
    return DataWriter(participant, Topic(participant, topic, kind, qos=QOS), qos=QOS)


def _messages(reader: DataReader):  # type: ignore[no-untyped-def]
    """Each JointState as it comes, with its arrival's Unix time in ns."""
    while True:
        samples = reader.take(N=64)
        if not samples:
            time.sleep(0.001)
        for sample in samples:
            if isinstance(sample, JointState):
                yield sample, time.time_ns()


def listen(domain: int, seconds: float) -> dict:
    """Count JointStates over `seconds` from the first one; their names, and how old they were on arrival."""
    participant = DomainParticipant(domain)
    messages = _messages(_reader(participant, "rt/joint_states", JointState))
    deadline = time.monotonic() + FIRST_MESSAGE_NET
    first, _ = next(messages)
    assert time.monotonic() < deadline
    start = time.monotonic()
    count, ages, last = 0, [], first
    for message, arrived in messages:
        if time.monotonic() - start >= seconds:
            break
        count += 1
        ages.append((arrived - (message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec)) / 1e9)
        last = message
    ages.sort()
    return {"count": count, "seconds": time.monotonic() - start, "rate": count / (time.monotonic() - start),
            "names": list(last.name), "position": list(last.position), "velocity": list(last.velocity),
            "effort": list(last.effort), "stamp_sec": last.header.stamp.sec,
            "age_median": ages[len(ages) // 2], "age_max": ages[-1]}


def goal(domain: int, safety_net: float, values: list[float], publish: bool = True) -> dict:
    """Publish `values` on rt/pbo/q_d every 100 ms (as `ros2 topic pub -r 10`; not if not `publish`)
    until 50 JointStates in a row are within 0.01 rad of them; the time that took and the last positions."""
    participant = DomainParticipant(domain)
    messages = _messages(_reader(participant, "rt/joint_states", JointState))
    writer = _writer(participant, "rt/pbo/q_d", Float64MultiArray) if publish else None
    message = Float64MultiArray(layout=MultiArrayLayout(dim=[], data_offset=0), data=values)
    start = time.monotonic()
    published_at = -1.0
    in_a_row = 0
    for state, _ in messages:
        now = time.monotonic()
        if writer is not None and now - published_at >= 0.1:
            writer.write(message)
            published_at = now
        error = max(abs(p - v) for p, v in zip(state.position, values, strict=True))
        in_a_row = in_a_row + 1 if error < 0.01 else 0
        if in_a_row >= 50 or now - start > safety_net:
            break
    return {"reached": in_a_row >= 50, "error": error, "position": list(state.position), "seconds": now - start}


def publish(domain: int, topic: str, kind: str, seconds: float, values: list[float]) -> dict:
    """A message every 10 ms for `seconds`, then none; how many were written."""
    participant = DomainParticipant(domain)
    if kind == "std_msgs/msg/Float64MultiArray":
        writer = _writer(participant, f"rt/{topic.lstrip('/')}", Float64MultiArray)
        message = Float64MultiArray(layout=MultiArrayLayout(dim=[], data_offset=0), data=values)
    elif kind == "sensor_msgs/msg/JointState":
        writer = _writer(participant, f"rt/{topic.lstrip('/')}", JointState)
        half = len(values) // 2  # names' indexes, then positions (velocities the same values): the joints in the order given
        message = JointState(header=Header(stamp=Time(sec=1, nanosec=0), frame_id=""),
                             name=[f"joint{int(i)}" for i in values[:half]],
                             position=values[half:], velocity=values[half:], effort=[0.0] * half)
    else:
        writer = _writer(participant, f"rt/{topic.lstrip('/')}", JointTrajectory)
        half = len(values) // 2  # names' indexes, then positions: the joints in the order given
        names = [f"joint{int(i)}" for i in values[:half]]
        message = JointTrajectory(header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""), joint_names=names, points=[
            JointTrajectoryPoint(positions=[0.0] * half, velocities=[], accelerations=[], effort=[],
                                 time_from_start=Duration(sec=1, nanosec=0)),
            JointTrajectoryPoint(positions=values[half:], velocities=[], accelerations=[], effort=[],
                                 time_from_start=Duration(sec=2, nanosec=0))])
    end = time.monotonic() + seconds
    written = 0
    while time.monotonic() < end:
        if isinstance(message, JointState):
            message.header.stamp.sec += 1  # a new state each time (the stamp is the arm's time)
        writer.write(message)
        written += 1
        time.sleep(0.01)
    return {"written": written}


def discovery(domain: int, node: str) -> dict:
    """Wait for `node` on ros_discovery_info (read as rmw reads it: transient local, so a description
    written before this participant joined comes too); the DDS topics of the endpoints its gids name,
    found among the endpoints DDS discovery announces, and whether its participant gid is a participant's."""
    participant = DomainParticipant(domain)
    qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.TransientLocal,
              Policy.History.KeepLast(1))
    infos = DataReader(participant, Topic(participant, "ros_discovery_info", ParticipantEntitiesInfo, qos=qos), qos=qos)
    publications = BuiltinDataReader(participant, BuiltinTopicDcpsPublication)
    subscriptions = BuiltinDataReader(participant, BuiltinTopicDcpsSubscription)
    topics: dict[bytes, str] = {}
    found: dict | None = None
    deadline = time.monotonic() + FIRST_MESSAGE_NET
    while time.monotonic() < deadline:
        for sample in infos.take(N=16):
            for entry in getattr(sample, "node_entities_info_seq", []):
                if entry.node_name == node:
                    found = {"participant": bytes(sample.gid.data), "namespace": entry.node_namespace,
                             "readers": [bytes(g.data) for g in entry.reader_gid_seq],
                             "writers": [bytes(g.data) for g in entry.writer_gid_seq]}
        for endpoint in [*publications.take(N=64), *subscriptions.take(N=64)]:
            if hasattr(endpoint, "topic_name"):
                topics[endpoint.key.bytes] = endpoint.topic_name
        if found is not None and all(g in topics for g in found["readers"] + found["writers"]):
            break
        time.sleep(0.01)
    if found is None:
        return {"found": False}
    return {"found": True, "namespace": found["namespace"], "participant_gid_bytes": len(found["participant"]),
            "readers": [topics.get(g, "?") for g in found["readers"]], "writers": [topics.get(g, "?") for g in found["writers"]]}


def main(argv: list[str]) -> None:
    verb, domain = argv[0], int(argv[1])
    if verb == "listen":
        result = listen(domain, float(argv[2]))
    elif verb == "discovery":
        result = discovery(domain, argv[2])
    elif verb in ("goal", "watch"):
        result = goal(domain, float(argv[2]), [float(v) for v in argv[3:]], publish=verb == "goal")
    else:
        result = publish(domain, argv[2], argv[3], float(argv[4]), [float(v) for v in argv[5:]])
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
