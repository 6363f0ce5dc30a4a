"""S2: homing on a 915 MHz emitter with four directional antennas and a particle filter.

Each antenna set (the four dishes' powers for one emitter frame) gives an instantaneous fix:
the direction θ = atan2(y1 − y2, x1 − x2) (see host.estimation.particle for the axes) and a
range from the strongest antenna's power with its dish gain removed (log-distance). The
particle filter (N = 1000) smooths the fixes into the emitter's position; the robot steers to
it (or to the planner's waypoint) with S0's velocity law and stops when the estimated range
is below ``arrival_range_m``. With
``motion = "preliminary"`` it moves by S2's first rule set instead (20 cm, ±15°, ±90°), with no
map and no planner. Its 20 cm are from the robot's body (scan range minus ``body_radius_m``):
measured from the scanner at the centre of a 0.25 m robot they were never reached before the
bumper, and the robot pushed against the wall until time ran out.

The default is ours: ``likelihood = "bounded"`` (see host.estimation.particle), stopping at
0.25 m and only when the dishes agree as well (the median range of the last five fixes below
it: such a range reads long and almost never short). A fix in which a chip saturated (its ED at
84, a few tens of centimetres from the emitter) counts as below it: the radio cannot read any
nearer, and the floor it reads instead is often above 0.25 m once the dish's offset is removed,
so the robot stood at the emitter without ever confirming it. It reached the emitter in all of S2's
scenarios where S2's own weights failed behind walls (docs/RESULTS.md). S2's system as
published is ``likelihood = "s2"`` with ``arrival_range_m = 0.5`` (S2: "stop when front+back
RSS says < 50 cm").

Calibration (config [s2]): the emitter's power at 1 m for an isotropic antenna (p0_dbm), the
path-loss exponent, and the dishes' peak gain (6.6 dBi for 0.3 m dishes at 915 MHz,
10 log10(0.55 (π d / λ)²)); or, from a calibration run through the dishes themselves, p0_dbm
with the gain inside it (peak_gain_db = 0). ``dish_offsets_db`` (x1, x2, y1, y2) are each
dish's own offset (chip and dish), measured with each dish facing the emitter in turn and
subtracted from its power before the direction and range are computed.
"""

from __future__ import annotations

import enum
import math
import statistics
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfhoming.host.drivers.rss import AntennaPowers
from rfhoming.host.estimation.fixed import wrap_rad
from rfhoming.host.estimation.particle import (
    ParticleFilter,
    PfParams,
    differential_to_range,
    direction,
)
from rfhoming.host.homing.schema import DB, DBM, M_S, RAD_S, M, setting
from rfhoming.host.homing.types import ControllerDefaults, Decision, ParamsError, Pose, velocity_law


@dataclass(frozen=True)
class S2Params:
    p0_dbm: float = setting(-40.0, low=-150, high=30, unit=DBM)
    n: float = setting(2.0, low=1, high=6, unit="(path-loss exponent)")
    peak_gain_db: float = setting(6.6, low=-20, high=40, unit="dBi")
    arrival_range_m: float = setting(0.25, low=0, above=True, high=100, unit=M)  # S2's own: 0.5
    min_fixes: int = setting(10, low=1, high=10000, unit="fixes")
    v_max: float = setting(0.4, low=0, above=True, high=5, unit=M_S)
    w_max: float = setting(1.0, low=0, above=True, high=10, unit=RAD_S)
    k_w: float = setting(1.5, low=0, above=True, high=20, unit="1/s")
    k_stop: float = setting(0.8, low=0, above=True, high=10, unit="1/s")
    search_w: float = setting(0.5, low=0, high=10, unit=RAD_S)
    seed: int = setting(0, low=0, high=2**32 - 1)
    motion: str = setting("full", choices=("full", "preliminary"))  # "full": the loop's grid + A*; "preliminary": S2's rule-based motion
    obstacle_m: float = setting(0.2, low=0, high=10, unit=M)  # preliminary: an obstacle this close ahead means turn until clear
    body_radius_m: float = setting(0.25, low=0, high=5, unit=M)  # preliminary: obstacle_m is measured from the robot's round body, not the scanner
    touch_m: float = setting(0.05, low=0, high=5, unit=M)  # preliminary: an obstacle this near the body anywhere in the scan counts as ahead
    likelihood: str = setting("bounded", choices=("s2", "bounded"))  # the particle filter's weights: "bounded" (ours) or "s2" (host.estimation.particle)
    dish_offsets_db: tuple[float, float, float, float] = setting((0.0, 0.0, 0.0, 0.0), low=-40, high=40, unit=DB)  # x1, x2, y1, y2
    confirm_s: float = setting(2.0, low=0, high=60, unit="s")  # bounded: arrival holds this long, the robot creeping on, before it stops
    saturated_arrival_m: float = setting(0.15, low=0, above=True, high=100, unit=M)  # bounded: the filter's stop radius when the chips saturate
    spin_calibration: bool = setting(True)  # bounded (ours): a turn in place measures the dishes' offsets where the robot stands
    spin_w: float = setting(0.8, low=0, above=True, high=10, unit=RAD_S)  # its turn rate
    stuck_s: float = setting(40.0, low=0, above=True, high=3600, unit="s")  # homing this long within stuck_m of one place: turn again
    stuck_m: float = setting(0.5, low=0, above=True, high=100, unit=M)
    contradict_s: float = setting(15.0, low=0, above=True, high=3600, unit="s")  # the filter against the dishes this long: turn again

    def __post_init__(self) -> None:  # a TOML list becomes the tuple the default is
        object.__setattr__(self, "dish_offsets_db", tuple(float(v) for v in self.dish_offsets_db))
        if len(self.dish_offsets_db) != 4:
            raise ParamsError("[s2] dish_offsets_db needs four values: x1, x2, y1, y2")



