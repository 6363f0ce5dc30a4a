"""Small value types shared by the controllers and the loop."""

from __future__ import annotations

from typing import NamedTuple


class Pose(NamedTuple):
    """Robot pose in the odometry/world frame: metres, radians CCW from +x."""

    x: float
    y: float
    theta: float


class Decision(NamedTuple):
    """A controller's output for one control step."""

    v: float  # m/s
    w: float  # rad/s
    goal: tuple[float, float] | None  # the goal position it steers to (standalone-planner output)
    arrived: bool
    note: str
