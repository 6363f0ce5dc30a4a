"""rfhoming's items as ROS 2 messages: which type and topic each goes to, and its fields.

Standard types where ROS 2 has one (``nav_msgs/Odometry``, ``sensor_msgs/LaserScan``,
``geometry_msgs/Twist``, ``geometry_msgs/PointStamped``, ``std_msgs/String``); rfhoming's own
definitions (``rfhoming_msgs/msg/*.msg`` beside this module, a ROS 2 package a workspace can
build) for what has none. The message definitions written into a log come from rosbags' type
store (ROS 2 Humble) plus our .msg files, so a reader needs nothing of rfhoming to decode them.

Messages are plain dicts keyed by field name; each builder returns ``(topic, type, message)``.
"""

from __future__ import annotations

import math
from functools import cache
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from rfhoming.host.estimation.anchors3d import board_direction
from rfhoming.host.export import frames
from rfhoming.host.export.frames import Transform

MSG_DIR = Path(__file__).with_name("rfhoming_msgs") / "msg"
OWN_TYPES = ("AoaAngle", "RssiReading", "AntennaSet", "Bearing")

ODOM = "nav_msgs/msg/Odometry"
SCAN = "sensor_msgs/msg/LaserScan"
TWIST = "geometry_msgs/msg/Twist"
POINT = "geometry_msgs/msg/PointStamped"
POSE = "geometry_msgs/msg/PoseWithCovarianceStamped"
STRING = "std_msgs/msg/String"
TF = "tf2_msgs/msg/TFMessage"
AOA = "rfhoming_msgs/msg/AoaAngle"
RSSI = "rfhoming_msgs/msg/RssiReading"
ANTENNAS = "rfhoming_msgs/msg/AntennaSet"
BEARING = "rfhoming_msgs/msg/Bearing"

COMMANDS = "/rfhoming/cmd_vel"
"""The loop's velocity commands as rfhoming logs and mirrors them: never ``/cmd_vel``, which
any ROS 2 base on the domain would drive on (or ``ros2 bag play`` of the log). The only
``/cmd_vel`` rfhoming publishes is a ``ros2:`` base's own command topic, by its driver."""

TOPICS = {  # topic -> type: the whole vocabulary of an rfhoming log
    "/tf": TF,
    "/tf_static": TF,
    "/odom": ODOM,
    "/scan": SCAN,
    COMMANDS: TWIST,
    "/rfhoming/target": POINT,
    "/rfhoming/fix": POINT,
    "/rfhoming/bearing": BEARING,
    "/rfhoming/events": STRING,
    "/rfhoming/aoa/angle": AOA,
    "/rfhoming/ble/rssi": RSSI,
    "/rfhoming/rss/antenna_set": ANTENNAS,
}

ODOM_FRAME, BASE_FRAME = frames.ODOM, frames.BASE


def offered_qos_profiles(topic: str) -> str:
    """The channel metadata ``offered_qos_profiles`` as ``ros2 bag record`` writes it, so that
    ``ros2 bag play`` offers what rfhoming's ``--ros2`` publishers do: reliable, transient-local
    (latched, as tf2's static broadcaster) for /tf_static, volatile elsewhere.

    The form is rosbag2_storage's (github.com/ros2/rosbag2 ``rosbag2_storage/src/rosbag2_storage/
    qos.cpp``, ``convert<Rosbag2QoS>::encode``; the MCAP plugin stores it per channel,
    ``rosbag2_storage_mcap/src/mcap_storage.cpp`` ``create_topic``): a YAML list of one profile,
    the policies as rmw's enum numbers (history 3 unknown with depth 0, as the graph reports an
    offer; reliability 1 reliable; durability 1 transient local, 2 volatile; liveliness 1
    automatic) and infinite durations as ``RMW_DURATION_INFINITE``. Numbers, not names: an MCAP
    without rosbag2's own metadata record is read as metadata version 8, which takes numbers."""
    durability = 1 if topic == "/tf_static" else 2
    infinite = "\n    sec: 9223372036\n    nsec: 854775807"
    return (f"- history: 3\n  depth: 0\n  reliability: 1\n  durability: {durability}\n  deadline:{infinite}\n"
            f"  lifespan:{infinite}\n  liveliness: 1\n  liveliness_lease_duration:{infinite}\n"
            "  avoid_ros_namespace_conventions: false")

# Odometry covariance (*assumed*: the base reports none). A planar differential drive: z, roll,
# pitch and the sideways/vertical/roll/pitch rates are known to be zero (tiny variance). The
# position spreads with the path driven, 2 % of it (σ), heading 0.02 rad per metre (σ), from a
# floor of 1 mm / 1 mrad; speeds are good to 0.01 m/s and 0.01 rad/s (σ), wheel-slip level.
KNOWN_ZERO_VAR = 1e-9
POSE_SIGMA_PER_M, YAW_SIGMA_PER_M = 0.02, 0.02
POSE_SIGMA_MIN, YAW_SIGMA_MIN = 0.001, 0.001
V_SIGMA, W_SIGMA = 0.01, 0.01


