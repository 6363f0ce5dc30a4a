"""ROS 2 over DDS with the Cyclone DDS Python binding: the message types as IDL, ROS 2's QoS
profiles and the loopback-only domain configuration used by default. Shared by the ROS 2 base's
port (rfhoming.host.ros2dds) and the emulated ROS 2 robot (rfhoming.emulator.ros2robot);
imported only where DDS is used (the ros2 extra). Like the rest of this layer it does no I/O:
joining a domain and its readers and writers are rfhoming.host.dds (and the emulator's own,
emulator/ros2robot.py).

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

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Annotated

from cyclonedds.core import Policy, Qos
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint32
from cyclonedds.util import duration

from rfhoming.protocol import ros2
from rfhoming.protocol.errors import Error


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
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


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
    TF: TFMessage, ros2.POSE_STAMPED: PoseStamped,
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
