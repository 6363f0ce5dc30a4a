"""S3: go to a goal position, localised by RSSI from BLE beacons at known places.

The robot's ESP32 scanner hears beacons whose positions are known (``[trilat] anchors``). Each
beacon's RSSI is Kalman-filtered (fixed point, S3's best filter), turned into a distance with the
log-distance model (S3: n = 2.7), and the robot's world position is multilaterated from every
beacon heard in the last ``fresh_s`` seconds (S3's trilateration uses the three strongest; with
four or more, least squares uses them all). Single fixes are metres off indoors (docs/RESULTS.md),
so they correct odometry instead of replacing it: the world position is odometry plus an offset
that each fix pulls by ``offset_gain``. (Odometry's heading is trusted; a rotation offset is not
estimated.) The robot drives to ``goal`` with S0's velocity law and stops within
``arrival_radius`` of it, by that fused estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.estimation.bearings import Degenerate
from rfhoming.host.estimation.filters import ScalarKalman
from rfhoming.host.estimation.fixed import from_q8, to_q8, wrap_rad
from rfhoming.host.estimation.lateration import multilaterate
from rfhoming.host.estimation.ranging import LogDistance
from rfhoming.host.homing.schema import DBM, M_S, RAD_S, M, S, setting
from rfhoming.host.homing.types import ControllerDefaults, Decision, ParamsError, Pose, velocity_law


@dataclass(frozen=True)
class TrilatParams:
    anchors: dict[str, list[float]] = setting(factory=dict, low=-10000, high=10000, unit=M, length=2)  # address (12 hex) -> [x, y]
    goal: list[float] = setting(factory=lambda: [0.0, 0.0], low=-10000, high=10000, unit=M, length=2)
    p0_dbm: float = setting(-64.3, low=-150, high=30, unit=DBM)
    n: float = setting(2.7, low=1, high=6, unit="(path-loss exponent)")
    kalman_q: float = setting(0.05, low=0, above=True, high=1000, unit="m^2 per step")
    kalman_r: float = setting(16.0, low=0, above=True, high=10000, unit="dB^2")
    fresh_s: float = setting(2.0, low=0, above=True, high=600, unit=S)
    max_range_m: float = setting(10.0, low=0, above=True, high=1000, unit=M)
    offset_gain: float = setting(0.05, low=0, high=1, unit="(fraction per fix)")
    min_fixes: int = setting(10, low=1, high=10000, unit="fixes")
    arrival_radius: float = setting(0.3, low=0, above=True, high=10, unit=M)
    v_max: float = setting(0.4, low=0, above=True, high=5, unit=M_S)
    w_max: float = setting(1.0, low=0, above=True, high=10, unit=RAD_S)
    k_w: float = setting(1.5, low=0, above=True, high=20, unit="1/s")
    k_stop: float = setting(0.8, low=0, above=True, high=10, unit="1/s")


class TrilatController(ControllerDefaults):
    source = "ble"

    def __init__(self, params: TrilatParams) -> None:
        if len(params.anchors) < 3:
            raise ParamsError("trilat needs at least three anchors: [trilat.anchors] ADDRESS = [x, y]")
        self.params = params
        self.model = LogDistance(params.p0_dbm, params.n)
        self.anchors = {addr.upper(): np.array(xy, float) for addr, xy in params.anchors.items()}
        self._filters: dict[str, ScalarKalman] = {}
        self._latest: dict[str, tuple[float, float]] = {}
        self.offset: np.ndarray | None = None
        self.fixes = 0
        self.last_fix: np.ndarray | None = None

    @property
    def phase(self) -> str:
        return "homing" if self.fixes >= self.params.min_fixes else "localising"

    @property
    def reported(self) -> Any:
        return np.array(self.params.goal, float)

    def world(self, pose: Pose) -> np.ndarray:
        return np.array([pose.x, pose.y]) + (self.offset if self.offset is not None else 0.0)

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, BleRssi) or item.address not in self.anchors:
            return None
        p = self.params
        k = self._filters.setdefault(item.address, ScalarKalman(p.kalman_q, p.kalman_r))
        self._latest[item.address] = (t, from_q8(k.update(to_q8(item.rssi_dbm))))
        fresh = [(a, v) for a, (ta, v) in self._latest.items() if t - ta <= p.fresh_s]
        fields: dict[str, Any] = {"address": item.address, "rssi": item.rssi_dbm}
        if len(fresh) < 3:
            return fields
        positions = np.array([self.anchors[a] for a, _ in fresh])
        ranges = np.minimum(self.model.distance(np.array([v for _, v in fresh])), p.max_range_m)
        try:
            fix = multilaterate(positions, ranges)
        except Degenerate:
            return fields
        odo = np.array([pose.x, pose.y])
        self.offset = fix - odo if self.offset is None else self.offset + p.offset_gain * (fix - odo - self.offset)
        self.fixes += 1
        self.last_fix = fix
        fields["fix"] = [round(float(v), 3) for v in fix]
        return fields

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        p = self.params
        goal = self.reported
        if self.phase != "homing":
            return Decision(0.0, 0.0, tuple(goal), False, "localising")
        here = self.world(pose)
        aim = goal if steer_to is None else np.array(steer_to) + self.offset  # waypoints are in odometry
        d_g = float(np.linalg.norm(goal - here))
        if d_g < p.arrival_radius:
            return Decision(0.0, 0.0, tuple(goal), True, "arrived")
        theta_g = wrap_rad(math.atan2(aim[1] - here[1], aim[0] - here[0]) - pose.theta)
        v, w = velocity_law(theta_g, d_g, p.v_max, p.w_max, p.k_w, p.k_stop)
        return Decision(v, w, tuple(goal), False, "homing")

    def estimate(self) -> dict[str, Any]:
        return {"offset": None if self.offset is None else [round(float(v), 3) for v in self.offset],
                "fix": None if self.last_fix is None else [round(float(v), 3) for v in self.last_fix]}