class Motion(enum.Enum):
    """What S2's robot is doing: turning in place to measure the dishes' offsets, or homing."""

    TURNING = "turning"
    HOMING = "homing"

class RssController(ControllerDefaults):
    source = "rss"

    def __init__(self, params: S2Params = S2Params()) -> None:
        if params.motion not in ("full", "preliminary"):
            raise ParamsError("[s2] motion must be 'full' or 'preliminary'")
        self.params = params
        # the preliminary system avoids obstacles by its own 20 cm rule: no planner, no S0 avoidance
        self.uses_planner = params.motion == "full"
        self.own_avoidance = params.motion == "preliminary"
        self.front_m = math.inf
        if params.likelihood not in ("s2", "bounded"):
            raise ParamsError("[s2] likelihood must be 's2' or 'bounded'")
        self.pf = ParticleFilter(PfParams(likelihood=params.likelihood), np.random.default_rng(params.seed))
        self.fixes = 0
        self._last_t: float | None = None
        self._last_fix: tuple[float, float] | None = None
        self._ranges: deque[float] = deque(maxlen=5)
        self._saturated: deque[bool] = deque(maxlen=5)
        self.offsets: tuple[float, float, float, float] = params.dish_offsets_db
        self.spins = 0
        self.motion = Motion.TURNING if params.spin_calibration and params.likelihood == "bounded" else Motion.HOMING
        self._spin: list[tuple[float, Pose, tuple[float, float, float, float], bool]] = []
        self._spin_turned = 0.0
        self._spin_heading: float | None = None
        self._anchor: tuple[float, float, float] | None = None  # (t, x, y): where the robot last was stuck_m away from
        self._t = 0.0
        self._spun_at = 0.0
        self._close_since: float | None = None
        self._recent: deque[tuple[float, float]] = deque()  # (t, range) of the last contradict_s of fixes
        self._track: deque[tuple[float, float, float, float, float]] = deque()  # (t, robot x, y, emitter x, y) as long

    @property
    def phase(self) -> str:
        if self.motion is Motion.TURNING:
            return "calibrating"
        return "homing" if self.fixes >= self.params.min_fixes else "searching"

    @property
    def reported(self) -> Any:
        return self.pf.estimate() if self.fixes >= self.params.min_fixes else None

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, AntennaPowers):
            return None
        if any(p is None for p in item.dbm):
            return {"incomplete": True}
        self._t = t
        raw = (float(item.dbm[0]), float(item.dbm[1]), float(item.dbm[2]), float(item.dbm[3]))  # type: ignore[arg-type]
        saturated = any(item.saturated)
        if self.motion is Motion.TURNING:
            self._spin.append((t, pose, raw, saturated))
        theta, diff_db, rng = self._fix(t, pose, raw)
        self.fixes += 1
        self._ranges.append(rng)
        self._saturated.append(saturated)
        self._recent.append((t, rng))
        while self._recent[0][0] < t - self.params.contradict_s:
            self._recent.popleft()
        self._last_fix = (pose.x + rng * math.cos(pose.theta + theta), pose.y + rng * math.sin(pose.theta + theta))
        out = {"theta": round(theta, 4), "range": round(rng, 3), "diff_db": round(diff_db, 2)}
        if saturated:
            out["saturated"] = True
        return out

    def _fix(self, t: float, pose: Pose, raw: tuple[float, float, float, float]) -> tuple[float, float, float]:
        """One fix into the filter, the dishes' offsets removed: (bearing rad, dB apart, range m)."""
        p = self.params
        dbm = [v - o for v, o in zip(raw, self.offsets)]
        theta, diff_db = direction(*dbm)
        rng = differential_to_range(np.array(dbm), p.p0_dbm, p.n, p.peak_gain_db)
        if self._last_t is not None:
            self.pf.predict(max(t - self._last_t, 0.0))
        self._last_t = t
        self.pf.update((pose.x, pose.y, pose.theta), rng, theta)
        return theta, diff_db, rng

    def _end_spin(self) -> None:
        """A full turn in place: every dish has faced every way, so what differs between their
        mean powers over the turn is their own offsets where the robot stands (chip, dish, and
        the place's fading on each), whatever the emitter's bearing. Take these as the offsets
        (mean zero, as the calibration's), restart the filter and give it the turn's readings."""
        self.motion = Motion.HOMING
        self.spins += 1
        bins: dict[int, list[tuple[float, float, float, float]]] = {}
        for _, pose, raw, _ in self._spin:  # by heading, so that a stall in one direction weighs no more
            bins.setdefault(int((pose.theta % (2 * math.pi)) // (math.pi / 6)), []).append(raw)
        if len(bins) >= 10:  # nearly every heading heard: else keep the offsets there are
            means = np.mean([np.mean(v, axis=0) for v in bins.values()], axis=0)
            means -= means.mean()
            self.offsets = (float(means[0]), float(means[1]), float(means[2]), float(means[3]))
            self.pf = ParticleFilter(self.pf.params, self.pf.rng)
            self._last_t = None
            self._ranges.clear()
            self._saturated.clear()
            for t, pose, raw, saturated in self._spin:
                _, _, rng = self._fix(t, pose, raw)
                self._ranges.append(rng)
                self._saturated.append(saturated)
        self._spin = []
        self._spin_heading = None
        self._anchor = None
        self._spun_at = self._t

    def _spin_step(self, pose: Pose) -> Decision | None:
        """While turning in place: the command, or None when the turn is done."""
        if self._spin_heading is not None:
            self._spin_turned += abs(wrap_rad(pose.theta - self._spin_heading))
        else:
            self._spin_turned = 0.0
        self._spin_heading = pose.theta
        if self._spin_turned < 2 * math.pi + 0.2:
            return Decision(0.0, self.params.spin_w, None, False, "turning in place: the dishes' offsets")
        self._end_spin()
        return None

    def _stuck(self, pose: Pose, d_g: float) -> bool:
        """Homing, and no farther than ``stuck_m`` from one place for ``stuck_s``; or, at least
        ``contradict_s`` after a turn, a filter that follows the robot: over the last
        ``contradict_s`` the robot moved more than 1 m, its emitter moved along by more than half
        that, and it is much nearer than the dishes' median range says (by 3 times and 1.5 m). A
        cloud that sits by the robot and moves with it is one its bounded weights cannot rule out
        by themselves (a static emitter does not follow the robot)."""
        p = self.params
        if not (p.spin_calibration and p.likelihood == "bounded"):
            return False
        goal = self.pf.estimate()
        self._track.append((self._t, pose.x, pose.y, float(goal[0]), float(goal[1])))
        while self._track[0][0] < self._t - p.contradict_s:
            self._track.popleft()
        if self._t - self._spun_at > p.contradict_s and self._recent:
            t0, x0, y0, gx0, gy0 = self._track[0]
            moved = math.hypot(pose.x - x0, pose.y - y0)
            dragged = math.hypot(goal[0] - gx0, goal[1] - gy0)
            heard = statistics.median(r for _, r in self._recent)
            if moved > 1.0 and dragged > moved / 2 and heard > max(3 * d_g, d_g + 1.5):
                return True
        if self._anchor is None or math.dist((pose.x, pose.y), self._anchor[1:]) > p.stuck_m:
            self._anchor = (self._t, pose.x, pose.y)
            return False
        return self._t - self._anchor[0] > p.stuck_s

    def on_scan(self, scan: Any) -> None:
        """Preliminary motion: the nearest obstacle to the robot's body within ±30° ahead (S2's
        20 cm are from the robot, not its scanner), or anywhere in the scan if it touches the
        body (``touch_m``: one beside the robot stops it as surely as one ahead)."""
        p = self.params
        ahead, beside = math.inf, math.inf
        for i, r in enumerate(scan.ranges):
            if r is not None:
                beside = min(beside, r - p.body_radius_m)
                if abs(scan.angle_min + i * scan.angle_increment) <= math.pi / 6:
                    ahead = min(ahead, r - p.body_radius_m)
        self.front_m = ahead if beside >= p.touch_m else min(ahead, beside)

    def _preliminary(self, pose: Pose, goal: Any) -> Decision:
        """S2's rules: an obstacle within 20 cm -> turn until clear; target within ±15° ->
        forward; otherwise turn toward it while moving forward; beyond ±90° turn in place."""
        p = self.params
        _, bearing = self.pf.relative((pose.x, pose.y, pose.theta))
        g = (float(goal[0]), float(goal[1]))
        if self.front_m < p.obstacle_m:
            return Decision(0.0, p.w_max, g, False, "obstacle within 20 cm: turning until clear")
        if abs(bearing) <= math.radians(15):
            return Decision(p.v_max, 0.0, g, False, "target within ±15°: forward")
        if abs(bearing) <= math.pi / 2:
            return Decision(p.v_max / 2, math.copysign(p.w_max / 2, bearing), g, False, "turning toward the target")
        return Decision(0.0, math.copysign(p.w_max, bearing), g, False, "target behind: turning")

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        p = self.params
        if self.motion is Motion.TURNING:
            turning = self._spin_step(pose)
            if turning is not None:
                return turning
        goal = self.reported
        if goal is None:
            return Decision(0.0, p.search_w if self.fixes == 0 else 0.0, None, False, "waiting for fixes")
        estimated_range, _ = self.pf.relative((pose.x, pose.y, pose.theta))
        d_g = math.hypot(goal[0] - pose.x, goal[1] - pose.y)
        close = estimated_range < p.arrival_range_m or d_g < p.arrival_range_m
        if close and p.likelihood == "bounded":  # the dishes must say so too (their range seldom reads short)
            if 2 * sum(self._saturated) > len(self._saturated):
                # most chips saturated: the radio cannot tell any nearer, its floor may read above
                # arrival_range_m, and a place's fading can saturate it farther out: the filter alone
                # decides, with a tighter radius
                r = p.saturated_arrival_m
                close = estimated_range < r or d_g < r
            else:
                close = statistics.median(self._ranges) < p.arrival_range_m
        if close and p.likelihood == "bounded":  # close for confirm_s on end, still creeping to the estimate
            self._close_since = self._t if self._close_since is None else self._close_since
            close = self._t - self._close_since >= p.confirm_s
        else:
            self._close_since = None
        if close:
            return Decision(0.0, 0.0, (float(goal[0]), float(goal[1])), True, "arrived")
        if self._close_since is None and self._stuck(pose, d_g):
            self.motion = Motion.TURNING
            return Decision(0.0, p.spin_w, None, False, "stuck: turning in place again")
        if p.motion == "preliminary":
            return self._preliminary(pose, goal)
        aim = steer_to if steer_to is not None else goal
        theta_g = wrap_rad(math.atan2(aim[1] - pose.y, aim[0] - pose.x) - pose.theta)
        v, w = velocity_law(theta_g, d_g, p.v_max, p.w_max, p.k_w, p.k_stop)
        return Decision(v, w, (float(goal[0]), float(goal[1])), False, "homing")

    def estimate(self) -> dict[str, Any]:
        goal = self.reported
        return {"goal": None if goal is None else [round(float(v), 4) for v in goal],
                "fix": None if self._last_fix is None else [round(v, 4) for v in self._last_fix]}
