"""Fixed XPLR-AOA anchors in 3-D with each board's own, biased error (the kit scenario).

An anchor with ``position = [x, y, z]`` (and ``yaw_deg``, ``pitch_deg``, ``roll_deg``) sees
every ``aoa_tag`` in 3-D, in the board frame of docs/estimation.md: x the boresight, y the
board's left, z its top; azimuth in the x-y plane with the board's sign (negative = left),
elevation out of it. What a real board adds, drawn once per anchor from the seed:

- mounting: the board sits ``mount_error_deg`` (sigma) off its nominal yaw and pitch;
- bias that grows with angle: azimuth and elevation are scaled by 1 + U(-scale_error,
  scale_error) (arrays compress or stretch angles away from boresight) plus a fixed offset
  N(0, bias_deg);
- noise: the scenario's [aoa] sigma, growing toward +-90, on azimuth; ``elevation_sigma_deg``
  (elevation is the weaker axis of the C211's antenna layout);
- reflections: near a wall of the room (within ``reflection_range_m``) the board locks onto
  the tag's mirror image in that wall with a probability up to ``reflection``.

Harder boards, each an option off by default (*assumed*: seen on real four-anchor
recordings with ground truth that this repository does not hold; no public source; docs/protocol.md):

- ``angle_model = "cone"``: the board reports direction cosines along its two array axes,
  sin(az) = -u.y, sin(el) = u.z, instead of atan2 angles (the physics of a planar array);
- ``az_compression``: |azimuth| is read short toward +-90: az * (1 - c (az / 90)^2);
- ``slow_bias_deg`` / ``slow_bias_s``: a slowly wandering bias per (anchor, tag) -- multipath
  that changes as people and the tag move -- an Ornstein-Uhlenbeck process of that sigma and
  time constant, on azimuth and (doubled) on elevation.

The host is told none of this: a calibration run through the same anchors has to find it.

Under a radio profile (``--radio measured|PROFILE``) none of these knobs apply: the board sits at
its nominal pose and its reports carry the profile's measured error process instead
(emulator/aoa_error.py), fitted to real anchors whose residuals already hold their mounting,
compression, bias and reflections.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from rfhoming.emulator.aoa_error import MeasuredAoa
from rfhoming.emulator.devices import AoaRunner, Heard
from rfhoming.emulator.faults import ByteFaults
from rfhoming.emulator.links import Link
from rfhoming.emulator.radio import AoaModel, PathLossModel, true_angles
from rfhoming.emulator.world import World
from rfhoming.firmware.xplr_aoa import C209_NAMESPACE, Advertisement, XplrAoaFirmware
from rfhoming.protocol.rssi_profile import RssiProfile


def rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Board -> world: Rz(yaw) Ry(-pitch) Rx(roll), positive pitch = boresight up."""
    y, p, r = (math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg))
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    ry = np.array([[math.cos(p), 0, -math.sin(p)], [0, 1, 0], [math.sin(p), 0, math.cos(p)]])
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    board_to_world: np.ndarray = rz @ ry @ rx
    return board_to_world


