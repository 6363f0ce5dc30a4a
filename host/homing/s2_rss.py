"""S2: homing on a 915 MHz emitter with four directional antennas and a particle filter.

Each antenna set (the four dishes' powers for one emitter frame) gives an instantaneous fix:
the direction θ = atan2(y1 − y2, x1 − x2) (see host.estimation.particle for the axes) and a
range from the strongest antenna's power with its dish gain removed (log-distance). The
particle filter (N = 1000, S2's weights) smooths the fixes into the emitter's position; the
robot steers to it (or to the planner's waypoint) with S0's velocity law and stops when the
estimated range is below 0.5 m (S2: "stop when front+back RSS says < 50 cm").

Calibration (config [s2]): the emitter's power at 1 m for an isotropic antenna (p0_dbm), the
path-loss exponent, and the dishes' peak gain (6.6 dBi for 0.3 m dishes at 915 MHz,
10 log10(0.55 (π d / λ)²)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from host.drivers.rss import AntennaPowers
from host.estimation.fixed import wrap_rad
from host.estimation.particle import ParticleFilter, PfParams, differential_to_range, direction
from host.homing.types import Decision, Pose


@dataclass(frozen=True)
class S2Params:
    p0_dbm: float = -40.0
    n: float = 2.0
    peak_gain_db: float = 6.6
    arrival_range_m: float = 0.5
    min_fixes: int = 10
    v_max: float = 0.4
    w_max: float = 1.0
    k_w: float = 1.5
    k_stop: float = 0.8
    search_w: float = 0.5
    seed: int = 0


class RssController:
    source = "rss"

    def __init__(self, params: S2Params = S2Params()) -> None:
        self.params = params
        self.pf = ParticleFilter(PfParams(), np.random.default_rng(params.seed))
        self.fixes = 0
        self.incomplete = 0
        self._last_t: float | None = None
        self._last_fix: tuple[float, float] | None = None

    @property
    def phase(self) -> str:
        return "homing" if self.fixes >= self.params.min_fixes else "searching"

    @property
    def reported(self) -> Any:
        return self.pf.estimate() if self.fixes >= self.params.min_fixes else None

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, AntennaPowers):
            return None
        if any(p is None for p in item.dbm):
            self.incomplete += 1
            return {"incomplete": True}
        p = self.params
        theta, diff_db = direction(*item.dbm)
        rng = differential_to_range(np.array(item.dbm), p.p0_dbm, p.n, p.peak_gain_db)
        if self._last_t is not None:
            self.pf.predict(max(t - self._last_t, 0.0))
        self._last_t = t
        self.pf.update((pose.x, pose.y, pose.theta), rng, theta)
        self.fixes += 1
        self._last_fix = (pose.x + rng * math.cos(pose.theta + theta), pose.y + rng * math.sin(pose.theta + theta))
        return {"theta": round(theta, 4), "range": round(rng, 3), "diff_db": round(diff_db, 2)}

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        p = self.params
        goal = self.reported
        if goal is None:
            return Decision(0.0, p.search_w if self.fixes == 0 else 0.0, None, False, "waiting for fixes")
        estimated_range, _ = self.pf.relative((pose.x, pose.y, pose.theta))
        d_g = math.hypot(goal[0] - pose.x, goal[1] - pose.y)
        if estimated_range < p.arrival_range_m or d_g < p.arrival_range_m:
            return Decision(0.0, 0.0, (float(goal[0]), float(goal[1])), True, "arrived")
        aim = steer_to if steer_to is not None else goal
        theta_g = wrap_rad(math.atan2(aim[1] - pose.y, aim[0] - pose.x) - pose.theta)
        v = (2 / math.pi) * p.v_max * abs(math.pi / 2 - abs(theta_g)) if abs(theta_g) <= math.pi / 2 else 0.0
        v = min(v, p.k_stop * d_g)
        w = max(-p.w_max, min(p.w_max, p.k_w * theta_g))
        return Decision(v, w, (float(goal[0]), float(goal[1])), False, "homing")

    def estimate(self) -> dict[str, Any]:
        goal = self.reported
        return {"goal": None if goal is None else [round(float(v), 4) for v in goal],
                "fix": None if self._last_fix is None else [round(v, 4) for v in self._last_fix]}
