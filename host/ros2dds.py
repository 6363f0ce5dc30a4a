"""ROS 2 over DDS with the Cyclone DDS Python binding: the message types as IDL, ROS 2's QoS
profiles, a loopback-only domain by default, and the port a ROS 2 robot base is reached by.

The IDL types follow ros2/common_interfaces field for field under ROS 2's DDS names
(rfhoming.protocol.ros2), so ROS 2 nodes on either default middleware (rmw_fastrtps,
rmw_cyclonedds) match them. QoS: rclcpp's ``rmw_qos_profile_default`` (reliable, volatile,
keep last 10) for commands, ``rmw_qos_profile_sensor_data`` (best effort, volatile, keep last
5) for what rfhoming reads -- a best-effort reader matches reliable and best-effort writers alike.

Safe by default (``discovery=localhost``, ROS 2's ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST): the
participant uses the loopback interface only, no multicast, unicast discovery to 127.0.0.1.
``discovery=subnet`` leaves Cyclone's own defaults (the machine's network, multicast discovery).
"""

# no `from __future__ import annotations`: cyclonedds reads the IDL fields' annotations at run time

import asyncio
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader, InvalidSample
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from rfhoming.host.drivers.ros2_base import Topics
from rfhoming.host.ports import Chunk, Disconnected, PortError, Tap
from rfhoming.protocol import ros2

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
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


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
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


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
    ranges: sequence[float32] = field(default_factory=list)
    intensities: sequence[float32] = field(default_factory=list)


TYPES: dict[str, type[IdlStruct]] = {
    ros2.ODOMETRY: Odometry, ros2.LASER_SCAN: LaserScan, ros2.TWIST: Twist, ros2.TWIST_STAMPED: TwistStamped,
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


_participants: dict[int, tuple[Domain | None, DomainParticipant, str]] = {}
_lock = threading.Lock()


def participant(domain: int, discovery: str = "localhost") -> DomainParticipant:
    """One participant per domain per process (two ports on a domain share it, as rclpy's
    nodes share a context). A domain is opened with one discovery range for the process."""
    with _lock:
        held = _participants.get(domain)
        if held is not None:
            if held[2] != discovery:
                raise PortError(f"ROS 2 domain {domain} is already open with discovery={held[2]} in this process")
            return held[1]
        xml = config(domain, discovery)
        try:
            dom = Domain(domain, xml) if xml else None
            dp = DomainParticipant(domain)
        except Exception as exc:  # cyclonedds raises DDSException with a return code
            raise PortError(f"cannot join ROS 2 domain {domain} ({exc})") from None
        _participants[domain] = (dom, dp, discovery)
        return dp


def reader(dp: DomainParticipant, topic: str, ros_type: str, on_sample: Callable[[Any], None],
           qos: Qos = SENSOR_QOS) -> DataReader:
    """A reader of a ROS topic; ``on_sample`` is called on Cyclone's listener thread."""
    def on_data(r: DataReader) -> None:
        for sample in r.take(64):
            if not isinstance(sample, InvalidSample):  # a writer gone (disposed, unregistered): no data
                on_sample(sample)

    return DataReader(dp, Topic(dp, ros2.dds_topic(topic), TYPES[ros_type]), qos=qos,
                      listener=Listener(on_data_available=on_data))


def writer(dp: DomainParticipant, topic: str, ros_type: str, qos: Qos = DEFAULT_QOS) -> DataWriter:
    return DataWriter(dp, Topic(dp, ros2.dds_topic(topic), TYPES[ros_type]), qos=qos)


MAX_QUEUED = 2000  # samples not yet read by the driver; beyond, new ones are dropped (counted)


class Ros2Port:
    """A ROS 2 robot base, HostPort-shaped: each chunk read is one sample record (topic +
    CDR) from /odom or /scan; each write is one record for the command topic. Every sample
    passes the taps, so a capture holds what the loop used and a replay feeds the same bytes.

    ``open`` returns when the first odometry arrives (a base that publishes nothing is not
    ready: the supervisor ends the run at the kind's deadline)."""

    def __init__(self, topics: Topics, *, name: str | None = None, taps: list[Tap] | None = None) -> None:
        self.topics = topics
        self.spec = f"ros2:domain={topics.domain}" + (f",ns={topics.ns}" if topics.ns else "")
        self.name = name or self.spec
        self.baud = 0
        self.taps: list[Tap] = list(taps or [])
        self.counters = {"bytes_in": 0, "bytes_out": 0, "chunks_in": 0, "opens": 0, "disconnects": 0,
                         "dropped_bytes": 0, "samples_dropped": 0}
        self._queue: asyncio.Queue[Chunk] = asyncio.Queue()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._odometry = asyncio.Event()
        self._entities: list[Any] = []
        self._writer: DataWriter | None = None

    @property
    def is_open(self) -> bool:
        return self._writer is not None

    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._odometry = asyncio.Event()
        t = self.topics
        dp = participant(t.domain, t.discovery)
        odom, scan, cmd = t.name(t.odom), t.name(t.scan), t.name(t.cmd_vel)
        self._entities = [reader(dp, odom, ros2.ODOMETRY, lambda s: self._from_dds(odom, ros2.ODOMETRY, s)),
                          reader(dp, scan, ros2.LASER_SCAN, lambda s: self._from_dds(scan, ros2.LASER_SCAN, s))]
        self._writer = writer(dp, cmd, t.command_type)
        self._command_type = TYPES[t.command_type]
        self.counters["opens"] += 1
        await self._odometry.wait()

    def _from_dds(self, topic: str, ros_type: str, sample: Any) -> None:
        """Cyclone's listener thread: the sample's CDR, to the event loop."""
        record = ros2.encode_record(topic, ros_type, sample.serialize())
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._received, topic, record)

    def _received(self, topic: str, record: bytes) -> None:
        now = round(time.time() * 1e6) / 1e6
        for tap in self.taps:
            tap(self.name, "in", now, record)
        self.counters["bytes_in"] += len(record)
        self.counters["chunks_in"] += 1
        if self._queue.qsize() >= MAX_QUEUED:
            self.counters["samples_dropped"] += 1
            return
        self._queue.put_nowait(Chunk(now, record))
        if topic == self.topics.name(self.topics.odom):  # the first odometry: the base is there
            self._odometry.set()

    async def read(self) -> Chunk:
        if self._writer is None:
            raise Disconnected(f"{self.name} is not open")
        return await self._queue.get()

    def take_pending(self) -> list[Chunk]:
        chunks = []
        while not self._queue.empty():
            chunks.append(self._queue.get_nowait())
        return chunks

    def write(self, data: bytes) -> None:
        """One sample record for the command topic, published."""
        if self._writer is None:
            raise Disconnected(f"{self.name} is not open")
        record = ros2.decode_record(data)
        if record.type != self.topics.command_type:
            raise PortError(f"{self.name}: a {record.type} where {self.topics.command_type} is published")
        now = round(time.time() * 1e6) / 1e6
        for tap in self.taps:
            tap(self.name, "out", now, data)
        self.counters["bytes_out"] += len(data)
        self._writer.write(self._command_type.deserialize(record.data))

    async def close(self) -> None:
        self._writer = None
        self._entities = []
        self._loop = None
