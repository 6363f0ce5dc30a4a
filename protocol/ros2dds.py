"""ROS 2 over DDS with the Cyclone DDS Python binding: the message types as IDL, ROS 2's QoS
profiles and a loopback-only domain by default. Shared by the ROS 2 base's port
(rfhoming.host.ros2dds) and the emulated ROS 2 robot (rfhoming.emulator.ros2robot); the only
module of this layer that touches a network, imported only where DDS is used (the ros2 extra).

The IDL types follow ros2/common_interfaces field for field under ROS 2's DDS names
(rfhoming.protocol.ros2), so ROS 2 nodes on either default middleware (rmw_fastrtps,
rmw_cyclonedds) match them. QoS: rclcpp's ``rmw_qos_profile_default`` (reliable, volatile,
keep last 10) for commands, ``rmw_qos_profile_sensor_data`` (best effort, volatile, keep last
5) for what rfhoming reads -- a best-effort reader matches reliable and best-effort writers alike.

Safe by default (``discovery=localhost``, ROS 2's ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST): the
participant uses the loopback interface only, no multicast, unicast discovery to 127.0.0.1.
``discovery=subnet`` leaves Cyclone's own defaults (the machine's network, multicast discovery).
"""

# no `from __future__ import annotations`: cyclonedds reads the IDL fields' annotations at run time.
# ``sequence[T]`` and ``array[T, n]`` are written out as what they make, ``Annotated[Sequence[T], ...]``,
# so that type checkers see a sequence too.

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any

from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.internal import InvalidSample
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from rfhoming.protocol import ros2
from rfhoming.protocol.errors import Error

log = logging.getLogger(__name__)


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: Annotated[Sequence[float64], array(float64, 36)] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
    header: Header = field(default_factory=Header)
    twist: Twist = field(default_factory=Twist)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: Annotated[Sequence[float64], array(float64, 36)] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class LaserScan(IdlStruct, typename="sensor_msgs::msg::dds_::LaserScan_"):
    header: Header = field(default_factory=Header)
    angle_min: float32 = 0.0
    angle_max: float32 = 0.0
    angle_increment: float32 = 0.0
    time_increment: float32 = 0.0
    scan_time: float32 = 0.0
    range_min: float32 = 0.0
    range_max: float32 = 0.0
    ranges: Annotated[Sequence[float32], sequence(float32)] = field(default_factory=list)
    intensities: Annotated[Sequence[float32], sequence(float32)] = field(default_factory=list)


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: Annotated[Sequence[TransformStamped], sequence(TransformStamped)] = field(default_factory=list)


TF = "tf2_msgs/msg/TFMessage"

TYPES: dict[str, type[IdlStruct]] = {
    ros2.ODOMETRY: Odometry, ros2.LASER_SCAN: LaserScan, ros2.TWIST: Twist, ros2.TWIST_STAMPED: TwistStamped,
    TF: TFMessage,
}

DEFAULT_QOS = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.Volatile,
                  Policy.History.KeepLast(10))
SENSOR_QOS = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5))

DISCOVERY = ("localhost", "subnet")


def config(domain: int, discovery: str = "localhost") -> str | None:
    """The Cyclone XML for a domain: loopback only, no multicast, unicast peers on 127.0.0.1
    (``localhost``); None (Cyclone's defaults: the network) for ``subnet``."""
    if discovery == "subnet":
        return None
    return (f'<CycloneDDS><Domain id="{domain}"><General><Interfaces><NetworkInterface address="127.0.0.1"/>'
            "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery>"
            "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>"
            '<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>')


class DdsError(Error):
    """A DDS domain that cannot be joined; the message says which and why."""


_participants: dict[int, tuple[Domain | None, DomainParticipant, str]] = {}
_lock = threading.Lock()


def participant(domain: int, discovery: str = "localhost") -> DomainParticipant:
    """One participant per domain per process (two ports on a domain share it, as rclpy's
    nodes share a context). A domain is opened with one discovery range for the process."""
    with _lock:
        held = _participants.get(domain)
        if held is not None:
            if held[2] != discovery:
                raise DdsError(f"ROS 2 domain {domain} is already open with discovery={held[2]} in this process")
            return held[1]
        xml = config(domain, discovery)
        try:
            dom = Domain(domain, xml) if xml else None
            dp = DomainParticipant(domain)
        except Exception as exc:  # cyclonedds raises DDSException with a return code
            raise DdsError(f"cannot join ROS 2 domain {domain} ({exc})") from None
        _participants[domain] = (dom, dp, discovery)
        return dp


def reader(dp: DomainParticipant, topic: str, ros_type: str, on_sample: Callable[[Any], None],
           qos: Qos = SENSOR_QOS) -> DataReader[Any]:
    """A reader of a ROS topic; ``on_sample`` is called on Cyclone's listener thread."""
    def on_data(r: DataReader[Any]) -> None:
        for sample in r.take(64):
            if not isinstance(sample, InvalidSample):  # a writer gone (disposed, unregistered): no data
                on_sample(sample)

    return DataReader(dp, Topic(dp, ros2.dds_topic(topic), TYPES[ros_type]), qos=qos,
                      listener=Listener(on_data_available=on_data))


def writer(dp: DomainParticipant, topic: str, ros_type: str, qos: Qos = DEFAULT_QOS) -> DataWriter[Any]:
    return DataWriter(dp, Topic(dp, ros2.dds_topic(topic), TYPES[ros_type]), qos=qos)