def _diagonal(*variances: float) -> list[float]:
    out = [0.0] * 36
    for i, v in enumerate(variances):
        out[7 * i] = v
    return out


def pose_covariance(path_m: float) -> list[float]:
    """x, y, z, roll, pitch, yaw (row-major 6×6) after ``path_m`` metres of driving."""
    sxy = max(POSE_SIGMA_MIN, POSE_SIGMA_PER_M * path_m)
    syaw = max(YAW_SIGMA_MIN, YAW_SIGMA_PER_M * path_m)
    return _diagonal(sxy**2, sxy**2, KNOWN_ZERO_VAR, KNOWN_ZERO_VAR, KNOWN_ZERO_VAR, syaw**2)


UNKNOWN_VAR = 1e6
"""*assumed*: the variance of what a message has a field for but rfhoming does not know (a tag
fix's orientation), far beyond any angle's; ROS 2 marks no field unknown."""

TWIST_COVARIANCE = _diagonal(V_SIGMA**2, KNOWN_ZERO_VAR, KNOWN_ZERO_VAR, KNOWN_ZERO_VAR, KNOWN_ZERO_VAR, W_SIGMA**2)


@cache
def msgdef(typename: str) -> str:
    """The ROS 2 message definition text (with its dependencies) that an MCAP schema carries."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    own = {}
    for name in OWN_TYPES:
        own.update(get_types_from_msg((MSG_DIR / f"{name}.msg").read_text(), f"rfhoming_msgs/msg/{name}"))
    store.register(own)
    text, _ = store.generate_msgdef(typename, ros_version=2)
    return text


def stamp(t: float) -> dict[str, int]:
    """Seconds -> builtin_interfaces/Time (negative times clamp to 0)."""
    ns = max(0, round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def header(t: float, frame: str) -> dict[str, Any]:
    return {"stamp": stamp(t), "frame_id": frame}


def yaw_quaternion(theta: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2), "w": math.cos(theta / 2)}


def odometry(t: float, x: float, y: float, theta: float, v: float, w: float,
             path_m: float = 0.0) -> tuple[str, str, dict[str, Any]]:
    """The base's odometry (metres, radians, m/s, rad/s), with the assumed covariances above
    after ``path_m`` metres driven."""
    return "/odom", ODOM, {
        "header": header(t, ODOM_FRAME), "child_frame_id": BASE_FRAME,
        "pose": {"pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": yaw_quaternion(theta)},
                 "covariance": pose_covariance(path_m)},
        "twist": {"twist": {"linear": {"x": v, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": w}},
                  "covariance": TWIST_COVARIANCE},
    }


def transforms(topic: str, t: float, tfs: list[Transform]) -> tuple[str, str, dict[str, Any]]:
    """``/tf`` or ``/tf_static``: a tf2_msgs/TFMessage of parent -> child transforms."""
    return topic, TF, {"transforms": [
        {"header": header(t, tf.parent), "child_frame_id": tf.child,
         "transform": {"translation": dict(zip("xyz", map(float, tf.xyz))), "rotation": tf.quaternion()}}
        for tf in tfs]}


def odom_transform(t: float, x: float, y: float, theta: float) -> tuple[str, str, dict[str, Any]]:
    """odom -> base_link on /tf, from one odometry record."""
    return transforms("/tf", t, [Transform(ODOM_FRAME, BASE_FRAME, (x, y, 0.0), theta)])


def laser_scan(t: float, scan: Any) -> tuple[str, str, dict[str, Any]]:
    """A range scan (:class:`~rfhoming.host.drivers.robot_base.Scan`) in the ``laser`` frame,
    REP 117: every range within [range_min, range_max], no return or beyond range_max +inf,
    below range_min -inf; range_min, range_max, scan_time and time_increment are the sensor's."""
    return "/scan", SCAN, {
        "header": header(t, frames.LASER), "angle_min": scan.angle_min,
        "angle_max": scan.angle_max, "angle_increment": scan.angle_increment,
        "time_increment": scan.time_increment, "scan_time": scan.scan_time, "range_min": scan.range_min,
        "range_max": scan.range_max, "ranges": [rep117(r, scan.range_min, scan.range_max) for r in scan.ranges],
        "intensities": [],
    }


def rep117(r: float | None, range_min: float, range_max: float) -> float:
    """A range as REP 117 has it: +inf for no return or beyond range_max, -inf below range_min."""
    if r is None or r > range_max:
        return math.inf
    return -math.inf if r < range_min else r


