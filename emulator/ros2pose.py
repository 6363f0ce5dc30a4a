"""``emulate --pose-from ros2:TOPIC``: the emulated radios ride on a robot that is not the
emulator's -- a ROS 2 robot whose pose comes on TOPIC, e.g. a simulator's ground truth
(Gazebo's, a motion-capture system's) -- so any ROS 2 simulator can rehearse homing on
rfhoming's emulated receivers while rfhoming drives that robot (``run --base ros2:``).

TOPIC carries nav_msgs/Odometry or geometry_msgs/PoseStamped; which one is read from DDS
discovery (the type its writer announces), so a user names the topic only. Each pose moves
the world's robot, and with it every receiver mounted on the robot; the scenario's own base is
not served. ``frame=start`` (the default): the first pose heard is the scenario's start pose and
later motion is applied relative to it, so the scenario's targets sit where they would for its
own robot whatever the simulator's spawn point; ``frame=world``: the poses are the scenario's
world coordinates (x, y and yaw of REP 103; z, roll and pitch are ignored). Until the first
pose the robot stands at the scenario's start. A pose with a non-finite value is refused
(counted). Loopback only unless ``discovery=subnet``, as the emulated ROS 2 robot.
"""

import logging
import math
from typing import Any

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.internal import InvalidSample

from rfhoming.emulator.ros2robot import join, reader
from rfhoming.protocol import ros2
from rfhoming.protocol import ros2dds as dds

FRAMES = ("start", "world")
TYPES = {ros2.dds_type(t): t for t in (ros2.ODOMETRY, ros2.POSE_STAMPED)}
log = logging.getLogger(__name__)


class PoseFollower:
    """The latest pose of a ROS 2 robot on ``topic``, in the scenario's world frame."""

    def __init__(self, topic: str, domain: int = 0, discovery: str = "localhost", frame: str = "start") -> None:
        if frame not in FRAMES:
            raise ValueError(f"frame={frame!r}: one of {', '.join(FRAMES)}")
        self.topic, self.domain, self.discovery, self.frame = ros2.topic_name("", topic), domain, discovery, frame
        self.counters = {"poses": 0, "refused": 0}
        self.type: str | None = None
        self._latest: tuple[float, float, float] | None = None
        self._origin: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
        self._entities: list[Any] = []
        self._warned: set[str] = set()  # the other types seen on the topic, each said once

    def start(self) -> None:
        self._domain, self._dp = join(self.domain, self.discovery)  # the domain object kept: it holds the configuration
        self._publications = BuiltinDataReader(self._dp, BuiltinTopicDcpsPublication)

    def _discover(self) -> None:
        """Reads what the domain's writers announce until one writes ``topic`` as a known type."""
        for p in self._publications.take(64):
            if isinstance(p, InvalidSample) or p.topic_name != ros2.dds_topic(self.topic):
                continue
            kind = TYPES.get(p.type_name)
            if kind is None:
                if p.type_name not in self._warned:
                    self._warned.add(p.type_name)
                    log.warning("--pose-from %s: a writer of %s, not nav_msgs/Odometry or geometry_msgs/PoseStamped: "
                                "ignored", self.topic, p.type_name)
                continue
            self.type = kind
            self._entities = [reader(self._dp, self.topic, kind, self._on_sample, dds.SENSOR_QOS)]
            return

    def _on_sample(self, sample: Any) -> None:
        """Cyclone's listener thread: the newest pose wins."""
        pose = sample.pose.pose if isinstance(sample, dds.Odometry) else sample.pose
        q = pose.orientation
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        xy_yaw = (pose.position.x, pose.position.y, yaw)
        if not all(math.isfinite(v) for v in (*xy_yaw, q.x, q.y, q.z, q.w)):
            self.counters["refused"] += 1
            return
        self.counters["poses"] += 1
        self._latest = xy_yaw

    def pose(self, start: tuple[float, float, float]) -> tuple[float, float, float] | None:
        """The robot's pose in the scenario's world now, None before the first; ``start`` is
        where the scenario's robot starts (``frame=start`` puts the first pose there)."""
        if self.type is None:
            self._discover()
        latest = self._latest
        if latest is None or self.frame == "world":
            return latest
        if self._origin is None:
            self._origin = (latest, start)
        (x0, y0, t0), (sx, sy, st) = self._origin
        dx, dy = latest[0] - x0, latest[1] - y0
        fx, fy = dx * math.cos(t0) + dy * math.sin(t0), -dx * math.sin(t0) + dy * math.cos(t0)  # in the first pose's frame
        return (sx + fx * math.cos(st) - fy * math.sin(st), sy + fx * math.sin(st) + fy * math.cos(st),
                math.remainder(st + latest[2] - t0, math.tau))

    def close(self) -> None:
        self._entities = []
