"""The emulated robot base as a ROS 2 robot: the base's firmware model, its link a DDS domain.

What the firmware sends (odometry and range-scan records) is published as nav_msgs/Odometry
on /odom, the odom -> base_link transform on /tf and sensor_msgs/LaserScan on /scan; a
geometry_msgs/Twist on /cmd_vel reaches the firmware as its velocity command, with the
firmware's command watchdog (COMMAND_TIMEOUT_MS) standing for a ROS 2 base's cmd_vel timeout.
Odometry and /tf go out with the sensor-data QoS as robot drivers do (the Create 3's odometry
is best effort); /cmd_vel is read with ROS 2's default QoS, as geometry_msgs/Twist or, with
``stamped``, TwistStamped (Jazzy-era Nav2's ``enable_stamped_cmd_vel``: one type per topic).
"""

import asyncio
import math
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException, Listener, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.internal import InvalidSample
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from rfhoming.emulator.links import Link
from rfhoming.protocol import ros2
from rfhoming.protocol import ros2dds as dds
from rfhoming.protocol.frames import FrameDecoder, Odometry, RangeScan, RangeScanV2, VelocityCommand, encode_frame

COMMAND_TIMEOUT_MS = 500  # *assumed*: a ROS 2 base stops this long after its last cmd_vel


def _stamp(t_us: int) -> dds.Time:
    return dds.Time(*ros2.Stamp.of(t_us / 1e6))


def join(domain: int, discovery: str) -> tuple[Domain | None, DomainParticipant]:
    """A participant on ``domain``, the domain configured as the host configures it (loopback
    only unless ``subnet``) unless this process made it already (the host, in-process)."""
    xml = dds.config(domain, discovery)
    made = None
    try:
        made = Domain(domain, xml) if xml else None
        return made, DomainParticipant(domain)
    except DDSException as exc:
        if made is None and exc.code == DDSException.DDS_RETCODE_PRECONDITION_NOT_MET:
            return None, DomainParticipant(domain)
        raise dds.DdsError(f"cannot join ROS 2 domain {domain} ({exc})") from None


def _writer(dp: DomainParticipant, topic: str, ros_type: str, qos: Qos) -> DataWriter[Any]:
    return DataWriter(dp, Topic(dp, ros2.dds_topic(topic), dds.TYPES[ros_type]), qos=qos)


def reader(dp: DomainParticipant, topic: str, ros_type: str, on_sample: Callable[[Any], None], qos: Qos) -> DataReader[Any]:
    """A reader of a ROS topic; ``on_sample`` is called on Cyclone's listener thread."""
    def on_data(r: DataReader[Any]) -> None:
        for sample in r.take(64):
            if not isinstance(sample, InvalidSample):  # a writer gone (disposed, unregistered): no data
                on_sample(sample)

    return DataReader(dp, Topic(dp, ros2.dds_topic(topic), dds.TYPES[ros_type]), qos=qos,
                      listener=Listener(on_data_available=on_data))


