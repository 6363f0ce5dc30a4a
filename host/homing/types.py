"""Small value types shared by the controllers and the loop."""

from __future__ import annotations

import math
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


def velocity_law(theta_g: float, d_g: float, v_max: float, w_max: float, k_w: float, k_stop: float
                 ) -> tuple[float, float]:
    """S0 eq. (15), shared by the controllers: v = (2/π) v_max |π/2 − |θg|| for |θg| ≤ π/2
    (0 beyond), capped by k_stop · d_g so the robot does not overshoot; ω = k_ω θg, clamped."""
    v = (2 / math.pi) * v_max * abs(math.pi / 2 - abs(theta_g)) if abs(theta_g) <= math.pi / 2 else 0.0
    return min(v, k_stop * d_g), max(-w_max, min(w_max, k_w * theta_g))
