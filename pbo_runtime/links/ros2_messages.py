"""ROS 2 messages on DDS as a ROS 2 node sees them: the types, the topic names and the QoS rmw_cyclonedds uses.

A ROS 2 topic `/joint_states` is the DDS topic `rt/joint_states`; a message type
`sensor_msgs/msg/JointState` is the DDS type `sensor_msgs::msg::dds_::JointState_`, serialized
as CDR in the fields' declaration order (as ROS 2's generated IDL declares them). ROS 2's default
QoS for topics is reliable, volatile, keep the last 10. Imported only when the 'ros2' extra
(cyclonedds) is installed: modules and drivers get it from `pbo_runtime.ros2_messages`. (No
`from __future__ import annotations` here: cyclonedds reads the fields' types at run time.)
"""

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
from cyclonedds.util import duration

DEFAULT_DOMAIN = 0  # ROS 2's, when ROS_DOMAIN_ID is not set
TOPIC_PREFIX = "rt"  # rmw's prefix of a topic's DDS name
DISCOVERY_TOPIC = "ros_discovery_info"  # where each ROS 2 participant says which nodes it hosts (no rt/ prefix)
GID_BYTES = 16  # rmw_dds_common/msg/Gid since ROS 2 Iron (Humble's is 24)
_NAME = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str = ""
    size: uint32 = 0
    stride: uint32 = 0


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: sequence[MultiArrayDimension] = field(default_factory=list)
    data_offset: uint32 = 0


@dataclass
class Float64MultiArray(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: sequence[float64] = field(default_factory=list)


@dataclass
class JointTrajectoryPoint(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectoryPoint_"):
    positions: sequence[float64] = field(default_factory=list)
    velocities: sequence[float64] = field(default_factory=list)
    accelerations: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)
    time_from_start: Duration = field(default_factory=Duration)


@dataclass
class JointTrajectory(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectory_"):
    header: Header = field(default_factory=Header)
    joint_names: sequence[str] = field(default_factory=list)
    points: sequence[JointTrajectoryPoint] = field(default_factory=list)


@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: array[uint8, GID_BYTES] = field(default_factory=lambda: [0] * GID_BYTES)


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: str = "/"
    node_name: str = ""
    reader_gid_seq: sequence[Gid] = field(default_factory=list)
    writer_gid_seq: sequence[Gid] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: sequence[NodeEntitiesInfo] = field(default_factory=list)


#: The ROS 2 message types by their ROS names (what `ros2 topic pub` and the YAML's `type:` say).
MESSAGES = {
    "sensor_msgs/msg/JointState": JointState,
    "std_msgs/msg/Float64MultiArray": Float64MultiArray,
    "trajectory_msgs/msg/JointTrajectory": JointTrajectory,
}


def goal_values(message: Any, names: Sequence[str]) -> list[float]:
    """A goal's values: a Float64MultiArray's `data`; a JointTrajectory's last point's `positions`
    (the trajectory's end), in the order of `names` when the message names its joints. [] when
    the message has no such values, or names other joints."""
    if isinstance(message, Float64MultiArray):
        return list(message.data)
    if not message.points:
        return []
    positions = list(message.points[-1].positions)
    given = list(message.joint_names)
    if not given or given == list(names):
        return positions
    if sorted(given) != sorted(names) or len(positions) != len(given):
        return []
    order = {name: index for index, name in enumerate(given)}
    return [positions[order[name]] for name in names]


def dds_topic(name: str) -> str:
    """The DDS name of the ROS 2 topic `name` ('/joint_states' -> 'rt/joint_states')."""
    return f"{TOPIC_PREFIX}/{name.lstrip('/')}"


def check_topic(name: str) -> str:
    """`name` if it is a ROS 2 topic name (a relative one is taken from the root), else ValueError."""
    if not _NAME.match(name):
        raise ValueError(f"topic must be a ROS 2 name: words of letters, digits and _ joined by /, got: {name!r}")
    return name


def domain_id(configured: int) -> int:
    """The DDS domain: the configured one, or (-1) ROS_DOMAIN_ID as ROS 2 reads it, else 0."""
    if configured >= 0:
        return configured
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    return int(text) if text.isdigit() else DEFAULT_DOMAIN


def ros2_qos(depth: int = 10) -> Qos:
    """ROS 2's default QoS for a topic (rmw_qos_profile_default): reliable, volatile, keep last `depth`;
    the messages in CDR (XCDR1), as rmw_cyclonedds writes them."""
    return Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )


def discovery_qos() -> Qos:
    """The QoS of `ros_discovery_info` as rmw writes it: reliable, transient local, keep the last one
    (a node that joins later gets the participant's newest description)."""
    return Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )


def gid_of(entity: Any) -> Gid:
    """A DDS entity's GUID as rmw_cyclonedds makes it the entity's ROS 2 gid."""
    return Gid(data=list(entity.guid.bytes))


def node_name(text: str) -> str:
    """`text` as a valid ROS 2 node name: other characters than letters, digits and _ become _."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", text)
    return name if name[:1].isalpha() else f"pbo_{name}"


def announce_node(participant: Any, name: str, readers: Sequence[Any] = (), writers: Sequence[Any] = (),
                  namespace: str = "/") -> Any:
    """Publish once on `ros_discovery_info`, as rmw does, that `participant` hosts the ROS 2 node
    `namespace`/`name` owning `readers` and `writers`: `ros2 node list` and `ros2 topic info -v` then
    see it. Returns the writer, which keeps the sample for nodes that join later: keep it alive."""
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    topic = Topic(participant, DISCOVERY_TOPIC, ParticipantEntitiesInfo, qos=discovery_qos())
    writer = DataWriter(participant, topic, qos=discovery_qos())
    node = NodeEntitiesInfo(node_namespace=namespace, node_name=node_name(name),
                            reader_gid_seq=[gid_of(r) for r in readers], writer_gid_seq=[gid_of(w) for w in writers])
    writer.write(ParticipantEntitiesInfo(gid=gid_of(participant), node_entities_info_seq=[node]))
    return writer
