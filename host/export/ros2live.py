"""``--ros2``: what rfhoming senses, published live on ROS 2 -- the same topics, types and
frames as the MCAP recording (host/export/recorder.py makes the messages; this sink publishes
them over DDS instead of writing them). The IDL types are made from the same message
definitions the MCAP schemas carry (rosbags' ROS 2 Humble store plus rfhoming_msgs), under
ROS 2's DDS names. QoS: /tf_static reliable and transient-local (as tf2's static broadcaster),
everything else ROS 2's default profile. Loopback only unless ``discovery=subnet``.

Time: every message is stamped on the host's wall clock (seconds since 1970), whatever the
recording would use: a base's clock (a microcontroller's time since boot) would put the stamps
in 1970 and tf2 on every other node, on wall time, would find no transform at "now". Publishing
``/clock`` from the base's time instead would make every node on the domain run on it
(``use_sim_time``), the robot's own too. A reading is stamped when it arrived; a run log record
(command, estimate, event) when it is published, as it is made.

The loop's commands are mirrored on ``/rfhoming/cmd_vel`` (rosmsgs.COMMANDS): ``/cmd_vel`` is
published only by a ``ros2:`` base's own driver, to that robot.
"""

# no `from __future__ import annotations`: cyclonedds reads the generated fields at run time
import time
from collections import Counter
from functools import cache
from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as idl
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.interfaces import Nodetype

from rfhoming.host.export import frames, rosmsgs
from rfhoming.host.export.recorder import McapRecorder
from rfhoming.protocol import ros2
from rfhoming.host.dds import participant
from rfhoming.protocol.ros2dds import DEFAULT_QOS

BASE = {"bool": bool, "int8": idl.int8, "uint8": idl.uint8, "byte": idl.uint8, "char": idl.uint8, "octet": idl.uint8,
        "int16": idl.int16, "uint16": idl.uint16, "int32": idl.int32, "uint32": idl.uint32, "int64": idl.int64,
        "uint64": idl.uint64, "float32": idl.float32, "float64": idl.float64, "string": str}
STATIC_QOS = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.TransientLocal,
                 Policy.History.KeepLast(1))


@cache
def _store() -> Any:
    store = get_typestore(Stores.ROS2_HUMBLE)
    own = {}
    for name in rosmsgs.OWN_TYPES:
        own.update(get_types_from_msg((rosmsgs.MSG_DIR / f"{name}.msg").read_text(), f"rfhoming_msgs/msg/{name}"))
    store.register(own)
    return store


def _annotation(node: tuple[Any, Any]) -> Any:
    kind, rest = node
    if kind == Nodetype.BASE:
        return BASE[rest[0]]
    if kind == Nodetype.NAME:
        return idl_type(rest)
    inner, length = rest
    if kind == Nodetype.ARRAY:
        return idl.array[_annotation(inner), length]  # type: ignore[misc]  # cyclonedds builds it at run time
    return idl.sequence[_annotation(inner)]  # type: ignore[misc]  # cyclonedds builds it at run time


@cache
def idl_type(ros_type: str) -> type[IdlStruct]:
    """A ROS 2 message type as a cyclonedds IDL struct named as ROS 2 names it on DDS."""
    _, fields = _store().fielddefs[ros_type]
    return make_idl_struct(ros_type.replace("/", "_"), ros2.dds_type(ros_type),
                           {name: _annotation(node) for name, node in fields} or {"structure_needs_at_least_one_member": idl.uint8})


def sample(ros_type: str, message: dict[str, Any]) -> IdlStruct:
    """A message as rosmsgs builds it (dicts by field name) -> an instance of its IDL type."""
    _, fields = _store().fielddefs[ros_type]
    values = {}
    for name, (kind, rest) in fields:
        value = message[name]
        if kind == Nodetype.NAME:
            value = sample(rest, value)
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and rest[0][0] == Nodetype.NAME:
            value = [sample(rest[0][1], v) for v in value]
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            value = list(value)
        values[name] = value
    return idl_type(ros_type)(**values)


class Ros2Publisher(McapRecorder):
    """The MCAP recorder's messages, published on a DDS domain instead of written."""

    def __init__(self, domain: int = 0, discovery: str = "localhost", *, skip: frozenset[str] = frozenset(),
                 source: str | None = None, site: Any = None, robot: bool = True) -> None:
        """``skip``: topics not to publish (a ROS 2 base's own /odom, /scan, /tf, /cmd_vel on its
        domain); ``source`` and ``site``: as the recorder's (``anchors``: angles in anchor_<id>,
        placed in map from the site on /tf_static); ``robot=False``: no robot (``locate``), so no
        base_link -> sensor frames."""
        # McapRecorder's state, without its file
        self.clock, self.commands_from, self.mounting, self.source, self.site = "host", "runlog", None, source, site
        self.robot = robot
        self._clocks: dict[str, Any] = {}
        self._static_written = False
        self._last_xy: tuple[float, float] | None = None
        self.path_m = 0.0
        self.robot_time: float | None = None
        self.counts: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()
        self._closed = False
        self.domain = domain
        self._participant = participant(domain, discovery)
        self._writers: dict[str, DataWriter[Any]] = {}
        self.skip = skip

    def static_transforms(self) -> list[frames.Transform]:
        return super().static_transforms() if self.robot else frames.anchor_mounts(self.site)

    def _on_runlog(self, record: dict[str, Any]) -> None:
        """A run log record, stamped now on the host's clock (its ``t`` is robot time)."""
        super()._on_runlog({**record, "t": time.time()})

    def _write(self, t: float, topic: str, typename: str, message: dict[str, Any], device: str = "") -> None:
        if self._closed or topic in self.skip:
            return
        if not self._static_written:
            self._static_written = True
            self._write(t, *rosmsgs.transforms("/tf_static", t, self.static_transforms()))
        writer = self._writers.get(topic)
        if writer is None:
            qos = STATIC_QOS if topic == "/tf_static" else DEFAULT_QOS
            writer = self._writers[topic] = DataWriter(self._participant, Topic(
                self._participant, ros2.dds_topic(topic), idl_type(typename)), qos=qos)
        writer.write(sample(typename, message))
        self.counts[topic] += 1

    def on_position(self, position: Any) -> None:
        """A located tag (host/locate.py ``Position``, host time) as its pose and point in
        ``map``; never raises (a sink's rule)."""
        try:
            self._write(position.t, *rosmsgs.tag_pose(position.t, position.tag, position.point, position.covariance))
            self._write(position.t, *rosmsgs.tag_point(position.t, position.tag, position.point))
        except Exception as exc:  # noqa: BLE001 - a watcher must not stop the locator
            self._failed("position", exc)

    def flush(self) -> None:
        """Nothing is held: every message is published as it is made."""

    def close(self) -> None:
        self._closed = True
        self._writers = {}
