"""A fixed target from many (bearing, range) readings taken near it along a path.

Each reading from robot position r with world bearing α and range d gives a raw vector goal
p = r + d (cos α, sin α). Its error is the range error along the ray and d·δα across it; with a
sensor prior σ² = σ_abs² + (σ_rel² + σ_α²) ρ², ρ the distance from r to the current estimate
(floored at ``min_range_m``), the fusion is the inverse-variance weighted mean of every raw goal
taken within ``max_range_m`` of the estimate.

Why: once the robot drives straight at the goal every ray agrees and only ranges
tell how far the goal is; S0's estimates then rest on its last few readings (Kohonen's k, a
20-reading vector goal), while this keeps every reading of the approach. Readings from farther
away are left out: RSSI ranges there carry biases an average cannot remove, and the
weights of near readings would drown in their number. ρ comes from the estimate, not the
reading's own range: weighting a reading by its own range would favour those that read short.
The σ are a prior fixed for every noise level (never the simulator's); ``half_life_s`` forgets
old readings, whose positions drift with odometry. Pure Python floats: it runs per reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class FusionPrior:
    sigma_angle_deg: float = 10.0
    sigma_abs_m: float = 0.5
    sigma_rel: float = 0.3
    min_range_m: float = 0.5
    max_range_m: float = 3.0
    half_life_s: float = 30.0


class RayRangeFusion:
    """Running inverse-variance weighted mean of the raw vector goals near the estimate."""

    def __init__(self, prior: FusionPrior = FusionPrior()) -> None:
        self.prior = prior
        self._sx = self._sy = self._sw = 0.0
        self._t: float | None = None
        self.readings = 0

    def add(self, t: float, x: float, y: float, alpha: float, distance: float,
            estimate: tuple[float, float] | None) -> None:
        """One reading from (x, y) at world bearing ``alpha`` (rad) and range ``distance`` (m);
        ``estimate``: the current goal estimate (the reading's own range stands in without one)."""
        p = self.prior
        rho = distance if estimate is None else math.hypot(estimate[0] - x, estimate[1] - y)
        if rho > p.max_range_m:
            return
        if self._t is not None and p.half_life_s > 0:
            keep = 0.5 ** (max(t - self._t, 0.0) / p.half_life_s)
            self._sx, self._sy, self._sw = self._sx * keep, self._sy * keep, self._sw * keep
        self._t = t
        rho = max(rho, p.min_range_m)
        w = 1.0 / (p.sigma_abs_m ** 2 + (p.sigma_rel ** 2 + math.radians(p.sigma_angle_deg) ** 2) * rho * rho)
        self._sx += w * (x + distance * math.cos(alpha))
        self._sy += w * (y + distance * math.sin(alpha))
        self._sw += w
        self.readings += 1

    def estimate(self) -> tuple[float, float] | None:
        """The fused target, or None before any reading near the estimate."""
        if self._sw <= 0.0:
            return None
        return self._sx / self._sw, self._sy / self._sw
