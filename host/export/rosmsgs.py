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

MSG_DIR = Path(__file__).with_name("rfhoming_msgs") / "msg"
OWN_TYPES = ("AoaAngle", "RssiReading", "AntennaSet", "Bearing")

ODOM = "nav_msgs/msg/Odometry"
SCAN = "sensor_msgs/msg/LaserScan"
TWIST = "geometry_msgs/msg/Twist"
POINT = "geometry_msgs/msg/PointStamped"
STRING = "std_msgs/msg/String"
AOA = "rfhoming_msgs/msg/AoaAngle"
RSSI = "rfhoming_msgs/msg/RssiReading"
ANTENNAS = "rfhoming_msgs/msg/AntennaSet"
BEARING = "rfhoming_msgs/msg/Bearing"

TOPICS = {  # topic -> type: the whole vocabulary of an rfhoming log
    "/odom": ODOM,
    "/scan": SCAN,
    "/cmd_vel": TWIST,
    "/rfhoming/target": POINT,
    "/rfhoming/fix": POINT,
    "/rfhoming/bearing": BEARING,
    "/rfhoming/events": STRING,
    "/rfhoming/aoa/angle": AOA,
    "/rfhoming/ble/rssi": RSSI,
    "/rfhoming/rss/antenna_set": ANTENNAS,
}

ODOM_FRAME, BASE_FRAME = "odom", "base_link"
SCAN_RANGE_MAX = 65.535  # the range scan record's largest range: u16 millimetres


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


def odometry(t: float, x: float, y: float, theta: float, v: float, w: float) -> tuple[str, str, dict]:
    """The base's odometry (metres, radians, m/s, rad/s); no covariance is known (zeros)."""
    zero = [0.0] * 36
    return "/odom", ODOM, {
        "header": header(t, ODOM_FRAME), "child_frame_id": BASE_FRAME,
        "pose": {"pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": yaw_quaternion(theta)},
                 "covariance": zero},
        "twist": {"twist": {"linear": {"x": v, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": w}},
                  "covariance": zero},
    }


def laser_scan(t: float, angle_min: float, increment: float, ranges: list[float | None]) -> tuple[str, str, dict]:
    """A range scan; no return -> +inf (REP 117)."""
    n = len(ranges)
    return "/scan", SCAN, {
        "header": header(t, BASE_FRAME), "angle_min": angle_min,
        "angle_max": angle_min + increment * max(0, n - 1), "angle_increment": increment,
        "time_increment": 0.0, "scan_time": 0.0, "range_min": 0.0, "range_max": SCAN_RANGE_MAX,
        "ranges": [math.inf if r is None else r for r in ranges], "intensities": [],
    }


def twist(v: float, w: float) -> tuple[str, str, dict]:
    """A velocity command (Twist has no header: the log time is its time)."""
    return "/cmd_vel", TWIST, {"linear": {"x": v, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": w}}


def point(topic: str, t: float, xy: list[float]) -> tuple[str, str, dict]:
    return topic, POINT, {"header": header(t, ODOM_FRAME), "point": {"x": float(xy[0]), "y": float(xy[1]), "z": 0.0}}


def text(topic: str, value: str) -> tuple[str, str, dict]:
    return topic, STRING, {"data": value}


def aoa_angle(t: float, device: str, e: Any) -> tuple[str, str, dict]:
    """A u-connectLocate AngleEvent."""
    return "/rfhoming/aoa/angle", AOA, {
        "header": header(t, device), "instance_id": e.instance_id, "anchor_id": e.anchor_id,
        "azimuth_deg": e.azimuth, "elevation_deg": e.elevation, "rssi1_dbm": e.rssi1, "reserved": e.reserved,
        "channel": e.channel, "timestamp_ms": e.timestamp_ms & 0xFFFFFFFF, "seq": -1 if e.seq is None else e.seq,
    }


def rssi_reading(t: float, device: str, r: Any) -> tuple[str, str, dict]:
    """An AdvReport record (the address goes MSB first, as printed)."""
    return "/rfhoming/ble/rssi", RSSI, {
        "header": header(t, device), "node_id": r.node_id, "address": r.addr[::-1].hex().upper(),
        "rssi_dbm": r.rssi_dbm, "tx_power_dbm": r.tx_power_dbm, "channel": r.channel,
    }


def antenna_set(t: float, device: str, r: Any) -> tuple[str, str, dict]:
    """An AntennaSet record."""
    return "/rfhoming/rss/antenna_set", ANTENNAS, {
        "header": header(t, device), "node_id": r.node_id, "emitter_seq": r.emitter_seq, "channel": r.channel,
        "page": r.page, "rssi_base_dbm": r.rssi_base_dbm, "valid_mask": r.valid_mask,
        "ed": [a.ed for a in r.antennas], "lqi": [a.lqi for a in r.antennas], "dt_us": [a.dt_us for a in r.antennas],
    }


def bearing(t: float, fields: dict[str, Any]) -> tuple[str, str, dict]:
    """A run log measurement: S0 gives theta_s/distance, S2 theta/range, S1 azimuth/rssi only."""
    def pick(*names: str) -> float:
        for name in names:
            if fields.get(name) is not None:
                return float(fields[name])
        return math.nan

    return "/rfhoming/bearing", BEARING, {
        "header": header(t, BASE_FRAME), "source": str(fields.get("source", "")),
        "bearing_rad": pick("theta_s", "theta"), "range_m": pick("distance", "range"),
        "azimuth_deg": pick("azimuth"), "rssi_dbm": pick("rssi"),
    }