class FixedAnchorRunner(AoaRunner):
    """An XPLR-AOA anchor fixed at a 3-D pose, with its own seeded error model."""

    ROBOT_TAG_HEIGHT_M = 0.3

    def __init__(self, name: str, link: Link, faults: ByteFaults, rng: np.random.Generator,
                 options: dict[str, Any], aoa: AoaModel, path_loss: PathLossModel,
                 robot_tag: tuple[str, float] | None = None, measured: MeasuredAoa | None = None,
                 rssi: Mapping[str, RssiProfile] | None = None) -> None:
        super().__init__(name, link, faults, rng, options, aoa, path_loss, robot_tag, measured, rssi)
        o = options
        self.position = np.array([float(v) for v in o["position"]])
        self.nominal_yaw = float(o.get("yaw_deg", 0.0))
        self.nominal = rotation(self.nominal_yaw, float(o.get("pitch_deg", 0.0)), float(o.get("roll_deg", 0.0)))
        mount_sigma = float(o.get("mount_error_deg", 3.0))
        scale_error = float(o.get("scale_error", 0.12))
        bias = float(o.get("bias_deg", 1.5))
        rng = self.rng
        self.true_pose = (float(o.get("yaw_deg", 0.0)) + float(rng.normal(0, mount_sigma)),
                          float(o.get("pitch_deg", 0.0)) + float(rng.normal(0, mount_sigma)),
                          float(o.get("roll_deg", 0.0)))
        self.az_scale = 1 + float(rng.uniform(-scale_error, scale_error))
        self.el_scale = 1 + float(rng.uniform(-scale_error, scale_error))
        self.az_bias = float(rng.normal(0, bias))
        self.el_bias = float(rng.normal(0, 2 * bias))
        self.el_sigma = float(o.get("elevation_sigma_deg", 5.0))
        self.reflection = float(o.get("reflection", 0.3))
        self.reflection_range = float(o.get("reflection_range_m", 1.0))
        self.rot = rotation(*self.true_pose)
        self.angle_model = str(o.get("angle_model", "spherical"))
        if self.angle_model not in ("spherical", "cone"):
            raise ValueError(f"{name}: angle_model must be \"spherical\" or \"cone\"")
        self.az_compression = float(o.get("az_compression", 0.0))
        self.slow_bias = float(o.get("slow_bias_deg", 0.0))
        self.slow_tau = float(o.get("slow_bias_s", 10.0))
        self._slow: dict[str, tuple[float, float, float]] = {}  # tag -> (t, az offset, el offset)

    def truth(self) -> dict[str, Any]:
        """The hidden error model, for the truth log and the calibration test's cross-check."""
        if self.measured is not None:
            return {"device": self.name, "error_model": "radio profile", "true_yaw_deg": float(self.nominal_yaw)}
        return {"device": self.name, "true_yaw_deg": self.true_pose[0], "true_pitch_deg": self.true_pose[1],
                "az_scale": self.az_scale, "az_bias_deg": self.az_bias,
                "el_scale": self.el_scale, "el_bias_deg": self.el_bias, "angle_model": self.angle_model,
                "az_compression": self.az_compression}

    def _slow_offsets(self, tag_id: str, t: float) -> tuple[float, float]:
        """The (azimuth, elevation) wander of this tag's multipath at ``t`` (exact OU steps)."""
        if self.slow_bias <= 0:
            return 0.0, 0.0
        t_prev, a, e = self._slow.get(tag_id, (t, float(self.rng.normal(0, self.slow_bias)),
                                               float(self.rng.normal(0, 2 * self.slow_bias))))
        keep = math.exp(-max(0.0, t - t_prev) / self.slow_tau)
        spread = math.sqrt(1 - keep * keep)
        a = a * keep + spread * float(self.rng.normal(0, self.slow_bias))
        e = e * keep + spread * float(self.rng.normal(0, 2 * self.slow_bias))
        self._slow[tag_id] = (t, a, e)
        return a, e

    def sources(self, world: World, t: float) -> list[Heard]:
        """Every tag in the room: the targets' and, if the robot carries one, the robot's."""
        tags = [Heard(t_.id, t_.position_at(t), t_.height, t_.interval_ms / 1000, t_.tx_power_dbm, t_.heading_at(t))
                for t_ in world.targets if t_.kind == "aoa_tag"]
        if self.robot_tag is not None:
            tag_id, interval_ms = self.robot_tag
            r = world.robot
            tags.append(Heard(tag_id, (r.x, r.y), self.ROBOT_TAG_HEIGHT_M, interval_ms / 1000, 0.0, r.theta))
        return tags

    def _image(self, world: World, p: np.ndarray) -> np.ndarray:
        """The tag, or (near a wall, sometimes) its mirror image in the nearest wall."""
        x0, y0, x1, y1 = world.bounds
        gaps = [(p[0] - x0, 0, x0), (x1 - p[0], 0, x1), (p[1] - y0, 1, y0), (y1 - p[1], 1, y1)]
        gap, axis, wall = min(gaps)
        if gap < self.reflection_range and self.rng.random() < self.reflection * (1 - gap / self.reflection_range):
            q = p.copy()
            q[axis] = 2 * wall - p[axis]
            return q
        return p

    def step(self, world: World, t0: float, t1: float) -> None:
        fw: XplrAoaFirmware = self.firmware
        for tag_id, pos, height, interval, tx, heading in self.sources(world, t1):
            for t in self.schedule.due(tag_id, interval, interval * 0.1, t0, t1):
                fw.tick(int(t * 1000))
                link = (tag_id, self.name)
                if self.channel.lost(link, t):
                    continue
                tag = np.array([pos[0], pos[1], height])
                distance = float(np.linalg.norm(tag - self.position))
                sample = self.channel.received_dbm(link, distance, tx, 0, t=t,
                                                   ends=(pos, (float(self.position[0]), float(self.position[1]))))
                if sample is None or sample < -100:
                    continue
                if self.measured is not None:
                    self._measured(fw, tag_id, t, tag, heading, sample)
                    continue
                az_ccw, el = true_angles(self.rot.T @ (self._image(world, tag) - self.position), self.angle_model == "cone")
                if self.az_compression:
                    az_ccw *= 1 - self.az_compression * (az_ccw / 90) ** 2
                slow_az, slow_el = self._slow_offsets(tag_id, t)
                az_ccw = (az_ccw * self.az_scale - self.az_bias + slow_az
                          + float(self.rng.normal(0, self.aoa.sigma_deg(az_ccw))))
                el = el * self.el_scale + self.el_bias + slow_el + float(self.rng.normal(0, self.el_sigma))
                fw.on_advertisement(Advertisement(tag_id, C209_NAMESPACE, -max(-90.0, min(90.0, az_ccw)),
                                                  max(-90.0, min(90.0, el)), sample,
                                                  self.channel.second_dbm(link, sample)))
        fw.tick(int(t1 * 1000))

    def _measured(self, fw: XplrAoaFirmware, tag_id: str, t: float, tag: np.ndarray, heading: float,
                  rssi: float) -> None:
        """One event under the radio profile: the true angles from the nominal pose (the
        profile's residuals were taken against nominal poses), then its error process."""
        az_ccw, el = true_angles(self.nominal.T @ (tag - self.position), self.angle_model == "cone")
        assert self.measured is not None
        board = (float(self.position[0]), float(self.position[1]), float(self.position[2]), math.radians(self.nominal_yaw))
        got = self.measured.report(tag_id, t, -az_ccw, el, board, (float(tag[0]), float(tag[1]), float(tag[2]), heading))
        if got is not None:
            fw.on_advertisement(Advertisement(tag_id, C209_NAMESPACE, got[0], got[1], rssi,
                                              self.channel.second_dbm((tag_id, self.name), rssi)))
