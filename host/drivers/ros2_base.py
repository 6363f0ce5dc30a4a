"""A ROS 2 robot base as the homing loop's base: nav_msgs/Odometry and sensor_msgs/LaserScan
in, geometry_msgs/Twist (or TwistStamped) out, over DDS (rfhoming.host.ros2dds).

The loop sees the same Pose2D and Scan items and makes the same calls as with rfhoming's
serial base. Differences, by the nature of ROS 2: there is no brake mode (``brake`` is
counted, nothing is sent: a ROS 2 base ramps to a zero command by its own limits) and no
command timeout on the wire -- a ROS 2 base's own cmd_vel watchdog is the second line of
defence. A stop is published STOP_REPEATS times, so that a best-effort reader gets one. A
TwistStamped carries the stamp of the odometry the loop acts on (robot time; ``acting_on``), not
of the newest the driver read, so a replay writes the same bytes as the live run did.
"""

from __future__ import annotations

import math
from typing import Any

from rfhoming.host.drivers.common import BoundedStream
from rfhoming.host.drivers.robot import CommandedBase, Pose2D, Scan
from rfhoming.host.ports import Disconnected, PortError, Tap
from rfhoming.host.portspec import PortSpec
from rfhoming.protocol import ros2

STOP_REPEATS = 3
STAMPS_KEPT = 4096  # odometry stamps kept for acting_on: more than the loop's stream holds (assembly.INPUT_QUEUE)


class Topics:
    """What the driver needs of a ROS 2 base's set-up: its command topic and type, and the
    odometry topic it waits for. Given by the port (live) or a capture's interface (replay)."""

    def __init__(self, domain: int = 0, ns: str = "", cmd_vel: str = "cmd_vel", odom: str = "odom",
                 scan: str = "scan", stamped: bool = False, discovery: str = "localhost") -> None:
        self.domain, self.ns, self.discovery = domain, ns, discovery
        self.cmd_vel, self.odom, self.scan, self.stamped = cmd_vel, odom, scan, stamped

    def name(self, topic: str) -> str:
        return ros2.topic_name(self.ns, topic)

    @property
    def command_type(self) -> str:
        return ros2.TWIST_STAMPED if self.stamped else ros2.TWIST

    def recorded(self) -> dict[str, str]:
        """The facts a capture's interface keeps, for a replay to write the same commands."""
        return {"domain": str(self.domain), "ns": self.ns or "/", "cmd_vel": self.name(self.cmd_vel),
                "odom": self.name(self.odom), "scan": self.name(self.scan), "stamped": str(int(self.stamped))}

    @classmethod
    def of_settings(cls, s: dict[str, Any]) -> Topics:
        return cls(domain=int(s.get("domain", 0)), ns=str(s.get("ns", "")).strip("/"),
                   cmd_vel=s.get("cmd_vel", "cmd_vel"), odom=s.get("odom", "odom"), scan=s.get("scan", "scan"),
                   stamped=s.get("stamped", False) in (True, "1"), discovery=s.get("discovery", "localhost"))


def pose_of(odo: ros2.Odometry, t_host: float) -> Pose2D:
    return Pose2D(t_host, odo.stamp.seconds, odo.x, odo.y, odo.yaw, odo.v, odo.w, 0)


def scan_of(msg: ros2.LaserScan, t_host: float) -> Scan:
    """A LaserScan in the loop's terms: a beam outside [range_min, range_max] (inf, NaN, 0) is no return."""
    ranges = tuple(r if math.isfinite(r) and r > 0 and msg.range_min <= r <= msg.range_max else None
                   for r in msg.ranges)
    return Scan(t_host, msg.angle_min, msg.angle_increment, ranges, msg.range_max, msg.range_min, msg.scan_time,
                msg.time_increment)


