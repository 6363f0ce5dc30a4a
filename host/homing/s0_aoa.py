"""S0: homing on angle-of-arrival with the vector + parallax hybrid (S0, Robotics 2023; docs/RESULTS.md).

Inputs: robot pose (odometry, world frame) and XPLR-AOA readings already converted to the
robot frame (θs CCW from the heading, radians) with an RSSI-derived distance.

Estimates:
- vector goal: g = r + d(cos α, sin α), α = θr + θs; reported as the time-weighted mean of the
  last 20 raw vector goals, w_k = exp(−(k−1)/τ), τ = 10 readings (the paper leaves τ open;
  at the board's 50 Hz that is 0.2 s, and the weights still reach across the whole buffer).
- parallax goal: the first two readings whose rays cross well (baseline ≥ 0.3 m, ≥ 3° apart,
  and, ours, at least one baseline ahead of both sensors: rays that meet at a sensor are bearing
  noise, and a goal on the robot would fold every later reading onto the wrong side) give it; afterwards each reading moves it onto its ray by k (Kohonen update). The paper's
  k = 0.8 is per reading of its simulation; at 50 Hz, k = 0.3 per reading moves as far in 0.1 s
  (1 − 0.7⁵ ≈ 0.83) and averages five times as many rays.
- hybrid: err = |g_p − g_v| / (½(d_p + d_v)); below 0.3 report g_p; otherwise z-test the new
  raw vector goal against the previous 20 (per axis, 1.645): an inlier moves g_p to the mean of
  g_p and g_v, an outlier is ignored.

Beyond the paper (both ours; ``close_fusion_m = 0`` and ``ray_fusion = False`` restore the
paper's rule and report):
- near-goal fusion: the parallax goal's error along the rays is never corrected once the robot
  drives straight at it, while near the goal the vector goal's relative distance error is
  small. Within 2 m each inlier vector goal pulls g_p by 0.1.
- ray fusion: on that straight approach every ray agrees and only ranges tell how far the goal
  is, and the paper's estimates rest on the last few readings (Kohonen's k, a 20-reading
  vector goal). Ours reports the inverse-variance mean of every raw vector goal taken within
  3 m of the goal (:mod:`rfhoming.host.estimation.ray_fusion`) once it holds 10, as long as it
  stays within ``arrival_agreement`` of g_p: ranges that disagree with the bearings (a biased
  RSSI link) are not trusted, and g_p is reported instead. Off by default: it needs ranges
  from a calibration. Without one, a link whose ranges read short by a factor makes every
  older (farther) reading land shorter still, and the mean trails the tag further than the
  hybrid does. The campaigns calibrate first and turn it on.
- robust fit (``robust_fit``, on; off restores S0's estimates): every few centimetres of path a
  ray is kept, and the tag's position fitted to all of them with a Cauchy loss
  (:mod:`rfhoming.host.estimation.bearing_fit`) is reported once the bearings alone place it
  (parallax from rays taken a metre or more away); a real board's bursts and slow errors
  otherwise drag S0's last-readings estimates. With the fit reported, arrival needs the
  vector goal within ``arrival_agreement`` of it.
Arrival also needs g_p, or a full buffer of vector goals when no parallax formed: one noisy
first reading must not end a run.

What the paper left open, and how it is handled here:
- the board's ±90° limit and front/back fold: each reading has two world-bearing hypotheses,
  θr + θs and θr + π − θs. At the start the robot turns in place (``disambiguation``) and keeps
  the hypothesis whose world bearing stays put; afterwards the hypothesis nearer the current
  goal is used. Readings beyond ``max_abs_azimuth`` (70°), where the board is least accurate
  and the fold most ambiguous, only steer (turn toward the target), they do not update goals.
- mounting (yaw offset, azimuth sign, upside down) is applied by the caller (host.homing.config).
- the velocity law is eq. (15), v = (2/π) v_max |π/2 − |θg|| for |θg| ≤ π/2, capped by
  ``k_stop · d_g`` so the robot does not overshoot the 0.3 m arrival circle; ω = k_ω θg.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rfhoming.host.bearing import Bearing
from rfhoming.host.estimation.bearing_fit import BearingFit
from rfhoming.host.estimation.bearings import Degenerate, intersect, kohonen_update
from rfhoming.host.estimation.fixed import wrap_rad
from rfhoming.host.estimation.ranging import LogDistance
from rfhoming.host.estimation.ray_fusion import RayRangeFusion
from rfhoming.host.homing.schema import DEG, M_S, RAD_S, M, S, setting
from rfhoming.host.homing.types import ControllerDefaults, Decision, Pose, velocity_law


@dataclass(frozen=True)
class S0Params:
    k: float = setting(0.3, low=0, above=True, high=1, unit="(gain per reading)")  # per reading at 50 Hz: 1 − 0.7⁵ ≈ the paper's 0.8 per 0.1 s
    buffer: int = setting(20, low=2, high=10000, unit="readings")
    tau: float = setting(10.0, low=0, above=True, high=10000, unit="readings")
    z_threshold: float = setting(1.645, low=0, above=True, high=10, unit="standard deviations")
    err_threshold: float = setting(0.3, low=0, above=True, high=10, unit=M)
    arrival_radius: float = setting(0.3, low=0, above=True, high=10, unit=M)
    arrival_agreement: float = setting(0.6, low=0, above=True, high=10, unit=M)  # |g_p − g_v| must be below this at arrival (m)
    min_baseline: float = setting(0.3, low=0, high=10, unit=M)
    min_crossing_deg: float = setting(3.0, low=0, high=90, unit=DEG)
    v_max: float = setting(0.7, low=0, above=True, high=5, unit=M_S)
    w_max: float = setting(1.2, low=0, above=True, high=10, unit=RAD_S)
    k_w: float = setting(1.5, low=0, above=True, high=20, unit="1/s")
    k_stop: float = setting(0.8, low=0, above=True, high=10, unit="1/s")
    max_abs_azimuth_deg: float = setting(70.0, low=0, above=True, high=180, unit=DEG)
    unambiguous_deg: float = setting(60.0, low=0, above=True, high=180, unit=DEG)  # only readings this near the boresight move the bearing estimate
    disambiguation_s: float = setting(1.2, low=0, high=60, unit=S)
    disambiguation_w: float = setting(0.8, low=0, high=10, unit=RAD_S)
    folded: bool = setting(True)  # the sensor folds bearings into ±90° (the XPLR-AOA); False: a 360° sensor
    close_fusion_m: float = setting(2.0, low=0, high=100, unit=M)  # nearer than this, inlier vector goals pull g_p (0: the paper's rule)
    close_fusion_gain: float = setting(0.1, low=0, high=1, unit="(fraction per reading)")
    ray_fusion: bool = setting(False)  # report the fusion of readings near the goal (needs calibrated ranges)
    fusion_min_readings: int = setting(10, low=1, high=10000, unit="readings")  # readings near the goal before the fusion is reported
    robust_fit: bool = setting(True)  # report the robust fit of the path's bearings once trusted (host/estimation/bearing_fit.py; False: S0's estimates alone)


@dataclass
class _Ray:
    x: float
    y: float
    alpha: float


class Phase(enum.StrEnum):
    """S0's phases: the bearing's front/back ambiguity first, then homing on it."""

    DISAMBIGUATING = "disambiguating"
    HOMING = "homing"


@dataclass
class S0Homing:
    params: S0Params = field(default_factory=S0Params)
    g_p: tuple[float, float] | None = None
    g_v: tuple[float, float] | None = None
    reported: tuple[float, float] | None = None
    phase: Phase = Phase.DISAMBIGUATING
    _raw: deque[tuple[float, float]] = field(init=False)  # the last ``buffer`` raw vector goals
    _weights: list[float] = field(init=False)  # g_v's weights, newest first
    _fusion: RayRangeFusion | None = field(init=False)  # ours: every reading near the goal
    _fit: BearingFit | None = field(init=False)  # ours: the robust fit of the path's bearings
    fitted: tuple[float, float] | None = None  # its trusted estimate, None before it is trusted
    _sums: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # Σx, Σy, Σx², Σy² of _raw
    _z_outlier: bool = False
    _first: _Ray | None = None
    _disamb: list[tuple[float, float, float]] = field(default_factory=list)  # (front α, back α, t)
    _mirror: bool = False
    _t0: float | None = None
    _last_theta_world: float | None = None  # the target's world bearing, steadily estimated
    _turn_sign: float = 1.0

    def __post_init__(self) -> None:
        if not self.params.folded:  # nothing to tell apart: home from the first reading
            self.phase = Phase.HOMING
        self._raw = deque(maxlen=self.params.buffer)
        self._weights = [math.exp(-k / self.params.tau) for k in range(self.params.buffer)]
        self._fusion = RayRangeFusion() if self.params.ray_fusion else None
        self._fit = BearingFit() if self.params.robust_fit else None

    def world_bearing(self, pose: Pose, theta_s: float) -> float:
        """The reading's world bearing under the current front/back choice."""
        front = wrap_rad(pose.theta + theta_s)
        if not self.params.folded:
            return front
        back = wrap_rad(pose.theta + math.pi - theta_s)
        if self.phase is Phase.DISAMBIGUATING:
            return back if self._mirror else front
        reference = self._goal_bearing(pose)
        if reference is None:
            return back if self._mirror else front
        return min((front, back), key=lambda a: abs(wrap_rad(a - reference)))

    def _goal_bearing(self, pose: Pose) -> float | None:
        goal = self.reported
        if goal is None or math.hypot(goal[0] - pose.x, goal[1] - pose.y) < self.params.min_baseline:
            return self._last_theta_world  # a goal on the robot tells no bearing
        return math.atan2(goal[1] - pose.y, goal[0] - pose.x)

    def on_reading(self, t: float, pose: Pose, theta_s: float, distance: float) -> None:
        """One AoA reading in the robot frame (θs CCW, rad) with its RSSI distance (m)."""
        p = self.params
        if self._t0 is None:
            self._t0 = t
        if self.phase is Phase.DISAMBIGUATING:
            self._disamb.append((wrap_rad(pose.theta + theta_s), wrap_rad(pose.theta + math.pi - theta_s), t))
            if t - self._t0 >= p.disambiguation_s and len(self._disamb) >= 5:
                self._decide_front_back()
            return
        alpha = self.world_bearing(pose, theta_s)
        relative = wrap_rad(alpha - pose.theta)
        if self._last_theta_world is None:  # an unfolded sensor skips the disambiguation
            self._last_theta_world = alpha
        if abs(math.degrees(relative)) < p.unambiguous_deg or not p.folded:
            # away from ±90°, where the two hypotheses cross, a reading can move the estimate;
            # near it a noisy reading could hand the tracker the mirror branch
            self._last_theta_world = wrap_rad(self._last_theta_world + 0.3 * wrap_rad(alpha - self._last_theta_world))
        if p.folded and abs(math.degrees(relative)) > p.max_abs_azimuth_deg:
            return  # near the array's edge: steer only
        self._update_vector(pose, alpha, distance)
        self._update_parallax(pose, alpha)
        previous = self.reported
        self._hybrid(pose)
        if self._fit is not None:
            self._fit.add(t, pose.x, pose.y, alpha, distance, guess=self.fitted or self.reported)
            self.fitted = self._fit.estimate()
            if self.fitted is not None:
                self.reported = self.fitted
                return  # the path's bearings outvote the last few readings (and the fusion's ranges)
        if self._fusion is not None:
            self._fusion.add(t, pose.x, pose.y, alpha, distance, previous)
            fused = self._fusion.estimate()
            if (fused is not None and self.g_p is not None and self._fusion.readings >= p.fusion_min_readings
                    and math.dist(fused, self.g_p) < p.arrival_agreement):
                self.reported = fused

    def _decide_front_back(self) -> None:
        def spread(angles: list[float]) -> float:
            s, c = sum(math.sin(a) for a in angles), sum(math.cos(a) for a in angles)
            return 1 - math.hypot(s, c) / len(angles)  # circular variance

        front = spread([a for a, _, _ in self._disamb])
        back = spread([b for _, b, _ in self._disamb])
        self._mirror = back < front
        chosen = [b if self._mirror else a for a, b, _ in self._disamb]
        self._last_theta_world = math.atan2(sum(math.sin(a) for a in chosen), sum(math.cos(a) for a in chosen))
        self.phase = Phase.HOMING

    def _update_vector(self, pose: Pose, alpha: float, distance: float) -> None:
        raw = (pose.x + distance * math.cos(alpha), pose.y + distance * math.sin(alpha))
        self._z_outlier = self._is_outlier(raw)
        if len(self._raw) == self._raw.maxlen:  # the oldest leaves the z-test's running sums
            ox, oy = self._raw[0]
            self._sums = _minus(self._sums, ox, oy)
        self._raw.append(raw)
        self._sums = _plus(self._sums, *raw)
        sx = sy = sw = 0.0  # the paper's g_v: w_k = exp(−(k−1)/τ), k = 1 the newest
        for w, (x, y) in zip(self._weights, reversed(self._raw)):
            sx, sy, sw = sx + w * x, sy + w * y, sw + w
        self.g_v = (sx / sw, sy / sw)

    def _is_outlier(self, raw: tuple[float, float]) -> bool:
        """The paper's z-test of a new raw vector goal against the buffer, per axis, from running
        sums (this runs for every reading)."""
        n = len(self._raw)
        if n < 5:
            return False
        sx, sy, sxx, syy = self._sums
        z_max = 0.0
        for value, s, ss in ((raw[0], sx, sxx), (raw[1], sy, syy)):
            mean = s / n
            std = math.sqrt(max(ss / n - mean * mean, 0.0))
            z_max = max(z_max, abs(value - mean) / max(std, 1e-3))
        return z_max > self.params.z_threshold

    def _update_parallax(self, pose: Pose, alpha: float) -> None:
        p = self.params
        if self.g_p is not None:
            self.g_p = kohonen_update(self.g_p, (pose.x, pose.y), alpha, p.k)
            return
        if self._first is None:
            self._first = _Ray(pose.x, pose.y, alpha)
            return
        first = self._first
        if math.hypot(pose.x - first.x, pose.y - first.y) < p.min_baseline:
            return
        try:
            point = intersect((first.x, first.y), first.alpha, (pose.x, pose.y), alpha,
                              math.sin(math.radians(p.min_crossing_deg)))
        except Degenerate:
            self._first = _Ray(pose.x, pose.y, alpha)  # slide the baseline forward
            return
        if min(math.dist(point, (first.x, first.y)), math.dist(point, (pose.x, pose.y))) < p.min_baseline:
            # rays that meet at a sensor: bearing noise, not parallax (the goal would sit on the robot)
            self._first = _Ray(pose.x, pose.y, alpha)
            return
        self.g_p = point

    def _hybrid(self, pose: Pose) -> None:
        if self.g_v is None:
            return
        if self.g_p is None:
            self.reported = self.g_v
            return
        (px, py), (vx, vy) = self.g_p, self.g_v
        d_p, d_v = math.hypot(px - pose.x, py - pose.y), math.hypot(vx - pose.x, vy - pose.y)
        err = math.hypot(px - vx, py - vy) / max(0.5 * (d_p + d_v), 1e-6)
        if err >= self.params.err_threshold and not self._z_outlier:
            self.g_p = ((px + vx) / 2, (py + vy) / 2)
        elif d_v < self.params.close_fusion_m and not self._z_outlier:
            # near the goal a relative distance error is small, but the parallax goal's error
            # along the rays is never corrected: let the vector goal pull it
            gain = self.params.close_fusion_gain
            self.g_p = (px + gain * (vx - px), py + gain * (vy - py))
        self.reported = self.g_p

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        """Velocity command toward the reported goal (eq. 15), or the disambiguation turn.

        ``steer_to``: a waypoint from a planner; the robot steers to it while arrival is still
        judged at the goal."""
        p = self.params
        if self.phase is Phase.DISAMBIGUATING:
            return Decision(0.0, p.disambiguation_w, None, False, "turning to tell front from back")
        goal = self.reported
        if goal is None:
            if self._last_theta_world is None:
                return Decision(0.0, 0.0, None, False, "no bearing yet")
            theta_g = wrap_rad(self._last_theta_world - pose.theta)
            return Decision(0.0, self._turn(theta_g), None, False, "turning toward the bearing")
        dx, dy = goal[0] - pose.x, goal[1] - pose.y
        d_g = math.hypot(dx, dy)
        agree = (self.g_v is not None and self.g_p is not None
                 and math.dist(self.g_p, self.g_v) < p.arrival_agreement)
        if self.fitted is not None and self.g_v is not None:  # the fit reported: the vector goal confirms it
            agree = math.dist(self.fitted, self.g_v) < p.arrival_agreement
        no_parallax = self.g_p is None and self.fitted is None and len(self._raw) == self._raw.maxlen
        if d_g < p.arrival_radius and (agree or no_parallax):
            return Decision(0.0, 0.0, goal, True, "arrived")
        if steer_to is not None:
            dx, dy = steer_to[0] - pose.x, steer_to[1] - pose.y
        theta_g = wrap_rad(math.atan2(dy, dx) - pose.theta)
        v, _ = velocity_law(theta_g, d_g, p.v_max, p.w_max, p.k_w, p.k_stop)
        return Decision(v, self._turn(theta_g), goal, False, "homing")

    def _turn(self, theta_g: float) -> float:
        """ω = k_ω θg; for a goal nearly behind keep the turning direction (no ±180° dithering)."""
        p = self.params
        if abs(theta_g) > math.radians(150):
            return self._turn_sign * p.w_max
        _, w = velocity_law(theta_g, 0.0, p.v_max, p.w_max, p.k_w, p.k_stop)
        if w:
            self._turn_sign = math.copysign(1.0, w)
        return w



