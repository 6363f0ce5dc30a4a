"""Homing on fixed anchors: the robot carries a tag of its own; the site's anchors locate both
it and the target, and the robot drives to the target.

The anchors give positions in the site's frame, the base's odometry in its own. The controller
aligns the two from pairs (odometry position, anchor fix of the robot's tag) at the same robot
time: a 2-D rigid transform by least squares (Procrustes), refitted as pairs come, once the
robot has moved ``align_m`` (it first drives straight ahead slowly to get there). The target's
position, turned into the odometry frame, is the goal; the odometry pose steers to it with the
shared velocity law. Angle events are stamped with robot time (the loop's clock), so the
Locator's windows and rate mean the same in lockstep as on a real robot.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfhoming.host.bearing import Bearing
from rfhoming.host.homing.types import ControllerDefaults, Decision, Pose, velocity_law
from rfhoming.host.locate import Locator
from rfhoming.host.site import Site


@dataclass(frozen=True)
class AnchorsParams:
    v_max: float = 0.5  # m/s
    w_max: float = 1.0  # rad/s
    k_w: float = 1.5
    k_stop: float = 0.5
    arrive_m: float = 0.35  # the fixes' own error is ~0.15 m each
    align_m: float = 1.0  # odometry spread before the frames are aligned
    align_speed: float = 0.25  # m/s straight ahead while aligning
    target_stale_s: float = 2.0  # robot seconds without a target fix: stop


def align(odometry: np.ndarray, world: np.ndarray) -> tuple[float, np.ndarray]:
    """(rotation phi, translation tau) with world ~ R(phi) odometry + tau, least squares over
    (N, 2) point pairs (Kabsch/Procrustes in 2-D)."""
    mo, mw = odometry.mean(axis=0), world.mean(axis=0)
    a, b = odometry - mo, world - mw
    phi = math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])), float(np.sum(a * b)))
    rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    return phi, mw - rot @ mo


class Phase(enum.StrEnum):
    """Homing on fixed anchors: turning to the estimate, waiting for one, driving to it."""

    ALIGNING = "aligning"
    WAITING = "waiting"
    HOMING = "homing"


class AnchorsController(ControllerDefaults):
    source = "anchors"

    def __init__(self, site: Site, params: AnchorsParams = AnchorsParams()) -> None:
        self.site = site
        self.params = params
        self.robot_tag = site.tag_with_role("robot").id
        self.target_tag = site.tag_with_role("target").id
        # one stream, already in arrival order; the fixes' constant-velocity tracker, as this
        # controller was tuned with (the angles tracker's motion models are a walker's)
        self.locator = Locator(site, reorder_s=0.0, tracker="cv")
        self._poses: deque[tuple[float, Pose]] = deque(maxlen=500)
        self._pairs: deque[tuple[tuple[float, float], tuple[float, float]]] = deque(maxlen=300)
        self.robot_world: np.ndarray | None = None
        self.target_world: np.ndarray | None = None
        self.target_t = -math.inf
        self.transform: tuple[float, np.ndarray] | None = None
        self.phase = Phase.ALIGNING
        self.reported: tuple[float, float] | None = None

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, Bearing):
            return None
        if not self._poses or self._poses[-1][0] != t:
            self._poses.append((t, pose))
        # the loop's robot time, not the driver's host stamp: the pairs below match fixes to poses
        # by it, and in lockstep host time runs apart from the robot's
        for p in self.locator.feed(item._replace(t=t)):
            xy = (float(p.point[0]), float(p.point[1]))
            if p.tag == self.target_tag:
                self.target_world, self.target_t = np.array(xy), p.t
            elif p.tag == self.robot_tag:
                self.robot_world = np.array(xy)
                at = min(self._poses, key=lambda tp: abs(tp[0] - p.t))[1]
                self._pairs.append(((at.x, at.y), xy))
                self._realign()
        return {"anchor": item.anchor, "tag": item.tag, "azimuth": item.clockwise_deg, "elevation": item.elevation_deg}

    def _realign(self) -> None:
        odo = np.array([p[0] for p in self._pairs])
        if len(odo) < 5 or float(np.ptp(odo, axis=0).max()) < self.params.align_m:
            return
        self.transform = align(odo, np.array([p[1] for p in self._pairs]))

    def _goal_in_odometry(self) -> tuple[float, float] | None:
        if self.transform is None or self.target_world is None:
            return None
        phi, tau = self.transform
        d = self.target_world - tau
        c, s = math.cos(phi), math.sin(phi)
        return (c * d[0] + s * d[1], -s * d[0] + c * d[1])

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        p = self.params
        now = self._poses[-1][0] if self._poses else 0.0
        goal = self._goal_in_odometry()
        self.reported = goal
        if self.transform is None:
            self.phase = Phase.ALIGNING
            return Decision(p.align_speed, 0.0, None, False, "aligning frames: straight ahead")
        if goal is None or now - self.target_t > p.target_stale_s:
            self.phase = Phase.WAITING
            return Decision(0.0, 0.0, None, False, "no fresh target fix")
        self.phase = Phase.HOMING
        aim = steer_to or goal
        d_g = math.dist((pose.x, pose.y), goal)
        if d_g < p.arrive_m:
            return Decision(0.0, 0.0, goal, True, "arrived")
        theta_g = math.remainder(math.atan2(aim[1] - pose.y, aim[0] - pose.x) - pose.theta, 2 * math.pi)
        v, w = velocity_law(theta_g, d_g, p.v_max, p.w_max, p.k_w, p.k_stop)
        return Decision(v, w, goal, False, "homing")

    def estimate(self) -> dict[str, Any]:
        def r(v: Any) -> list[float] | None:
            return None if v is None else [round(float(x), 3) for x in v]

        return {"robot_world": r(self.robot_world), "target_world": r(self.target_world), "goal": r(self.reported),
                "frame_rotation_deg": None if self.transform is None else round(math.degrees(self.transform[0]), 2),
                "map_odom": None if self.transform is None else  # world = R(yaw) odometry + (x, y): map -> odom
                [*(r(self.transform[1]) or []), round(self.transform[0], 5)]}
