"""S1: docking on BLE RSSI and angle of arrival measured by the station (S1, Electronics 2026; docs/RESULTS.md).

The station's array measures the robot's tag; the robot receives those readings (the emulator's
``dock_aoa`` device stands for that link). Filters: moving average over the last N = 10 of RSSI
and of AoA (fixed point, host.estimation.filters). RSSI_diff = RSSI_arrival − RSSÎ.

Stages, with hysteresis: docking when RSSÎ > −73 dBm, back to mission below −76 dBm, kept in
between. In "mission" S1's robot navigates on its map toward the station; here, with
``mission_goal`` (the station's position on the robot's map, in the odometry frame) the robot
drives toward it and stops ``mission_stop_m`` short, and without it the robot waits. While docking and RSSI_diff > α, steps of
    Δθ = G_a · RSSI_diff · (AoÂ_k − AoÂ_{k−1})   (degrees)
    Δr = G_d · RSSI_diff                          (metres, capped by ``max_step_m``)
are taken: rotate by Δθ, then drive Δr. Re-alignment: when RSSI_diff < β and |AoÂ| > γ, the
step's rotation is δ toward the station's axis instead. RSSI_diff ≤ α: docked.

Signs (the paper gives none): the station's array faces the approaching robot and reports
azimuth negative when the robot is to the station's left; turning toward the station's axis is
then a turn of −sign(AoA), and a drift of AoA by ΔAoA is corrected by −G_a·RSSI_diff·ΔAoA.

Beyond the paper: confirmation. RSSI_diff ≤ α on the moving average taken while driving can be
one lucky stretch of a heavy-tailed channel (a real board's): the robot stops and stands
``confirm_s``, and is docked only if the mean of the RSSI received while it stands is within
α of the arrival RSSI; otherwise it takes a step from that figure, at most ``confirm_step_m``
(it may stand at the docked pose already, and the station's link read weak: a full step
carried a measured-radio trial past the station, out of its docking stage), and goes on; the
``confirm_tries``-th confirmation docks whatever it says (``confirm_s = 0``: the paper's
instant stop).

Beyond the paper: final heading. S1's steps steer the robot's position onto the station's
axis but nothing aligns its heading (the paper's trial ended 12.5° off). Every reading is also a
point of the robot in the station's frame (range from RSSI with ``path_n`` and the arrival
RSSI at ``standoff_m``, bearing from AoA) paired with the robot's odometry position; a 2-D
rigid fit of those pairs (closed-form Procrustes) gives the station's axis in the odometry
frame. Once RSSI_diff ≤ α the robot turns in place onto that axis, then reports docked.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfhoming.host.bearing import Bearing
from rfhoming.host.estimation.filters import MovingAverage
from rfhoming.host.estimation.fixed import from_q8, to_q8, wrap_rad
from rfhoming.host.homing.schema import DB, DBM, DEG, M_S, RAD_S, M, S, setting
from rfhoming.host.homing.types import ControllerDefaults, Decision, Pose, velocity_law


@dataclass(frozen=True)
class S1Params:
    g_a: float = setting(0.25, low=0, high=10, unit="degrees per dB per degree")
    g_d: float = setting(0.08, low=0, high=10, unit="m per dB")
    alpha_db: float = setting(1.0, low=0, high=60, unit=DB)
    beta_db: float = setting(8.0, low=0, high=60, unit=DB)
    gamma_deg: float = setting(20.0, low=0, high=180, unit=DEG)
    delta_deg: float = setting(30.0, low=0, high=180, unit=DEG)
    n: int = setting(10, low=1, high=1000, unit="readings")
    rssi_arrival_dbm: float = setting(-51.0, low=-150, high=30, unit=DBM)
    enter_dbm: float = setting(-73.0, low=-150, high=30, unit=DBM)
    leave_dbm: float = setting(-76.0, low=-150, high=30, unit=DBM)
    v_min: float = setting(0.1, low=0, high=5, unit=M_S)
    v_max: float = setting(0.25, low=0, above=True, high=5, unit=M_S)
    w_max: float = setting(0.52, low=0, above=True, high=10, unit=RAD_S)
    max_step_m: float = setting(0.4, low=0, above=True, high=10, unit=M)
    heading_tolerance_deg: float = setting(3.0, low=0, above=True, high=90, unit=DEG)
    position_tolerance_m: float = setting(0.03, low=0, above=True, high=1, unit=M)
    align: bool = setting(True)  # turn onto the station's fitted axis at the end (False: the paper's stop)
    standoff_m: float = setting(0.3, low=0, high=10, unit=M)  # where rssi_arrival_dbm is received (the docked position)
    path_n: float = setting(2.0, low=1, high=6, unit="(path-loss exponent)")  # path-loss exponent for the fit's RSSI ranges
    align_min_spread_m: float = setting(0.5, low=0, high=100, unit=M)  # the fit needs the robot to have moved this far along the approach
    mission_goal: tuple[float, float] | None = setting(None, low=-10000, high=10000, unit=M)  # the station on the robot's map (mission stage)
    mission_stop_m: float = setting(0.8, low=0, high=100, unit=M)  # the mission stage stops this far from mission_goal
    confirm_s: float = setting(1.0, low=0, high=60, unit=S)  # stand this long and confirm RSSI_diff <= alpha on the standing readings (0: the paper's instant stop)
    confirm_settle_s: float = setting(0.2, low=0, high=10, unit=S)  # readings this soon after stopping are left out of the confirmation
    confirm_tries: int = setting(3, low=1, high=100, unit="confirmations")  # the last one docks whatever it says (steps past the station only lose it)
    confirm_step_m: float = setting(0.1, low=0, high=10, unit=M)  # the step after a failed confirmation, at most (the robot may stand at the docked pose already: a full step carries it past the station)


class Stage(enum.StrEnum):
    """Where the docking controller is; S1's docking stage is DOCKING, CONFIRMING and DOCKED."""

    MISSION = "mission"  # toward the station on the map, or waiting for its RSSI
    DOCKING = "docking"  # stepping on RSSI and AoA
    CONFIRMING = "confirming"  # standing: the readings decide
    DOCKED = "docked"  # confirmed: aligning with the approach axis, then arrived