class Ros2Link(Link):
    """A base's link that is a ROS 2 robot on ``domain`` under namespace ``ns``."""

    def __init__(self, domain: int = 0, ns: str = "", discovery: str = "localhost", stamped: bool = False) -> None:
        super().__init__()
        self.domain, self.ns, self.discovery, self.stamped = domain, ns, discovery, stamped
        self.decoder = FrameDecoder()
        self.counters.update(published=0, commands=0)
        self._seq = 0
        self._entities: list[Any] = []
        self._loop: asyncio.AbstractEventLoop | None = None

    def describe(self) -> dict[str, Any]:
        spec = f"ros2:{'/' + self.ns if self.ns else ''}{',' if self.ns else ''}domain={self.domain}"
        return {"kind": "ros2", "protocol": "ros2", "path": spec, "ros2": {"domain": self.domain, "ns": self.ns or "/",
                                       "topics": [self._name(t) for t in ("odom", "scan", "tf", "cmd_vel")]}}

    def _name(self, topic: str) -> str:
        return ros2.topic_name(self.ns, topic)

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._domain, dp = join(self.domain, self.discovery)  # the domain object kept: it holds the configuration
        self._odom = _writer(dp, self._name("odom"), ros2.ODOMETRY, dds.SENSOR_QOS)
        self._scan = _writer(dp, self._name("scan"), ros2.LASER_SCAN, dds.SENSOR_QOS)
        self._tf = _writer(dp, self._name("tf"), dds.TF, dds.DEFAULT_QOS)
        self._cmd = reader(dp, self._name("cmd_vel"), ros2.TWIST_STAMPED if self.stamped else ros2.TWIST,
                              self._from_dds, dds.DEFAULT_QOS)
        self._entities = [self._odom, self._scan, self._tf, self._cmd]
        self.plugged = True

    def _from_dds(self, command: dds.Twist | dds.TwistStamped) -> None:
        twist = command.twist if isinstance(command, dds.TwistStamped) else command
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._command, twist.linear.x, twist.angular.z)

    def _command(self, v: float, w: float) -> None:
        if not self.plugged:
            return
        self._seq = (self._seq + 1) & 0xFFFF
        frame = encode_frame(VelocityCommand(0, self._seq, 0, max(-32768, min(32767, round(v * 1000))),
                                             max(-32768, min(32767, round(w * 1000))), COMMAND_TIMEOUT_MS))
        self.counters["commands"] += 1
        self.counters["rx_bytes"] += len(frame)
        self.on_receive(frame)

    def send(self, data: bytes) -> None:
        """The firmware's bytes: each record as the ROS 2 message a robot driver publishes."""
        if not self.plugged:
            self.counters["dropped_bytes"] += len(data)
            return
        self.counters["tx_bytes"] += len(data)
        for record in self.decoder.feed(data):
            if isinstance(record, Odometry):
                self._publish_odometry(record)
            elif isinstance(record, (RangeScan, RangeScanV2)):
                self._publish_scan(record)

    def _publish_odometry(self, r: Odometry) -> None:
        header = dds.Header(_stamp(r.t_us), "odom")
        yaw = r.theta_urad / 1e6
        rotation = dds.Quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
        position = dds.Point(r.x_mm / 1000, r.y_mm / 1000, 0.0)
        msg = dds.Odometry(header, "base_link")
        msg.pose.pose = dds.Pose(position, rotation)
        msg.twist.twist = dds.Twist(dds.Vector3(r.v_mm_s / 1000, 0, 0), dds.Vector3(0, 0, r.w_mrad_s / 1000))
        self._odom.write(msg)
        self._tf.write(dds.TFMessage([dds.TransformStamped(header, "base_link", dds.Transform(
            dds.Vector3(position.x, position.y, 0.0), rotation))]))
        self.counters["published"] += 2

    def _publish_scan(self, r: RangeScan | RangeScanV2) -> None:
        n = len(r.ranges_mm)
        if isinstance(r, RangeScanV2):
            first, last, range_max = r.angle_min_urad / 1e6, r.angle_max_urad / 1e6, r.range_max_mm / 1000
            step = (last - first) / (n - 1) if n > 1 else 0.0
        else:
            first, step, range_max = r.angle_min_mrad / 1000, r.angle_inc_mrad / 1000, 65.535
            last = first + step * max(0, n - 1)
        ranges = [mm / 1000 if mm else math.inf for mm in r.ranges_mm]  # REP 117: no return is +inf
        self._scan.write(dds.LaserScan(dds.Header(_stamp(r.t_us), "laser"), first, last, step, 0.0, 0.1, 0.0,
                                       range_max, ranges, []))
        self.counters["published"] += 1

    async def unplug(self) -> None:
        self.plugged = False
        self._entities = []
        self.counters["unplugs"] += 1
