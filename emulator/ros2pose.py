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
pose the robot stands at the scenario's start. Loopback only unless ``discovery=subnet``, as the
emulated ROS 2 robot.

It speaks up (warnings, each repeated every ``REPEAT_S`` while it holds): no pose within
``wait`` seconds (saying which writers it did see), a pose with a non-finite value or another
``header.frame_id`` than ``frame_id=`` (else the first pose's) -- both refused and counted --
and poses that stop for ``stale`` seconds: the follower is then stale, and the emulator's radios
hear nothing until poses come again (a robot whose pose is unknown has no place to hear from).
"""

import logging
import math
import time
from collections.abc import Callable
from typing import Any

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.internal import InvalidSample

from rfhoming.emulator.ros2robot import join, reader
from rfhoming.protocol import ros2
from rfhoming.protocol import ros2dds as dds

FRAMES = ("start", "world")
TYPES = {ros2.dds_type(t): t for t in (ros2.ODOMETRY, ros2.POSE_STAMPED)}
WAIT_S = 5.0  # no pose this long after the start: said (a mistyped topic, a simulator not started)
STALE_S = 1.0  # poses stopped this long: stale, the radios stop (a simulator's ground truth comes at 10 Hz or more)
REPEAT_S = 30.0  # a warning that still holds is said again this often
SEEN_TOPICS = 20  # the other topics' names kept to suggest (bounded)
log = logging.getLogger(__name__)


class PoseFollower:
    """The latest pose of a ROS 2 robot on ``topic``, in the scenario's world frame."""

    def __init__(self, topic: str, domain: int = 0, discovery: str = "localhost", frame: str = "start",
                 wait: float = WAIT_S, stale: float = STALE_S, frame_id: str | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if frame not in FRAMES:
            raise ValueError(f"frame={frame!r}: one of {', '.join(FRAMES)}")
        if not (wait > 0 and stale > 0):
            raise ValueError(f"wait={wait:g}, stale={stale:g}: seconds above 0")
        self.topic, self.domain, self.discovery, self.frame = ros2.topic_name("", topic), domain, discovery, frame
        self.wait_s, self.stale_s, self.frame_id, self.clock = wait, stale, frame_id, clock
        self.counters = {"poses": 0, "refused": 0, "wrong_frame": 0}
        self.type: str | None = None
        self.state = "waiting"  # -> following <-> stale
        self._latest: tuple[float, float, float] | None = None
        self._heard_at: float | None = None  # ``clock`` at the newest pose taken
        self._started = clock()
        self._origin: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
        self._entities: list[Any] = []
        self._warned: set[str] = set()  # the other types seen on the topic, each said once
        self._topics: set[str] = set()  # other topics with writers (bounded): what a mistyped name may have meant
        self._said: dict[str, tuple[float, int]] = {}  # each warning: when last said, and its count then
        self._wrong_frame = ""  # the frame of the last pose refused for it

    def start(self) -> None:
        self._domain, self._dp = join(self.domain, self.discovery)  # the domain object kept: it holds the configuration
        self._publications = BuiltinDataReader(self._dp, BuiltinTopicDcpsPublication)

    def _discover(self) -> None:
        """Reads what the domain's writers announce until one writes ``topic`` as a known type."""
        for p in self._publications.take(64):
            if isinstance(p, InvalidSample):
                continue
            if p.topic_name != ros2.dds_topic(self.topic):
                if p.topic_name.startswith("rt/") and len(self._topics) < SEEN_TOPICS:
                    self._topics.add(p.topic_name[2:])
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
        """Cyclone's listener thread: the newest pose wins; one in another frame than the first
        (or ``frame_id=``), or not finite, is refused (counted, said by :meth:`_watch`)."""
        if self.frame_id is None:
            self.frame_id = sample.header.frame_id
        if sample.header.frame_id != self.frame_id:
            self._wrong_frame = sample.header.frame_id
            self.counters["wrong_frame"] += 1
            return
        pose = sample.pose.pose if isinstance(sample, dds.Odometry) else sample.pose
        q = pose.orientation
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        xy_yaw = (pose.position.x, pose.position.y, yaw)
        if not all(math.isfinite(v) for v in (*xy_yaw, q.x, q.y, q.z, q.w)):
            self.counters["refused"] += 1
            return
        self.counters["poses"] += 1
        self._latest = xy_yaw
        self._heard_at = self.clock()

    def _watch(self) -> None:
        """The state (waiting, following, stale) from when the newest pose came, and the warnings."""
        now = self.clock()
        if self._heard_at is None:
            if now - self._started > self.wait_s:
                self._say("none", f"no pose in {now - self._started:.0f} s: {self._why_silent()}; the radios report "
                          "from the scenario's start until one comes")
        elif now - self._heard_at > self.stale_s:
            if self.state != "stale":
                self.state = "stale"
                self._said.pop("stale", None)
            self._say("stale", f"no pose for {now - self._heard_at:.1f} s (its publisher stopped or stalls): the "
                      "radios hear nothing until poses come again")
        elif self.state != "following":
            if self.state == "stale":
                log.warning("--pose-from %s: poses again: the radios hear again", self.topic)
            self.state = "following"
        for key in ("refused", "wrong_frame"):
            if (count := self.counters[key]) > self._said.get(key, (0.0, 0))[1]:
                why = ("with a value that is not finite (NaN, inf)" if key == "refused" else
                       f"in frame {self._wrong_frame!r}, not {self.frame_id!r} (the first pose's, or frame_id=)")
                self._say(key, f"{count} pose(s) refused so far, {why}", count)

    def _say(self, key: str, what: str, count: int = 0) -> None:
        """A warning, said at once and again every REPEAT_S while it holds."""
        now = self.clock()
        last = self._said.get(key)
        if last is None or now - last[0] >= REPEAT_S:
            self._said[key] = (now, count)
            log.warning("--pose-from %s: %s", self.topic, what)

    def _why_silent(self) -> str:
        if self._warned:
            return f"its writers publish {', '.join(sorted(self._warned))}, not nav_msgs/Odometry or PoseStamped"
        if self.type is not None:
            return (f"a {self.type} writer is there but nothing came (a best-effort reader: is its robot moving, "
                    "its simulator running?)")
        seen = f"; writers seen: {', '.join(sorted(self._topics))}" if self._topics else ""
        return f"no writer of {self.topic} on ROS 2 domain {self.domain} (a mistyped topic or domain?{seen})"

    @property
    def stale(self) -> bool:
        """Its publisher stopped: the radios hear nothing (Emulator.step)."""
        return self.state == "stale"

    def pose(self, start: tuple[float, float, float]) -> tuple[float, float, float] | None:
        """The robot's pose in the scenario's world now, None before the first; ``start`` is
        where the scenario's robot starts (``frame=start`` puts the first pose there)."""
        if self.type is None:
            self._discover()
        self._watch()
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
