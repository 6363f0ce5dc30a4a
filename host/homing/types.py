"""Small value types shared by the controllers and the loop, and the controllers' interface."""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Protocol

from rfhoming.host.drivers.robot import Scan
from rfhoming.protocol.errors import Error


class ParamsError(Error, ValueError):
    """A controller's parameters cannot make it (e.g. a config that lacks what it needs); the
    message names the config key."""


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


class Controller(Protocol):
    """What the loop needs of a homing controller (:class:`ControllerDefaults` gives the
    optional parts)."""

    source: str  # what its readings are called in the run log ("aoa", "rss", ...)
    uses_planner: bool  # the loop's occupancy grid and A* may steer it
    own_avoidance: bool  # it avoids obstacles by its own rules: the loop's S0 avoidance stays off
    # the loop stops the robot while its readings are stale; a survey flies its pattern on
    # odometry whatever it hears (silence is where it has not found anything yet)
    needs_fresh_readings: bool

    @property
    def phase(self) -> str: ...

    @property
    def reported(self) -> Any:
        """The goal estimate (x, y) or None."""

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        """One sensor reading; returns the fields to log, or None if it was not a reading."""

    def on_scan(self, scan: Scan) -> None:
        """A range scan (most controllers leave scans to the planner and avoidance)."""

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision: ...

    def estimate(self) -> dict[str, Any]:
        """What to log of the current estimate."""


class ControllerDefaults:
    """The optional parts of :class:`Controller`: planned, the loop's avoidance, scans unused."""

    uses_planner = True
    own_avoidance = False
    needs_fresh_readings = True

    def on_scan(self, scan: Scan) -> None:
        pass
