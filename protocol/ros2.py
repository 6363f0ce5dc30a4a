"""ROS 2 messages on DDS, sans-IO: names, the CDR of the messages a robot base speaks, and the
sample record rfhoming's captures keep.

ROS 2's DDS mapping (ROS 2 design article "Topic and Service name mapping to DDS", and
rmw_cyclonedds / rmw_fastrtps): a ROS topic ``/ns/name`` is the DDS topic ``rt/ns/name``; a
message ``pkg/msg/Type`` is the DDS type ``pkg::msg::dds_::Type_``; samples are plain CDR
(XCDR1), little-endian, behind the 4-byte encapsulation header ``00 01 00 00``. Field order and
types follow ros2/common_interfaces (nav_msgs/msg/Odometry.msg, sensor_msgs/msg/LaserScan.msg,
geometry_msgs/msg/Twist.msg, TwistStamped.msg, std_msgs/msg/Header.msg).

A *sample record* is one DDS sample as rfhoming saw or sent it: ``u16 length | the ROS topic
name | u16 length | the ROS type name | the serialized sample (encapsulation header + CDR)``,
names in UTF-8, lengths little-endian, so a capture says what each sample is. The
ROS 2 base's port hands its driver one record per chunk, so a capture holds each sample as a
packet and a replay feeds the same driver the same bytes.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any, NamedTuple

from rfhoming.protocol.errors import Error

CDR_LE = b"\x00\x01\x00\x00"
MAX_RECORD = 1 << 20  # a sample record larger than this is refused (a LaserScan of 100k beams is 400 kB)

ODOMETRY = "nav_msgs/msg/Odometry"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"  # a ground-truth pose (emulate --pose-from)


class Ros2FormatError(Error, ValueError):
    """A sample record or CDR body that does not parse; the message says where."""


def dds_topic(name: str) -> str:
    """``/ns/cmd_vel`` -> ``rt/ns/cmd_vel`` (ROS topics are published under the ``rt`` prefix)."""
    return "rt/" + name.lstrip("/")


def dds_type(ros_type: str) -> str:
    """``nav_msgs/msg/Odometry`` -> ``nav_msgs::msg::dds_::Odometry_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def topic_name(ns: str, topic: str) -> str:
    """A ROS topic in a namespace: relative topics go under ``ns``, absolute ones stay."""
    if topic.startswith("/"):
        return topic
    ns = "/" + ns.strip("/") if ns.strip("/") else ""
    return f"{ns}/{topic}"


class Stamp(NamedTuple):
    sec: int
    nanosec: int

    @property
    def seconds(self) -> float:
        return self.sec + self.nanosec / 1e9

    @classmethod
    def of(cls, t: float) -> Stamp:
        ns = round(t * 1e9)
        return cls(ns // 1_000_000_000, ns % 1_000_000_000)


class Odometry(NamedTuple):
    """nav_msgs/Odometry, the planar part rfhoming uses (z, roll, pitch and the covariances are
    read past and written as zero)."""

    stamp: Stamp
    frame_id: str
    child_frame_id: str
    x: float
    y: float
    yaw: float  # radians, from the orientation quaternion
    v: float  # twist.linear.x, m/s in child_frame_id
    w: float  # twist.angular.z, rad/s


class LaserScan(NamedTuple):
    stamp: Stamp
    frame_id: str
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: tuple[float, ...]
    intensities: tuple[float, ...] = ()


class Twist(NamedTuple):
    """geometry_msgs/Twist (``stamp`` None) or TwistStamped: planar v and ω."""

    v: float
    w: float
    stamp: Stamp | None = None
    frame_id: str = ""


class SampleRecord(NamedTuple):
    topic: str  # the ROS topic, e.g. /odom
    type: str  # the ROS type, e.g. nav_msgs/msg/Odometry
    data: bytes  # encapsulation header + CDR


def encode_record(topic: str, ros_type: str, data: bytes) -> bytes:
    name, kind = topic.encode(), ros_type.encode()
    return struct.pack("<H", len(name)) + name + struct.pack("<H", len(kind)) + kind + data


def decode_record(chunk: bytes) -> SampleRecord:
    if len(chunk) > MAX_RECORD:
        raise Ros2FormatError(f"a sample record of {len(chunk)} bytes")
    names, pos = [], 0
    for what in ("topic", "type"):
        if pos + 2 > len(chunk):
            raise Ros2FormatError(f"a sample record of {len(chunk)} bytes ends before its {what}")
        (n,) = struct.unpack_from("<H", chunk, pos)
        if pos + 2 + n > len(chunk):
            raise Ros2FormatError(f"a {what} of {n} bytes in a record of {len(chunk)}")
        try:
            names.append(chunk[pos + 2:pos + 2 + n].decode())
        except UnicodeDecodeError:
            raise Ros2FormatError(f"a {what} name that is not UTF-8") from None
        pos += 2 + n
    return SampleRecord(names[0], names[1], chunk[pos:])


class _Reader:
    """XCDR1 little-endian: primitives aligned to their size, offsets from after the header."""

    def __init__(self, data: bytes) -> None:
        if data[:2] != CDR_LE[:2]:
            raise Ros2FormatError(f"encapsulation {data[:2].hex() or 'missing'}, not CDR little-endian (0001)")
        self.body = memoryview(data)[4:]
        self.pos = 0

    def take(self, fmt: str, size: int, count: int = 1) -> tuple[Any, ...]:
        self.pos += -self.pos % size
        end = self.pos + size * count
        if end > len(self.body):
            raise Ros2FormatError(f"CDR ends at byte {len(self.body)}, a field needs {end}")
        values = struct.unpack_from(f"<{count}{fmt}", self.body, self.pos)
        self.pos = end
        return values

    def f64(self, count: int = 1) -> tuple[float, ...]:
        return self.take("d", 8, count)

    def f32_seq(self) -> tuple[float, ...]:
        (n,) = self.take("I", 4)
        if n * 4 > len(self.body) - self.pos:
            raise Ros2FormatError(f"a sequence of {n} floats in {len(self.body) - self.pos} bytes")
        return self.take("f", 4, n) if n else ()

    def string(self) -> str:
        (n,) = self.take("I", 4)
        if n == 0 or self.pos + n > len(self.body):
            raise Ros2FormatError(f"a string of {n} bytes at {self.pos}")
        raw = bytes(self.body[self.pos:self.pos + n - 1])
        self.pos += n
        return raw.decode(errors="replace")

    def header(self) -> tuple[Stamp, str]:
        (sec,), (nanosec,) = self.take("i", 4), self.take("I", 4)
        return Stamp(sec, nanosec), self.string()


class _Writer:
    def __init__(self) -> None:
        self.out = bytearray()

    def put(self, fmt: str, size: int, *values: Any) -> None:
        self.out += b"\0" * (-len(self.out) % size)
        self.out += struct.pack(f"<{len(values)}{fmt}", *values)

    def string(self, text: str) -> None:
        raw = text.encode() + b"\0"
        self.put("I", 4, len(raw))
        self.out += raw

    def header(self, stamp: Stamp, frame_id: str) -> None:
        self.put("i", 4, stamp.sec)
        self.put("I", 4, stamp.nanosec)
        self.string(frame_id)

    def f32_seq(self, values: tuple[float, ...]) -> None:
        self.put("I", 4, len(values))
        if values:
            self.put("f", 4, *values)

    def done(self) -> bytes:
        return CDR_LE + bytes(self.out)


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    return math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))


