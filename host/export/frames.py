"""REP 105 frames of a run: ``map`` (the site: surveyed anchors), ``odom`` (the base's
odometry), ``base_link`` (the robot) and one frame per sensor on the robot, placed by the
config's ``[mounting]``; and the AoA boards off the robot: S1's docking station
(``dock_station``) and a site's fixed anchors (``anchor_<id>``, the id their +UUDF lines carry).
Shared by the MCAP recorder and the live view; imports nothing heavy.

odom -> base_link comes from every odometry record; base_link -> sensor is static; map -> odom
exists only when fixed anchors locate the robot (S3's odometry offset, the anchors controller's
alignment); map -> anchor_<id> is static, from the site file (surveyed position and mounting);
odom -> dock_station is S1's fit of the station in the odometry frame, refined as readings come
(the station is fixed, its place in odom is what the readings say).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

MAP, ODOM, BASE = "map", "odom", "base_link"
AOA, LASER, RSS, BLE = "aoa_link", "laser", "rss_link", "ble_link"
STATION = "dock_station"  # S1's XPLR-AOA sits on the docking station: x its boresight, z up
ANCHOR_PREFIX = "anchor_"  # the fixed anchors of --controller anchors: anchor_<id>


class Transform(NamedTuple):
    parent: str
    child: str
    xyz: tuple[float, float, float]
    yaw: float  # radians, about z
    roll: float = 0.0  # radians, about x (a board mounted upside down)
    pitch: float = 0.0  # radians, about y (REP 103: positive tips x down)

    def quaternion(self) -> dict[str, float]:
        """z-y-x (yaw, pitch, then roll: R = Rz Ry Rx) as a unit quaternion."""
        cy, sy = math.cos(self.yaw / 2), math.sin(self.yaw / 2)
        cp, sp = math.cos(self.pitch / 2), math.sin(self.pitch / 2)
        cr, sr = math.cos(self.roll / 2), math.sin(self.roll / 2)
        return {"x": cy * cp * sr - sy * sp * cr, "y": cy * sp * cr + sy * cp * sr,
                "z": sy * cp * cr - cy * sp * sr, "w": cy * cp * cr + sy * sp * sr}


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


def anchor_frame(anchor_id: str) -> str:
    return ANCHOR_PREFIX + anchor_id


def anchor_mounts(site: Any) -> list[Transform]:
    """map -> anchor_<id> for each of a site's anchors (None: no site, none): its surveyed
    position and mounting, the calibrated yaw offset included -- the board -> world rotation
    the locator uses (host/estimation/anchors3d.py: Rz(yaw) Ry(-pitch) Rx(roll), the site's
    pitch positive up), so a bearing drawn in the anchor's frame lands where the fix does."""
    if site is None:
        return []
    return [Transform(MAP, anchor_frame(a.id), (float(a.position[0]), float(a.position[1]), float(a.position[2])),
                      math.radians(a.yaw_deg + a.calibration.yaw_offset_deg), math.radians(a.roll_deg),
                      -math.radians(a.pitch_deg))
            for a in site.anchors]


def map_to_odom(offset: list[float]) -> Transform:
    """S3's odometry offset (world = odometry + offset; heading trusted), or the anchors
    controller's alignment ``[x, y, yaw]`` (world = R(yaw) odometry + (x, y)), as map -> odom."""
    yaw = float(offset[2]) if len(offset) > 2 else 0.0
    return Transform(MAP, ODOM, (float(offset[0]), float(offset[1]), 0.0), yaw)


def dock_station(pose: list[float]) -> Transform:
    """S1's station ``[x, y, boresight heading]`` in the odometry frame as odom -> dock_station."""
    return Transform(ODOM, STATION, (float(pose[0]), float(pose[1]), 0.0), float(pose[2]))