def _plus(sums: tuple[float, float, float, float], x: float, y: float) -> tuple[float, float, float, float]:
    return sums[0] + x, sums[1] + y, sums[2] + x * x, sums[3] + y * y


def _minus(sums: tuple[float, float, float, float], x: float, y: float) -> tuple[float, float, float, float]:
    return sums[0] - x, sums[1] - y, sums[2] - x * x, sums[3] - y * y


class AoaController(ControllerDefaults):
    """S0 behind the loop's interface: board azimuth -> θs (the mounting's ``to_robot``), RSSI ->
    distance (the calibration's model)."""

    source = "aoa"

    def __init__(self, params: S0Params, to_robot: Callable[[float], float], ranging: LogDistance) -> None:
        self.to_robot, self.ranging = to_robot, ranging
        self.s0 = S0Homing(params)

    @property
    def phase(self) -> str:
        return self.s0.phase

    @property
    def reported(self) -> Any:
        return self.s0.reported

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, Bearing) or item.rssi is None:  # no RSSI: no range for S0
            return None
        theta_s = self.to_robot(item.clockwise_deg)
        distance = float(self.ranging.distance(item.rssi))
        self.s0.on_reading(t, pose, theta_s, distance)
        return {"azimuth": item.clockwise_deg, "rssi": item.rssi, "theta_s": round(theta_s, 4), "distance": round(distance, 3)}

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        return self.s0.decide(pose, steer_to)

    def estimate(self) -> dict[str, Any]:
        return {"goal": _round(self.s0.reported), "g_p": _round(self.s0.g_p), "g_v": _round(self.s0.g_v)}


def _round(v: tuple[float, float] | None) -> list[float] | None:
    return None if v is None else [round(float(x), 4) for x in v]