def decode_odometry(data: bytes) -> Odometry:
    r = _Reader(data)
    stamp, frame = r.header()
    child = r.string()
    x, y, _z, qx, qy, qz, qw = r.f64(7)
    r.f64(36)
    v, _vy, _vz, _wx, _wy, w = r.f64(6)
    r.f64(36)
    return Odometry(stamp, frame, child, x, y, yaw_of(qx, qy, qz, qw), v, w)


def encode_odometry(odo: Odometry) -> bytes:
    wr = _Writer()
    wr.header(odo.stamp, odo.frame_id)
    wr.string(odo.child_frame_id)
    wr.put("d", 8, odo.x, odo.y, 0.0, 0.0, 0.0, math.sin(odo.yaw / 2), math.cos(odo.yaw / 2))
    wr.put("d", 8, *[0.0] * 36)
    wr.put("d", 8, odo.v, 0.0, 0.0, 0.0, 0.0, odo.w)
    wr.put("d", 8, *[0.0] * 36)
    return wr.done()


def decode_scan(data: bytes) -> LaserScan:
    r = _Reader(data)
    stamp, frame = r.header()
    angle_min, angle_max, angle_increment, time_increment, scan_time, range_min, range_max = r.take("f", 4, 7)
    return LaserScan(stamp, frame, angle_min, angle_max, angle_increment, time_increment, scan_time, range_min,
                     range_max, r.f32_seq(), r.f32_seq())


def encode_scan(scan: LaserScan) -> bytes:
    wr = _Writer()
    wr.header(scan.stamp, scan.frame_id)
    wr.put("f", 4, scan.angle_min, scan.angle_max, scan.angle_increment, scan.time_increment, scan.scan_time,
           scan.range_min, scan.range_max)
    wr.f32_seq(scan.ranges)
    wr.f32_seq(scan.intensities)
    return wr.done()


def decode_twist(data: bytes, stamped: bool = False) -> Twist:
    r = _Reader(data)
    stamp, frame = r.header() if stamped else (None, "")
    v, _vy, _vz, _wx, _wy, w = r.f64(6)
    return Twist(v, w, stamp, frame)


def encode_twist(twist: Twist) -> bytes:
    """Twist, or TwistStamped when the command carries a stamp."""
    wr = _Writer()
    if twist.stamp is not None:
        wr.header(twist.stamp, twist.frame_id)
    wr.put("d", 8, twist.v, 0.0, 0.0, 0.0, 0.0, twist.w)
    return wr.done()


class SampleDecoder:
    """Sample records (one per chunk, as a capture holds them) -> decoded messages; a record
    that does not parse is a counted drop, as the other decoders count theirs."""

    DECODERS: dict[str, Callable[[bytes], Any]] = {ODOMETRY: decode_odometry, LASER_SCAN: decode_scan, TWIST: decode_twist,
                TWIST_STAMPED: lambda data: decode_twist(data, stamped=True)}

    def __init__(self) -> None:
        self.counters = {"samples": 0, "drops": 0, "other_types": 0}

    def feed(self, chunk: bytes) -> list[tuple[SampleRecord, Any]]:
        try:
            record = decode_record(chunk)
            decode = self.DECODERS.get(record.type)
            if decode is None:
                self.counters["other_types"] += 1
                return [(record, None)]
            message = decode(record.data)
        except Ros2FormatError:
            self.counters["drops"] += 1
            return []
        self.counters["samples"] += 1
        return [(record, message)]
