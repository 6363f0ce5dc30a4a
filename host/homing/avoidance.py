"""S0 Appendix B: rule-based obstacle avoidance on the base's 180° front range scan.

The scan is split into left / centre / right thirds plus 'centre 2', the middle 20 %; each
sector's reading is its shortest range (S0 also corrects the centre sectors with a forward
ultrasonic range for glass; our base has no ultrasonic sensor, so the scan is used as it is).
Thresholds from S0 Table A1: obsThreshold1 1.5 m, obsThreshold2 0.35 m, sideObsThreshold 0.4 m.

S0 gives the thresholds but its rule flowchart (Figure A6) is not in the text; these rules are
our reconstruction:
- something within obsThreshold2 ahead (centre 2 or centre): stop and turn to the freer side;
  with a planner steering, stop but keep the planner's own turn (a turn in place brings
  nothing nearer). Turning to the freer side there, the robot turned back and forth for
  minutes facing a chair while the path led away beside it: the homing turned it toward the
  path, slowly driving as it turned, and this rule back to the freer side as soon as the
  chair came into the centre;
- something within obsThreshold1 in the centre while driving forward: slow down in proportion
  and steer to the freer side unless the homing command already does (a turn in place is left
  alone: steering it away from something ahead it does not approach held the robot facing a
  sofa, turning back and forth, while the goal lay behind it);
- a side closer than sideObsThreshold while driving forward: turn away from it. A turn in
  place is left alone here too: it brings no part of the round base nearer, and forbidding
  it wedged the robot between a chair and a wall, turning away and back for two minutes while
  the goal lay behind it.
Once avoiding, the chosen side is kept until the centre has been clear for ``release_s``
(robot time): a reactive rule that re-chooses every step dithers in front of a wall between
the robot and its goal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfhoming.host.drivers.robot import Scan
from rfhoming.host.homing.schema import RAD_S, M, S, setting
from rfhoming.host.homing.types import Decision


@dataclass(frozen=True)
class AvoidParams:
    enabled: bool = setting(True)
    obs_threshold1: float = setting(1.5, low=0, above=True, high=20, unit=M)
    obs_threshold2: float = setting(0.35, low=0, above=True, high=20, unit=M)
    side_threshold: float = setting(0.4, low=0, high=20, unit=M)
    w_turn: float = setting(1.0, low=0, above=True, high=10, unit=RAD_S)
    release_s: float = setting(1.5, low=0, high=60, unit=S)


@dataclass
class Sectors:
    left: float
    centre: float
    right: float
    centre2: float


def sectors(scan: Scan) -> Sectors:
    ranges = np.array([math.inf if r is None else r for r in scan.ranges])
    angles = scan.angle_min + scan.angle_increment * np.arange(len(ranges))

    def shortest(mask: np.ndarray) -> float:
        return float(ranges[mask].min()) if mask.any() else math.inf

    third = math.pi / 6
    return Sectors(left=shortest(angles > third), centre=shortest(np.abs(angles) <= third),
                   right=shortest(angles < -third), centre2=shortest(np.abs(angles) <= math.radians(18)))


class ObstacleAvoidance:
    def __init__(self, params: AvoidParams = AvoidParams()) -> None:
        self.params = params
        self.latest: Sectors | None = None
        self._side = 0.0  # +1 left, −1 right, 0 not avoiding
        self._clear_since: float | None = None

    def on_scan(self, scan: Scan) -> None:
        self.latest = sectors(scan)

    def adjust(self, decision: Decision, t: float, emergency_only: bool = False) -> Decision:
        """The homing command, modified where an obstacle is near. ``emergency_only`` (a planner
        is steering) keeps just the stop-and-turn and side rules."""
        s, p = self.latest, self.params
        if s is None or decision.arrived:
            return decision
        v, w, note = decision.v, decision.w, decision.note
        ahead = min(s.centre, s.centre2)
        if (emergency_only or v <= 0.0) and ahead >= p.obs_threshold2:
            pass  # a planner steers, or the robot turns in place: nothing ahead to slow for
        elif emergency_only and v <= 0.0:
            pass  # a planner steers a turn in place: it brings nothing nearer, whatever is ahead
        elif emergency_only and abs(w) >= p.w_turn / 2:
            # a planner steers away, something is near ahead: stop, and keep turning as the path does
            v, note = 0.0, "blocked ahead: turning toward the path"
        elif ahead < p.obs_threshold1:
            self._clear_since = None
            if not self._side:
                self._side = 1.0 if s.left >= s.right else -1.0
            if ahead < p.obs_threshold2:
                v, w, note = 0.0, self._side * p.w_turn, "blocked ahead: turning to the freer side"
            else:
                v *= (ahead - p.obs_threshold2) / (p.obs_threshold1 - p.obs_threshold2)
                if w * self._side <= 0:
                    w = self._side * p.w_turn * (p.obs_threshold1 - ahead) / (p.obs_threshold1 - p.obs_threshold2)
                note = "obstacle ahead: slowing, steering to the freer side"
        elif self._side:
            self._clear_since = t if self._clear_since is None else self._clear_since
            if t - self._clear_since >= p.release_s:
                self._side = 0.0
        if v > 0.0 and s.left < p.side_threshold:
            w, note = min(w, -p.w_turn / 2), "too close on the left"
        if v > 0.0 and s.right < p.side_threshold:
            w, note = max(w, p.w_turn / 2), "too close on the right"
        return Decision(v, w, decision.goal, False, note)
