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

Beyond the paper, for real radios (docs/estimation.md, "S3 under measured radios"):
- the fix: ``robust_fit`` solves the position in dB (the log-distance RSSI of a position
  against the readings, Huber loss ``huber_db``) rather than by the linear least squares of
  squared ranges, so a far link counts for what its range is worth and one faded link is
  held to a linear cost;
- the start: the robot stands ``localise_s`` and the offset starts from one fix of each
  beacon's mean raw RSSI over that time (not from the first fix of three barely filtered
  readings, which the small ``offset_gain`` then takes many fixes to forget);
- arrival: when the fused estimate is within ``arrival_radius``, the robot stands
  ``confirm_s`` and re-solves from the mean raw RSSI of the standing readings; arrived if
  that fix is within ``confirm_radius`` of the goal; else, without ``self_calibrate``, the
  offset is set from it and the robot goes on, and with it (the default) the fix is not
  used and the robot stands again at once: there the confirmation is up to
  ``confirm_tries`` standing windows; the ``confirm_tries``-th arrives whatever it says
  (S1's standing confirmation, host/homing/s1_dock.py);
- the offset: ``self_calibrate`` fits it, every ``calibrate_every_s``, with the radios' P0
  and n and each beacon's own offset in dB (priors: the settings' P0 and n, 3 dB per beacon)
  to the last ``history_s`` of raw readings, one mean per beacon and ``place_m`` cell of the
  path (a beacon's shadowing holds at a place: a robot standing long is one observation),
  instead of pulling it by ``offset_gain`` towards each fix;
- the survey: with ``self_calibrate``, the first time the fused estimate is within
  ``arrival_radius`` the robot does not stand yet: it drives a square ``survey_m`` wide about
  the goal (corners fixed in odometry when it begins), so the fit has places on every side of
  the goal, and comes back; each further survey ``survey_grow_m`` wider (new places); it
  surveys at least ``survey_min`` times, and again while a survey moves the fitted offset by
  ``survey_tol_m`` or more, up to ``survey_max`` surveys; then it stands to confirm as above.
  ``history_s`` (150 s) keeps the surveys' readings in the fit.
``localise_s = 0``, ``confirm_s = 0``, ``robust_fit = false`` and ``self_calibrate = false``:
the paper's loop; ``survey_m = 0`` and ``history_s = 30``: the loop before the survey.
The survey's corners stay ``survey_margin_m`` inside the box the beacons span (where the site
is known to be: a beacon is often on a wall); a negative margin lets them out.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.estimation.bearings import Degenerate
from rfhoming.host.estimation.filters import ScalarKalman
from rfhoming.host.estimation.fixed import from_q8, to_q8, wrap_rad
from rfhoming.host.estimation.lateration import multilaterate, offset_and_links, rssi_position
from rfhoming.host.estimation.ranging import LogDistance
from rfhoming.host.homing.schema import DB, DBM, M_S, RAD_S, M, S, setting
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
    robust_fit: bool = setting(True)  # solve each fix in dB with a Huber loss (False: S3's linear least squares of ranges)
    huber_db: float = setting(3.0, low=0, above=True, high=100, unit=DB)
    localise_s: float = setting(2.0, low=0, high=60, unit=S)  # stand this long first; the offset starts from the mean readings (0: from the first fix)
    confirm_s: float = setting(2.0, low=0, high=60, unit=S)  # at arrival stand this long and re-solve from the standing readings (0: the paper's instant stop)
    confirm_settle_s: float = setting(0.2, low=0, high=10, unit=S)  # readings this soon after stopping are left out
    confirm_radius: float = setting(0.5, low=0, above=True, high=10, unit=M)  # the standing fix must be this near the goal
    self_calibrate: bool = setting(True)  # fit the offset with P0, n and each beacon's own offset over the path's readings
    history_s: float = setting(150.0, low=0, above=True, high=3600, unit=S)  # the readings that fit is made of
    place_m: float = setting(0.5, low=0, above=True, high=100, unit=M)  # readings within one such cell of the path are one observation
    calibrate_every_s: float = setting(0.5, low=0, above=True, high=60, unit=S)
    confirm_tries: int = setting(3, low=1, high=100, unit="confirmations")  # the last one arrives whatever it says
    survey_m: float = setting(1.5, low=0, high=20, unit=M)  # at the goal, drive a square this wide about it before standing (0: none)
    survey_tol_m: float = setting(0.3, low=0, above=True, high=10, unit=M)  # a survey that moved the offset less than this ends the surveys
    survey_max: int = setting(3, low=0, high=100, unit="surveys")
    survey_min: int = setting(2, low=0, high=100, unit="surveys")  # surveys before one that moved the offset little may end them
    survey_grow_m: float = setting(1.0, low=0, high=20, unit=M)  # each further survey is this much wider (new places)
    survey_margin_m: float = setting(0.25, low=-100, high=100, unit=M)  # the survey's corners stay this far inside the beacons' box


