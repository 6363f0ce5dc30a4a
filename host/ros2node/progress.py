"""What ``rfhoming node`` says of a homing run, from the loop's run log and state, without ROS 2:
the feedback (estimate, its uncertainty, the distance, the phase), the stand-off goal handed to
Nav2 and when to send it again, and the diagnostics rows. The node turns these into messages."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels


@dataclass(frozen=True)
class Progress:
    """One estimate record of the loop: the goal estimate (odometry frame, m), its spread (m:
    how far the method's two estimates lie apart, S0's parallax and vector goals; None where the
    method keeps one), the robot's pose and its distance to the estimate, and the phase."""

    t: float
    goal: tuple[float, float] | None
    uncertainty_m: float | None
    pose: tuple[float, float, float]
    phase: str

    @property
    def distance_m(self) -> float | None:
        return None if self.goal is None else math.dist(self.goal, self.pose[:2])


def progress(record: dict[str, Any]) -> Progress | None:
    """A run log record -> its Progress, or None (not an estimate, or no pose yet)."""
    if record.get("kind") != "estimate" or record.get("pose") is None:
        return None
    goal = record.get("goal")
    g_p, g_v = record.get("g_p"), record.get("g_v")
    spread = math.dist(g_p, g_v) if g_p is not None and g_v is not None else None
    x, y, theta = record["pose"]
    return Progress(float(record["t"]), None if goal is None else (float(goal[0]), float(goal[1])), spread,
                    (float(x), float(y), float(theta)), str(record.get("phase", "")))


def stand_off(p: Progress, distance_m: float) -> tuple[float, float, float]:
    """The goal for a planner: on the line from the robot to the estimate, ``distance_m`` short of
    it, facing it (x, y, yaw). A robot already nearer than that is sent to where it stands."""
    assert p.goal is not None
    (gx, gy), (x, y) = p.goal, p.pose[:2]
    d = math.dist((gx, gy), (x, y))
    yaw = math.atan2(gy - y, gx - x) if d > 1e-6 else p.pose[2]
    keep = min(distance_m, d)
    return gx - keep * math.cos(yaw), gy - keep * math.sin(yaw), yaw


class Resender:
    """When to hand the planner a new goal: the first estimate in the homing phase, then once the
    estimate has moved ``moved_m`` from the one last sent (it firms up as the robot drives), at
    most once per ``every_s`` of robot time: S0's estimate wanders by about half a metre from one
    control period to the next, and each new goal makes Nav2 plan again."""

    def __init__(self, moved_m: float, every_s: float) -> None:
        self.moved_m, self.every_s = moved_m, every_s
        self.sent: tuple[float, float] | None = None
        self.sent_t = -math.inf
        self.count = 0

    def due(self, p: Progress) -> bool:
        if p.goal is None or p.phase != "homing" or p.t - self.sent_t < self.every_s:
            return False
        if self.sent is not None and math.dist(self.sent, p.goal) < self.moved_m:
            return False
        self.sent, self.sent_t = p.goal, p.t
        self.count += 1
        return True


def diagnostics(loop: Any, mode: str) -> list[tuple[str, int, str, dict[str, str]]]:
    """Rows of /diagnostics: (name, level, message, key-values). ``loop``: the running
    HomingLoop, or None when the node is idle. The fail-safes' row says what stops the robot
    now (a stale sensor stream, odometry silent on the wall clock); each driver's row its
    counters and state (from its ``health()``)."""
    if loop is None:
        return [("rfhoming: homing", OK, "idle", {"mode": mode})]
    reading_age = None if loop.last_reading is None else loop.t - loop.last_reading
    odometry_age = time.monotonic() - loop.last_odometry_wall
    level, message = OK, str(loop.controller.phase)
    if loop.odometry_stale:
        level, message = ERROR, "odometry stale: stopped"
    elif loop.stale:
        level, message = WARN, f"{loop.source} stale: stopped"
    failsafes = {"mode": mode, "driving": str(loop.driving), "phase": str(loop.controller.phase),
                 "sensor_stale": str(loop.stale), "odometry_stale": str(loop.odometry_stale),
                 "stale_stops": str(loop.stale_stops), "commands": str(loop.commands),
                 "reading_age_s": "none" if reading_age is None else f"{reading_age:.3f}",
                 "stale_timeout_s": f"{loop.stale_timeout():.3f}", "odometry_age_s": f"{odometry_age:.3f}",
                 "speed_limit_m_s": "none" if math.isinf(loop.speed_limit) else f"{loop.speed_limit:.3f}"}
    rows = [("rfhoming: homing", level, message, failsafes)]
    for role, driver in [*((d.kind, d) for d in loop.sensors), ("base", loop.base)]:
        health = driver.health()
        state = str(health.get("state", ""))
        rows.append((f"rfhoming: {role} {health.get('device', '')}".rstrip(),
                     OK if state in ("streaming", "connected", "ready", "") else WARN, state,
                     {k: str(v) for k, v in health.items()}))
    return rows
