"""REP 105 frames of a run: ``map`` (the site: surveyed anchors), ``odom`` (the base's
odometry), ``base_link`` (the robot) and one frame per sensor on the robot, placed by the
config's ``[mounting]``. Shared by the MCAP recorder and the live view; imports nothing heavy.

odom -> base_link comes from every odometry record; base_link -> sensor is static; map -> odom
exists only when fixed anchors locate the robot (S3's odometry offset).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

MAP, ODOM, BASE = "map", "odom", "base_link"
AOA, LASER, RSS, BLE = "aoa_link", "laser", "rss_link", "ble_link"
STATION = "dock_station"  # S1's XPLR-AOA sits on the docking station, whose place is not known
ANCHOR_PREFIX = "anchor_"  # the fixed anchors of --controller anchors: anchor_<id>, not placed

ITEM_FRAMES = {"angle": AOA, "adv_report": BLE, "antenna_set": RSS, "range_scan": LASER, "range_scan_v2": LASER}
"""A device item's kind -> the frame its readings are in (robot-mounted sensors)."""


class Transform(NamedTuple):
    parent: str
    child: str
    xyz: tuple[float, float, float]
    yaw: float  # radians, about z
    roll: float = 0.0  # radians, about x (a board mounted upside down)
    pitch: float = 0.0  # radians, about y (REP 103: positive tips x down toward -z)

    def quaternion(self) -> dict[str, float]:
        """z-y-x (yaw, then pitch, then roll) as a unit quaternion."""
        cy, sy = math.cos(self.yaw / 2), math.sin(self.yaw / 2)
        cp, sp = math.cos(self.pitch / 2), math.sin(self.pitch / 2)
        cr, sr = math.cos(self.roll / 2), math.sin(self.roll / 2)
        return {"x": sr * cp * cy - cr * sp * sy, "y": cr * sp * cy + sr * cp * sy,
                "z": cr * cp * sy - sr * sp * cy, "w": cr * cp * cy + sr * sp * sy}


def sensor_mounts(mounting: Any) -> list[Transform]:
    """base_link -> each sensor frame, from the config's ``[mounting]`` (None: all at the centre)."""
    if mounting is None:
        return [Transform(BASE, f, (0.0, 0.0, 0.0), 0.0) for f in (AOA, LASER, RSS, BLE)]
    return [
        Transform(BASE, AOA, tuple(mounting.aoa_xyz_m), math.radians(mounting.yaw_offset_deg),
                  math.pi if mounting.upside_down else 0.0),
        Transform(BASE, LASER, tuple(mounting.laser_xyz_m), math.radians(mounting.laser_yaw_deg)),
        Transform(BASE, RSS, tuple(mounting.rss_xyz_m), 0.0),
        Transform(BASE, BLE, tuple(mounting.ble_xyz_m), 0.0),
    ]


def anchor_mounts(anchors: Any) -> list[Transform]:
    """map -> anchor_<id> of a site's fixed anchors (host/site.py ``Anchor``: surveyed position,
    yaw with its calibrated offset, pitch lifting the boresight up, roll), the frames their angle
    events are in."""
    return [Transform(MAP, ANCHOR_PREFIX + a.id, tuple(a.position),
                      math.radians(a.yaw_deg + a.calibration.yaw_offset_deg), math.radians(a.roll_deg),
                      -math.radians(a.pitch_deg)) for a in anchors]


def item_frame(kind: str, source: str | None) -> str:
    """The frame of a device item; an AoA board off the robot (S1's station, fixed anchors)
    gets a frame of its own, which no transform places."""
    if kind == "angle" and source == "dock_aoa":
        return STATION
    if kind == "angle" and source == "anchors":
        return ANCHOR_PREFIX + "board"
    return ITEM_FRAMES[kind]


def map_to_odom(offset: list[float]) -> Transform:
    """S3's odometry offset (world = odometry + offset; heading trusted) as map -> odom."""
    return Transform(MAP, ODOM, (float(offset[0]), float(offset[1]), 0.0), 0.0)
