"""S1: docking on BLE RSSI and angle of arrival measured by the station (methods.md §S1).

The station's array measures the robot's tag; the robot receives those readings (the emulator's
``dock_aoa`` device stands for that link). Filters: moving average over the last N = 10 of RSSI
and of AoA (fixed point, host.estimation.filters). RSSI_diff = RSSI_arrival − RSSÎ.

Stages, with hysteresis: docking when RSSÎ > −73 dBm, back to mission below −76 dBm, kept in
between (in "mission" the robot waits: reaching the station's neighbourhood is another
controller's job). While docking and RSSI_diff > α, steps of
    Δθ = G_a · RSSI_diff · (AoÂ_k − AoÂ_{k−1})   (degrees)
    Δr = G_d · RSSI_diff                          (metres, capped by ``max_step_m``)
are taken: rotate by Δθ, then drive Δr. Re-alignment: when RSSI_diff < β and |AoÂ| > γ, first
rotate by δ toward the station's axis. RSSI_diff ≤ α: docked.

Signs (the paper gives none): the station's array faces the approaching robot and reports
azimuth negative when the robot is to the station's left; turning toward the station's axis is
then a turn of −sign(AoA), and a drift of AoA by ΔAoA is corrected by −G_a·RSSI_diff·ΔAoA.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from host.drivers.aoa import TimedAngle
from host.estimation.filters import MovingAverage
from host.estimation.fixed import from_q8, to_q8, wrap_rad
from host.homing.types import Decision, Pose


@dataclass(frozen=True)
class S1Params:
    g_a: float = 0.25
    g_d: float = 0.08
    alpha_db: float = 1.0
    beta_db: float = 8.0
    gamma_deg: float = 20.0
    delta_deg: float = 30.0
    n: int = 10
    rssi_arrival_dbm: float = -51.0
    enter_dbm: float = -73.0
    leave_dbm: float = -76.0
    v_min: float = 0.1
    v_max: float = 0.25
    w_max: float = 0.52
    max_step_m: float = 0.4
    heading_tolerance_deg: float = 3.0
    position_tolerance_m: float = 0.03


class DockController:
    source = "dock_aoa"

    def __init__(self, params: S1Params = S1Params()) -> None:
        self.params = params
        self._rssi = MovingAverage(params.n)
        self._aoa = MovingAverage(params.n)
        self.rssi: float | None = None
        self.aoa: float | None = None
        self._aoa_prev_step: float | None = None
        self.stage = "mission"
        self.readings = 0
        self._step: tuple[float, float, float] | None = None  # target x, y, heading
        self._rotate_only = False
        self.steps = 0

    @property
    def phase(self) -> str:
        return self.stage

    @property
    def reported(self) -> Any:
        return None if self._step is None else self._step[:2]

    @property
    def rssi_diff(self) -> float:
        return self.params.rssi_arrival_dbm - (self.rssi if self.rssi is not None else -127.0)

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, TimedAngle):
            return None
        e = item.event
        self.rssi = from_q8(self._rssi.update(to_q8(e.rssi1)))
        self.aoa = from_q8(self._aoa.update(to_q8(e.azimuth)))
        self.readings += 1
        p = self.params
        if self.stage == "mission" and self.rssi > p.enter_dbm and self.readings >= p.n:
            self.stage = "docking"
        elif self.stage == "docking" and self.rssi < p.leave_dbm:
            self.stage, self._step = "mission", None
        return {"rssi": e.rssi1, "azimuth": e.azimuth, "rssi_ma": round(self.rssi, 2), "aoa_ma": round(self.aoa, 2)}

    def _next_step(self, pose: Pose) -> None:
        p = self.params
        diff = self.rssi_diff
        aoa = self.aoa or 0.0
        if diff < p.beta_db and abs(aoa) > p.gamma_deg:
            turn = -math.copysign(math.radians(p.delta_deg), aoa)  # re-align toward the axis
            self._step, self._rotate_only = (pose.x, pose.y, wrap_rad(pose.theta + turn)), True
        else:
            d_aoa = 0.0 if self._aoa_prev_step is None else aoa - self._aoa_prev_step
            heading = wrap_rad(pose.theta - math.radians(p.g_a * diff * d_aoa))
            step = min(p.g_d * diff, p.max_step_m)
            self._step = (pose.x + step * math.cos(heading), pose.y + step * math.sin(heading), heading)
            self._rotate_only = False
        self._aoa_prev_step = aoa
        self.steps += 1

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        p = self.params
        if self.stage != "docking" or self.rssi is None:
            return Decision(0.0, 0.0, None, False, "waiting: not in the docking stage")
        if self.rssi_diff <= p.alpha_db:
            return Decision(0.0, 0.0, (pose.x, pose.y), True, "arrived")
        if self._step is None:
            self._next_step(pose)
        x, y, heading = self._step
        turn = wrap_rad(heading - pose.theta)
        if abs(math.degrees(turn)) > p.heading_tolerance_deg:  # rotate first
            return Decision(0.0, max(-p.w_max, min(p.w_max, 1.5 * turn)), (x, y), False, "rotating")
        remaining = (x - pose.x) * math.cos(heading) + (y - pose.y) * math.sin(heading)
        if self._rotate_only or remaining < p.position_tolerance_m:
            self._step = None  # step done: the next one from fresh readings
            return Decision(0.0, 0.0, (x, y), False, "step done")
        v = max(p.v_min, min(p.v_max, remaining))
        return Decision(v, max(-p.w_max, min(p.w_max, 1.5 * turn)), (x, y), False, "driving")

    def estimate(self) -> dict[str, Any]:
        return {"stage": self.stage, "rssi_diff": round(self.rssi_diff, 2), "step": None if self._step is None
                else [round(v, 3) for v in self._step]}