def twist(v: float, w: float) -> tuple[str, str, dict[str, Any]]:
    """A velocity command (Twist has no header: the log time is its time), on :data:`COMMANDS`."""
    return COMMANDS, TWIST, {"linear": {"x": v, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": w}}


def point(topic: str, t: float, xy: list[float], frame: str = ODOM_FRAME) -> tuple[str, str, dict[str, Any]]:
    return topic, POINT, {"header": header(t, frame), "point": {"x": float(xy[0]), "y": float(xy[1]), "z": 0.0}}


def tag_topic(tag: str, what: str) -> str:
    """A located tag's topic: ``/rfhoming/tag_<ID>/pose`` or ``/point`` (a ROS name token may
    not start with a digit, a tag id may)."""
    return f"/rfhoming/tag_{tag}/{what}"


def tag_pose(t: float, tag: str, xyz: Any, covariance: Any) -> tuple[str, str, dict[str, Any]]:
    """A tag's fix in ``map`` with its 3×3 position covariance (m²); it has no orientation:
    identity, with UNKNOWN_VAR rotation variances."""
    cov = [0.0] * 36
    for i in range(3):
        for j in range(3):
            cov[6 * i + j] = float(covariance[i][j])
        cov[7 * (i + 3)] = UNKNOWN_VAR
    return tag_topic(tag, "pose"), POSE, {
        "header": header(t, frames.MAP),
        "pose": {"pose": {"position": dict(zip("xyz", map(float, xyz))),
                          "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}, "covariance": cov}}


def tag_point(t: float, tag: str, xyz: Any) -> tuple[str, str, dict[str, Any]]:
    """A tag's fix in ``map`` as a point (what a viewer draws without a covariance)."""
    return tag_topic(tag, "point"), POINT, {"header": header(t, frames.MAP), "point": dict(zip("xyz", map(float, xyz)))}


def text(topic: str, value: str) -> tuple[str, str, dict[str, Any]]:
    return topic, STRING, {"data": value}


def aoa_angle(t: float, frame: str, e: Any, board_sign: int = -1, model: str = "spherical") -> tuple[str, str, dict[str, Any]]:
    """A u-connectLocate AngleEvent in its board's frame, REP 103 signs (x the boresight, z up).

    The board's own sign (negative = tag to its left) is turned into the direction in the
    board's frame by the locator's conversion (host/estimation/anchors3d.py ``board_direction``,
    ``model`` the site's angle model), so a bearing drawn from the message points where the
    locator's ray does. ``board_sign``: the config's ``[mounting] azimuth_sign`` for the robot's
    board (-1: the XPLR-AOA's convention; +1 a board reporting counter-clockwise)."""
    x, y, z = board_direction(-board_sign * e.azimuth, e.elevation, model)
    return "/rfhoming/aoa/angle", AOA, {
        "header": header(t, frame), "instance_id": e.instance_id, "anchor_id": e.anchor_id,
        "azimuth_rad": math.atan2(y, x), "elevation_rad": math.atan2(z, math.hypot(x, y)),
        "board_azimuth_deg": e.azimuth, "board_elevation_deg": e.elevation, "rssi1_dbm": e.rssi1,
        "reserved": e.reserved, "channel": e.channel, "timestamp_ms": e.timestamp_ms & 0xFFFFFFFF,
        "seq": -1 if e.seq is None else e.seq,
    }


def rssi_reading(t: float, r: Any) -> tuple[str, str, dict[str, Any]]:
    """An AdvReport record (the address goes MSB first, as printed)."""
    return "/rfhoming/ble/rssi", RSSI, {
        "header": header(t, frames.BLE), "node_id": r.node_id, "address": r.addr[::-1].hex().upper(),
        "rssi_dbm": r.rssi_dbm, "tx_power_dbm": r.tx_power_dbm, "channel": r.channel,
    }


def antenna_set(t: float, r: Any) -> tuple[str, str, dict[str, Any]]:
    """An AntennaSet record."""
    return "/rfhoming/rss/antenna_set", ANTENNAS, {
        "header": header(t, frames.RSS), "node_id": r.node_id, "emitter_seq": r.emitter_seq, "channel": r.channel,
        "page": r.page, "rssi_base_dbm": r.rssi_base_dbm, "valid_mask": r.valid_mask,
        "ed": [a.ed for a in r.antennas], "lqi": [a.lqi for a in r.antennas], "dt_us": [a.dt_us for a in r.antennas],
    }


def bearing(t: float, fields: dict[str, Any]) -> tuple[str, str, dict[str, Any]]:
    """A run log measurement: S0 gives theta_s/distance, S2 theta/range, S1 azimuth/rssi only."""
    def pick(*names: str) -> float:
        for name in names:
            if fields.get(name) is not None:
                return float(fields[name])
        return math.nan

    return "/rfhoming/bearing", BEARING, {
        "header": header(t, BASE_FRAME), "source": str(fields.get("source", "")),
        "bearing_rad": pick("theta_s", "theta"), "range_m": pick("distance", "range"),
        "board_azimuth_deg": pick("azimuth"), "rssi_dbm": pick("rssi"),
    }