class Ros2BaseDriver(CommandedBase):
    kind = "ros2"
    watchdog = "the ROS 2 base's own cmd_vel timeout"
    items = ()  # its Pose2D and Scan are the homing loop's, not the Python API's items

    def sent(self, data: bytes) -> list[Any]:
        return []  # its Twist samples: an export's commands come from a run log

    def __init__(self, port: Any, *, command_timeout_ms: int = 300, reconnect: bool = True,
                 out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out)
        self.command_timeout_ms = command_timeout_ms  # the loop's; a ROS 2 command carries none
        self.topics: Topics = getattr(port, "topics", None) or Topics.of_settings(getattr(port, "description", {}))
        self.counters.update(samples=0, bad_samples=0, other_types=0)
        self._stamp = ros2.Stamp(0, 0)  # what a TwistStamped carries: the odometry's the loop acts on
        self._stamps: dict[float, ros2.Stamp] = {}  # of the odometries read, newest last (bounded)
        t = self.topics
        odom = t.name(t.odom)
        self.problem = (f"no {odom} ({ros2.dds_topic(odom)}) on ROS 2 domain {t.domain} yet: is the robot up, on "
                        "that ROS_DOMAIN_ID" + (", on this machine (discovery=localhost)?"
                                                 if t.discovery == "localhost" else "?"))

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> Ros2BaseDriver:
        if port is not None:  # a replay of a ROS 2 run: the recorded samples
            return cls(port, **options)
        try:
            from rfhoming.host.ros2dds import Ros2Port  # cyclonedds: the ros2 extra
        except ImportError as exc:
            raise PortError(f"{spec}: a ROS 2 base needs {exc.name or exc}; install it with "
                            "pip install 'rfhoming[ros2]'") from None

        return cls(Ros2Port(topics_of(spec), name=spec.name or spec.where, taps=taps), **options)

    @classmethod
    def describe_spec(cls, spec: PortSpec) -> dict[str, str]:
        """What a capture's interface records of the spec (host/session.py resolve)."""
        return topics_of(spec).recorded()

    async def session(self) -> None:
        self.problem = None
        await super().session()

    def on_chunk(self, data: bytes, t_host: float) -> None:
        try:
            record = ros2.decode_record(data)
            if record.type == ros2.ODOMETRY:
                odometry = ros2.decode_odometry(record.data)
                item: Any = pose_of(odometry, t_host)
                self._stamps[item.t_robot] = odometry.stamp
                if len(self._stamps) > STAMPS_KEPT:
                    del self._stamps[next(iter(self._stamps))]
                self.latest = item
            elif record.type == ros2.LASER_SCAN:
                item = scan_of(ros2.decode_scan(record.data), t_host)
            else:
                self.counters["other_types"] += 1
                return
        except ros2.Ros2FormatError as exc:
            self.counters["bad_samples"] += 1
            self.emit(t_host, {"kind": "drop", "why": str(exc)})
            return
        self.counters["samples"] += 1
        self.emit(t_host, item)
        self.out.put(item)

    def acting_on(self, odometry: Pose2D) -> None:
        """Its commands carry this odometry's stamp (exact: the one its sample carried)."""
        super().acting_on(odometry)
        self._stamp = self._stamps.get(odometry.t_robot) or ros2.Stamp.of(odometry.t_robot)

    def send_velocity(self, v: float, w: float) -> bool:
        """Publish (v m/s, ω rad/s); False (counted) when the base is not connected."""
        t = self.topics
        command = ros2.Twist(v, w, self._stamp, "base_link") if t.stamped else ros2.Twist(v, w)
        try:
            self.port.write(ros2.encode_record(t.name(t.cmd_vel), t.command_type, ros2.encode_twist(command)))
        except Disconnected:
            self.counters["unsent"] += 1
            return False
        self.counters["commands"] += 1
        return True

    def stop(self) -> bool:
        self.counters["stops"] += 1
        return all([self.send_velocity(0.0, 0.0) for _ in range(STOP_REPEATS)])


def topics_of(spec: PortSpec) -> Topics:
    """A ``ros2:[NS][,settings]`` spec's topics: WHERE is the namespace, ``ns=`` says it too."""
    return Topics.of_settings({"ns": spec.where, **spec.settings})