class DockController(ControllerDefaults):
    source = "dock_aoa"

    def __init__(self, params: S1Params = S1Params()) -> None:
        self.params = params
        self._rssi = MovingAverage(params.n)
        self._aoa = MovingAverage(params.n)
        self.rssi: float | None = None
        self.aoa: float | None = None
        self._aoa_prev_step: float | None = None
        self.stage = Stage.MISSION
        self.readings = 0
        self._step: tuple[float, float, float] | None = None  # target x, y, heading
        self.steps = 0
        self._pairs: deque[tuple[float, float, float, float]] = deque(maxlen=2000)  # odometry x, y; station-frame x, y
        self.axis: float | None = None  # the fitted approach heading, set when aligning
        self._t: float | None = None  # the newest reading's time
        self._standing_since: float | None = None  # confirming: when the robot stopped
        self._standing: list[float] = []  # confirming: the raw RSSI received while it stands
        self._hold_until = 0  # after a failed confirmation, the moving average is not trusted before this reading
        self._tries = 0  # confirmations taken

    @property
    def phase(self) -> str:
        """S1's two stages, as the run log names them: confirming and docked are in the docking stage."""
        return "mission" if self.stage is Stage.MISSION else "docking"

    @property
    def confirmed(self) -> bool:
        """RSSI_diff <= alpha held on the standing readings (or the last try was taken)."""
        return self.stage is Stage.DOCKED

    @property
    def reported(self) -> Any:
        return None if self._step is None else self._step[:2]

    @property
    def rssi_diff(self) -> float:
        return self.params.rssi_arrival_dbm - (self.rssi if self.rssi is not None else -127.0)

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, Bearing) or item.rssi is None:  # docking ranges by RSSI
            return None
        rssi, azimuth = item.rssi, item.clockwise_deg
        self._t = t
        if self._standing_since is not None and t - self._standing_since >= self.params.confirm_settle_s:
            self._standing.append(rssi)
        self.rssi = from_q8(self._rssi.update(to_q8(rssi)))
        self.aoa = from_q8(self._aoa.update(to_q8(azimuth)))
        self.readings += 1
        p = self.params
        r = p.standoff_m * 10 ** ((p.rssi_arrival_dbm - rssi) / (10 * p.path_n))
        phi = item.azimuth  # REP 103: positive = the robot on the station's left
        self._pairs.append((pose.x, pose.y, r * math.cos(phi), r * math.sin(phi)))
        if self.stage is Stage.MISSION and self.rssi > p.enter_dbm and self.readings >= p.n:
            self.stage = Stage.DOCKING
        elif self.stage is not Stage.MISSION and self.rssi < p.leave_dbm:
            self.stage, self._step, self._standing_since = Stage.MISSION, None, None
            self._tries = 0  # a later docking confirms afresh
        return {"rssi": rssi, "azimuth": azimuth, "rssi_ma": round(self.rssi, 2), "aoa_ma": round(self.aoa, 2)}

    def _next_step(self, pose: Pose, diff: float | None = None, cap_m: float | None = None) -> None:
        p = self.params
        diff = self.rssi_diff if diff is None else diff
        aoa = self.aoa or 0.0
        if diff < p.beta_db and abs(aoa) > p.gamma_deg:
            # re-align: rotate δ toward the axis *before* the step (a rotation alone leaves the
            # AoA where it was, and the next step would rotate again: a spin in place)
            heading = wrap_rad(pose.theta - math.copysign(math.radians(p.delta_deg), aoa))
        else:
            d_aoa = 0.0 if self._aoa_prev_step is None else aoa - self._aoa_prev_step
            heading = wrap_rad(pose.theta - math.radians(p.g_a * diff * d_aoa))
        step = min(p.g_d * diff, p.max_step_m if cap_m is None else cap_m)
        self._step = (pose.x + step * math.cos(heading), pose.y + step * math.sin(heading), heading)
        self._aoa_prev_step = aoa
        self.steps += 1

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        p = self.params
        if self.stage is Stage.MISSION or self.rssi is None:
            return self._mission(pose)
        # a confirmation, once begun, runs its window
        if self.stage is Stage.CONFIRMING or (self.stage is Stage.DOCKING and self.rssi_diff <= p.alpha_db
                                              and self.readings >= self._hold_until):
            confirming = self._confirm(pose)
            if confirming is not None:
                return confirming
        if self.confirmed or self.axis is not None:
            if p.align and self.axis is None:
                self.axis = self.approach_heading()
            if self.axis is not None:
                turn = wrap_rad(self.axis - pose.theta)
                if abs(math.degrees(turn)) > p.heading_tolerance_deg:
                    return Decision(0.0, max(-p.w_max, min(p.w_max, 1.5 * turn)), (pose.x, pose.y), False, "aligning")
            return Decision(0.0, 0.0, (pose.x, pose.y), True, "arrived")
        if self._step is None:
            self._next_step(pose)
            assert self._step is not None
        x, y, heading = self._step
        turn = wrap_rad(heading - pose.theta)
        if abs(math.degrees(turn)) > p.heading_tolerance_deg:  # rotate first
            return Decision(0.0, max(-p.w_max, min(p.w_max, 1.5 * turn)), (x, y), False, "rotating")
        remaining = (x - pose.x) * math.cos(heading) + (y - pose.y) * math.sin(heading)
        if remaining < p.position_tolerance_m:
            self._step = None  # step done: the next one from fresh readings
            return Decision(0.0, 0.0, (x, y), False, "step done")
        v = max(p.v_min, min(p.v_max, remaining))
        return Decision(v, max(-p.w_max, min(p.w_max, 1.5 * turn)), (x, y), False, "driving")

    def _confirm(self, pose: Pose) -> Decision | None:
        """Docked only if the readings received while the robot stands say so: their mean RSSI
        within alpha of the arrival RSSI (or on the last try). A moving average taken while driving can dip under
        alpha on one lucky stretch of a heavy-tailed channel. None: confirmed (or no window)."""
        p = self.params
        if p.confirm_s <= 0:
            self.stage = Stage.DOCKED
            return None
        if self.stage is not Stage.CONFIRMING:
            self.stage, self._standing_since, self._standing = Stage.CONFIRMING, self._t, []
            self._step = None
        assert self._standing_since is not None and self._t is not None
        if self._t - self._standing_since < p.confirm_s or len(self._standing) < 3:
            return Decision(0.0, 0.0, (pose.x, pose.y), False, "confirming: standing")
        diff = p.rssi_arrival_dbm - float(np.mean(self._standing))  # the mean, as the calibration's and S1's averages
        self._standing_since, self._standing = None, []
        self._tries += 1
        if diff <= p.alpha_db or self._tries >= p.confirm_tries:
            self.stage = Stage.DOCKED
            return None
        self.stage = Stage.DOCKING
        self._hold_until = self.readings + p.n  # a step from the standing figure, then fresh readings
        self._next_step(pose, diff, p.confirm_step_m)
        return Decision(0.0, 0.0, self._step[:2] if self._step else None, False, "not confirmed: stepping on")

    def _mission(self, pose: Pose) -> Decision:
        """Before the docking stage: toward the station on the map (S1's mission stage), or wait."""
        p = self.params
        if p.mission_goal is None or self.rssi is None:
            return Decision(0.0, 0.0, None, False, "waiting: not in the docking stage")
        gx, gy = p.mission_goal
        d = math.hypot(gx - pose.x, gy - pose.y) - p.mission_stop_m
        if d <= 0:
            return Decision(0.0, 0.0, None, False, "mission: at the station, waiting for the docking stage")
        v, w = velocity_law(wrap_rad(math.atan2(gy - pose.y, gx - pose.x) - pose.theta), d, p.v_max, p.w_max, 1.5, 0.8)
        return Decision(v, w, (gx, gy), False, "mission: toward the station on the map")

    def approach_heading(self) -> float | None:
        """The heading that faces the station along its axis, in the odometry frame; None when
        the robot has not moved far enough for the fit."""
        station = self.station_pose()
        return None if station is None else wrap_rad(station[2] + math.pi)

    def station_pose(self) -> tuple[float, float, float] | None:
        """The station in the odometry frame, (x, y, boresight heading), from the rigid fit of
        the readings' station-frame points onto the odometry positions; None before the robot
        has moved far enough for it (the MCAP's odom -> dock_station)."""
        if len(self._pairs) < 2 * self.params.n:
            return None
        a = np.array(self._pairs)
        mean_odo, mean_station = a[:, :2].mean(axis=0), a[:, 2:].mean(axis=0)
        odo, station = a[:, :2] - mean_odo, a[:, 2:] - mean_station
        if np.ptp(a[:, 0]) ** 2 + np.ptp(a[:, 1]) ** 2 < self.params.align_min_spread_m ** 2:
            return None
        h = station.T @ odo  # rotation R (station -> odometry) maximises trace(R h)
        psi = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])  # the station's boresight
        c, s = math.cos(psi), math.sin(psi)
        x, y = mean_odo - np.array([[c, -s], [s, c]]) @ mean_station  # where the station's origin lands
        return float(x), float(y), psi

    def estimate(self) -> dict[str, Any]:
        station = self.station_pose()
        return {"stage": self.phase, "rssi_diff": round(self.rssi_diff, 2), "step": None if self._step is None
                else [round(v, 3) for v in self._step],
                "station": None if station is None else [round(v, 3) for v in station]}