class Step(enum.Enum):
    """Where the S3 controller is; every change of step is in on_input, decide and its helpers."""

    LOCALISING = "localising"  # standing for the first offset
    HOMING = "homing"  # driving to the goal on the fused estimate
    SURVEYING = "surveying"  # driving the square about the goal, for the fit's places
    CONFIRMING = "confirming"  # standing for the confirmation's fix
    ARRIVED = "arrived"


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
        self._t: float | None = None  # the newest reading's time
        self._window_since: float | None = None  # localising or confirming: when the robot began to stand
        self._window: dict[str, list[float]] = {}  # the raw RSSI of each beacon received while it stands
        self.step = Step.HOMING if params.localise_s <= 0 else Step.LOCALISING
        self.confirmations = 0
        self._names = list(self.anchors)
        self._history: deque[tuple[float, float, float, int, float]] = deque()  # t, odometry x, y, anchor, raw RSSI
        self.theta: np.ndarray | None = None  # self-calibration: offset x, y, P0, n, each anchor's offset
        self._calibrated_t = -math.inf
        self._survey: list[np.ndarray] = []  # odometry waypoints still to drive while SURVEYING
        self._survey_from: np.ndarray | None = None  # the offset when the survey began
        self._survey_moved: float | None = None  # how far the last finished survey moved the offset
        self.surveys = 0
        box = np.array(list(self.anchors.values()))  # where the survey may drive: the beacons' box, survey_margin_m in
        low, high = box.min(axis=0) + params.survey_margin_m, box.max(axis=0) - params.survey_margin_m
        self._inside = (np.minimum(low, (low + high) / 2), np.maximum(high, (low + high) / 2))

    @property
    def phase(self) -> str:
        """The loop's view: it plans only while "homing" (surveying and confirming included)."""
        return "localising" if self.step is Step.LOCALISING or self.fixes < self.params.min_fixes else "homing"

    @property
    def arrived(self) -> bool:
        return self.step is Step.ARRIVED

    def _surveyed(self) -> bool:
        """No survey is due: surveys are off, or the last one settled the offset (or the most were made)."""
        p = self.params
        if p.survey_m <= 0 or not p.self_calibrate:
            return True
        if self._survey_moved is None:
            return False
        return (self._survey_moved < p.survey_tol_m and self.surveys >= p.survey_min) or self.surveys >= p.survey_max

    @property
    def reported(self) -> Any:
        return np.array(self.params.goal, float)

    def world(self, pose: Pose) -> np.ndarray:
        return np.array([pose.x, pose.y]) + (self.offset if self.offset is not None else 0.0)

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, BleRssi) or item.address not in self.anchors:
            return None
        p = self.params
        self._keep(t, pose, item)
        k = self._filters.setdefault(item.address, ScalarKalman(p.kalman_q, p.kalman_r))
        self._latest[item.address] = (t, from_q8(k.update(to_q8(item.rssi_dbm))))
        fresh = [(a, v) for a, (ta, v) in self._latest.items() if t - ta <= p.fresh_s]
        fields: dict[str, Any] = {"address": item.address, "rssi": item.rssi_dbm}
        fix = self.solve(dict(fresh)) if len(fresh) >= 3 else None
        if fix is None:
            return fields
        odo = np.array([pose.x, pose.y])
        if self.step is Step.LOCALISING:
            located = self._mean_fix(p.localise_s)
            if located is None:
                self.last_fix = fix
                return fields
            self.offset, self.step, self._window_since = located - odo, Step.HOMING, None
        elif p.self_calibrate and self.offset is not None:
            self._calibrate(t)
        elif self.step is not Step.CONFIRMING:  # standing, the confirmation's fix decides
            self.offset = fix - odo if self.offset is None else self.offset + p.offset_gain * (fix - odo - self.offset)
        self.fixes += 1
        self.last_fix = fix
        fields["fix"] = [round(float(v), 3) for v in fix]
        return fields

    def _keep(self, t: float, pose: Pose, item: BleRssi) -> None:
        """The raw reading into the standing window (localising, or confirming once settled) and
        into the self-calibration's history of ``history_s``."""
        p = self.params
        self._t = t
        if self._window_since is None and self.step is Step.LOCALISING:
            self._window_since, self._window = t, {}
        settle = p.confirm_settle_s if self.step is Step.CONFIRMING else 0.0
        if self._window_since is not None and t - self._window_since >= settle:
            self._window.setdefault(item.address, []).append(float(item.rssi_dbm))
        if p.self_calibrate:
            self._history.append((t, pose.x, pose.y, self._names.index(item.address), float(item.rssi_dbm)))
            while self._history and t - self._history[0][0] > p.history_s:
                self._history.popleft()

    def _calibrate(self, t: float) -> None:
        """Every ``calibrate_every_s``: the offset, P0, n and each beacon's offset fitted to the history."""
        p = self.params
        assert self.offset is not None
        if self.theta is None:
            self.theta = np.concatenate([self.offset, [p.p0_dbm, p.n], np.zeros(len(self._names))])
        if t - self._calibrated_t >= p.calibrate_every_s:
            self._calibrated_t = t
            which, odo_xy, rssi = self._places()
            self.theta = offset_and_links(np.array([self.anchors[a] for a in self._names]), which, odo_xy, rssi,
                                          self.theta, p.p0_dbm, p.n, reading_sd_db=5.0, independent=1.0)
            self.offset = self.theta[:2].copy()

    def _places(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The history as one mean reading per beacon and place (``place_m`` cells of the
        odometry): a link's shadowing holds at a place, so readings there are one observation,
        however long the robot stood (anchor indices, odometry positions, RSSI)."""
        h = np.array(self._history)
        cells = np.round(h[:, 1:3] / self.params.place_m)
        keys = np.column_stack([h[:, 3], cells])
        _, group = np.unique(keys, axis=0, return_inverse=True)
        group = group.ravel()
        count = np.bincount(group).astype(float)
        mean = np.stack([np.bincount(group, weights=h[:, c]) / count for c in (1, 2, 3, 4)], axis=1)
        return mean[:, 2].round().astype(int), mean[:, :2], mean[:, 3]

    def solve(self, rssi: dict[str, float]) -> np.ndarray | None:
        """One fix from one RSSI per beacon (three or more); None on degenerate geometry."""
        p = self.params
        positions = np.array([self.anchors[a] for a in rssi])
        readings = np.array(list(rssi.values()))
        try:
            if p.robust_fit:
                return rssi_position(positions, readings, p.p0_dbm, p.n, p.huber_db, p.max_range_m)
            return multilaterate(positions, np.minimum(self.model.distance(readings), p.max_range_m))
        except Degenerate:
            return None

    def _mean_fix(self, length_s: float) -> np.ndarray | None:
        """The fix of each beacon's mean raw RSSI while the robot stands, once it has stood
        ``length_s`` and three beacons were heard three times each; else None."""
        if self._window_since is None or self._t is None or self._t - self._window_since < length_s:
            return None
        heard = {a: float(np.mean(v)) for a, v in self._window.items() if len(v) >= 3}
        if len(heard) < 3:
            return None
        if self.theta is not None:  # the self-calibration's constants
            th = self.theta
            try:
                return rssi_position(np.array([self.anchors[a] for a in heard]),
                                     np.array([v - th[4 + self._names.index(a)] for a, v in heard.items()]),
                                     float(th[2]), float(th[3]), self.params.huber_db, self.params.max_range_m)
            except Degenerate:
                return None
        return self.solve(heard)

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        goal = self.reported
        if self.step is Step.ARRIVED:
            return Decision(0.0, 0.0, tuple(goal), True, "arrived")
        if self.phase != "homing":
            return Decision(0.0, 0.0, tuple(goal), False, "localising")
        odo = np.array([pose.x, pose.y])
        if self.step is Step.CONFIRMING:
            standing = self._confirm(odo)
            if standing is not None:
                return standing
        if self.step is Step.SURVEYING:
            if float(np.linalg.norm(self._survey[0] - odo)) < 0.2:
                self._survey.pop(0)
            if self._survey:
                return self._drive(pose, self._survey[0] + self.offset, "surveying")
            assert self._survey_from is not None and self.offset is not None
            self._survey_moved = float(np.linalg.norm(self.offset - self._survey_from))
            self.step = Step.HOMING
        return self._home(pose, goal, steer_to)

    def _confirm(self, odo: np.ndarray) -> Decision | None:
        """CONFIRMING: stand until the standing fix; then arrive, or home on (None)."""
        p = self.params
        goal = self.reported
        fix = self._mean_fix(p.confirm_s)
        if fix is None:
            return Decision(0.0, 0.0, tuple(goal), False, "confirming: standing")
        self.step, self._window_since = Step.HOMING, None
        self.confirmations += 1
        self.last_fix = fix
        if float(np.linalg.norm(goal - fix)) <= p.confirm_radius or self.confirmations >= p.confirm_tries:
            self.step = Step.ARRIVED
            return Decision(0.0, 0.0, tuple(goal), True, "arrived")
        if self.theta is None:
            self.offset = fix - odo  # the standing fix is the best the radios give: go on from it
        return None

    def _home(self, pose: Pose, goal: np.ndarray, steer_to: tuple[float, float] | None) -> Decision:
        """HOMING: drive to the goal; within ``arrival_radius`` survey first if one is due, else stand."""
        p = self.params
        here = self.world(pose)
        aim = goal if steer_to is None else np.array(steer_to) + self.offset  # waypoints are in odometry
        d_g = float(np.linalg.norm(goal - here))
        if d_g < p.arrival_radius and not self._surveyed() and self.offset is not None:
            h = (p.survey_m + p.survey_grow_m * self.surveys) / 2
            corners = [goal + np.array(c) * h for c in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            self._survey = [np.clip(c, *self._inside) - self.offset for c in corners]
            self._survey_from, self.surveys, self.step = self.offset.copy(), self.surveys + 1, Step.SURVEYING
            return self._drive(pose, self._survey[0] + self.offset, "surveying")
        if d_g < p.arrival_radius:
            if p.confirm_s <= 0:
                self.step = Step.ARRIVED
                return Decision(0.0, 0.0, tuple(goal), True, "arrived")
            self.step, self._window_since, self._window = Step.CONFIRMING, self._t, {}
            return Decision(0.0, 0.0, tuple(goal), False, "confirming: standing")
        theta_g = wrap_rad(math.atan2(aim[1] - here[1], aim[0] - here[0]) - pose.theta)
        v, w = velocity_law(theta_g, d_g, p.v_max, p.w_max, p.k_w, p.k_stop)
        return Decision(v, w, tuple(goal), False, "homing")

    def _drive(self, pose: Pose, aim: np.ndarray, note: str) -> Decision:
        p = self.params
        here = self.world(pose)
        theta_g = wrap_rad(math.atan2(aim[1] - here[1], aim[0] - here[0]) - pose.theta)
        v, w = velocity_law(theta_g, max(float(np.linalg.norm(aim - here)), 0.3), p.v_max, p.w_max, p.k_w, p.k_stop)
        return Decision(v, w, tuple(self.reported), False, note)

    def estimate(self) -> dict[str, Any]:
        return {"offset": None if self.offset is None else [round(float(v), 3) for v in self.offset],
                "confirmations": self.confirmations, "surveys": self.surveys,
                "radio": None if self.theta is None else [round(float(v), 2) for v in self.theta[2:]],
                "fix": None if self.last_fix is None else [round(float(v), 3) for v in self.last_fix]}
