"""A second reader of ROS 2 topics, written with nothing but the cyclonedds binding: its own
IDL types (from ros2/common_interfaces' .msg files, ROS 2's DDS names) and its own loopback
configuration. Reads rt/cmd_vel, rt/rfhoming/cmd_vel, rt/odom, rt/scan, rt/tf,
rt/rfhoming/target and rt/rfhoming/events on a domain, and any of EXTRA -- rfhoming/aoa/angle
(rfhoming_msgs/AoaAngle, transcribed here from its .msg), tf_static (reliable, transient local,
as tf2 reads it), rfhoming/tag_<ID>/pose and rfhoming/tag_<ID>/point -- and prints one JSON
line per sample; ends after SECONDS, or once its standard input closes and then 3 s pass with
no command on rt/cmd_vel (what was still on its way is read). EXTRA ``publications`` also
prints every writer the domain's discovery announces (DDS's built-in DCPSPublication topic:
its topic and type name), whether or not anything here reads that topic.

    python tests/ros2_listener.py DOMAIN SECONDS [EXTRA ...]
"""

import json
import select
import sys
import time
from dataclasses import dataclass

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int8, int16, int32, sequence, uint8, uint32
from cyclonedds.sub import DataReader, InvalidSample
from cyclonedds.topic import Topic


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
class LaserScan(IdlStruct, typename="sensor_msgs::msg::dds_::LaserScan_"):
    header: Header
    angle_min: float32
    angle_max: float32
    angle_increment: float32
    time_increment: float32
    scan_time: float32
    range_min: float32
    range_max: float32
    ranges: sequence[float32]
    intensities: sequence[float32]


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class PointStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PointStamped_"):
    header: Header
    point: Point


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


@dataclass
class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
    header: Header
    pose: PoseWithCovariance


@dataclass
class AoaAngle(IdlStruct, typename="rfhoming_msgs::msg::dds_::AoaAngle_"):
    header: Header
    instance_id: str
    anchor_id: str
    azimuth_rad: float32
    elevation_rad: float32
    board_azimuth_deg: int16
    board_elevation_deg: int16
    rssi1_dbm: int8
    reserved: int8
    channel: uint8
    timestamp_ms: uint32
    seq: int32


def extra_reader(name: str) -> tuple[type, Qos | None]:
    """The type of an EXTRA topic, and its QoS when not best effort."""
    if name == "tf_static":
        return TFMessage, Qos(Policy.Reliability.Reliable(100_000_000), Policy.Durability.TransientLocal,
                              Policy.History.KeepLast(1))
    if name == "rfhoming/aoa/angle":
        return AoaAngle, None
    if name.startswith("rfhoming/tag_") and name.endswith("/pose"):
        return PoseWithCovarianceStamped, None
    if name.startswith("rfhoming/tag_") and name.endswith("/point"):
        return PointStamped, None
    raise SystemExit(f"no reader for {name!r}")


def seconds(stamp: Time) -> float:
    return stamp.sec + stamp.nanosec / 1e9


def describe(name: str, s: object) -> dict:
    if name.endswith("cmd_vel"):
        return {"v": s.linear.x, "w": s.angular.z}
    if name == "odom":
        return {"x": s.pose.pose.position.x, "frame": s.header.frame_id, "child": s.child_frame_id,
                "stamp": seconds(s.header.stamp)}
    if name == "scan":
        return {"beams": len(s.ranges), "frame": s.header.frame_id, "range_max": s.range_max}
    if name == "rfhoming/target" or name.endswith("/point"):
        return {"frame": s.header.frame_id, "xy": [s.point.x, s.point.y], "z": s.point.z}
    if name == "rfhoming/events":
        return {"what": s.data}
    if name == "rfhoming/aoa/angle":
        return {"frame": s.header.frame_id, "tag": s.instance_id, "anchor": s.anchor_id, "azimuth": s.azimuth_rad,
                "elevation": s.elevation_rad, "board_azimuth": s.board_azimuth_deg, "rssi": s.rssi1_dbm,
                "channel": s.channel, "stamp": seconds(s.header.stamp)}
    if name.endswith("/pose"):
        p = s.pose.pose
        return {"frame": s.header.frame_id, "xyz": [p.position.x, p.position.y, p.position.z],
                "orientation": [p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w],
                "covariance": list(s.pose.covariance)}
    return {"frames": [[t.header.frame_id, t.child_frame_id] for t in s.transforms],
            "stamps": [seconds(t.header.stamp) for t in s.transforms],
            "transforms": [[*(getattr(t.transform.translation, k) for k in "xyz"),
                            *(getattr(t.transform.rotation, k) for k in "xyzw")] for t in s.transforms]}


def main() -> None:
    domain, seconds = int(sys.argv[1]), float(sys.argv[2])
    config = (f'<CycloneDDS><Domain id="{domain}"><General><Interfaces><NetworkInterface address="127.0.0.1"/>'
              "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto"
              "</ParticipantIndex><MaxAutoParticipantIndex>30</MaxAutoParticipantIndex><Peers>"
              '<Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>')
    _domain = Domain(domain, config)  # noqa: F841 -- kept alive with the participant
    dp = DomainParticipant(domain)
    best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(50))
    readers = {name: DataReader(dp, Topic(dp, "rt/" + name, kind), qos=best_effort)
               for name, kind in (("cmd_vel", Twist), ("rfhoming/cmd_vel", Twist), ("odom", Odometry),
                                  ("scan", LaserScan), ("tf", TFMessage), ("rfhoming/target", PointStamped),
                                  ("rfhoming/events", String))}
    extra = sys.argv[3:]
    publications = BuiltinDataReader(dp, BuiltinTopicDcpsPublication) if "publications" in extra else None
    for name in (e for e in extra if e != "publications"):
        kind, qos = extra_reader(name)
        readers[name] = DataReader(dp, Topic(dp, "rt/" + name, kind), qos=qos or best_effort)
    print(json.dumps({"ready": domain}), flush=True)
    end = time.monotonic() + seconds
    closing = False
    while time.monotonic() < end:
        if not closing and select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.read(1):
            closing, end = True, time.monotonic() + 3.0
        for name, reader in readers.items():
            for s in reader.take(50):
                if isinstance(s, InvalidSample):  # a writer went away: no data
                    continue
                if closing and name == "cmd_vel":
                    end = time.monotonic() + 3.0
                print(json.dumps({"topic": name, **describe(name, s)}), flush=True)
        for p in publications.take(50) if publications is not None else ():
            if isinstance(p, InvalidSample):  # a writer gone
                continue
            print(json.dumps({"topic": "DCPSPublication", "name": p.topic_name, "type": p.type_name}), flush=True)
        time.sleep(0.01)


if __name__ == "__main__":
    main()
