"""Bearings: where rays from known positions cross.

Frames: world x/y in metres, bearings in radians counter-clockwise from +x (the robot heading
plus the sensor's angle, as S0 writes α = θr + θs). Used by S0's parallax homing (one moving sensor) and by
fixed multi-anchor XPLR-AOA set-ups (several sensors at once).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

MIN_CROSSING_SIN = math.sin(math.radians(3.0))
"""Rays closer than 3° to parallel cross too far away to trust."""


class Degenerate(ValueError):
    """The geometry cannot give a position (parallel rays, too few or collinear anchors)."""


def intersect(p1: Sequence[float], a1: float, p2: Sequence[float], a2: float,
              min_sin: float = MIN_CROSSING_SIN) -> tuple[float, float]:
    """The point where the ray from p1 at bearing a1 meets the ray from p2 at bearing a2.

    S0's parallax form: d1 = −dr·sin(β − a2)/sin(a2 − a1). Raises Degenerate for near-parallel
    rays or a crossing behind either sensor.
    """
    s = math.sin(a2 - a1)
    if abs(s) < min_sin:
        raise Degenerate(f"rays {math.degrees(abs(a2 - a1)):.1f}° from parallel")
    dx, dy = p2[0] - p1[0], p2[1] - p1[1]
    d1 = (dx * math.sin(a2) - dy * math.cos(a2)) / s
    d2 = (dx * math.sin(a1) - dy * math.cos(a1)) / s
    if d1 < 0 or d2 < 0:
        raise Degenerate("the rays cross behind a sensor")
    return p1[0] + d1 * math.cos(a1), p1[1] + d1 * math.sin(a1)


def triangulate(positions: np.ndarray, bearings: np.ndarray, weights: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares point closest to all bearing lines; returns (point, covariance).

    Each line contributes (I − u uᵀ) with u its direction; weights are 1/σ² of each bearing
    scaled by 1/range² in practice (the caller knows). Degenerate for parallel lines.
    """
    p = np.asarray(positions, float).reshape(-1, 2)
    b = np.asarray(bearings, float).ravel()
    w = np.ones(len(b)) if weights is None else np.asarray(weights, float).ravel()
    if len(b) < 2:
        raise Degenerate("need at least two bearings")
    u = np.stack([np.cos(b), np.sin(b)], axis=1)
    proj = np.eye(2)[None] - u[:, :, None] * u[:, None, :]  # (n, 2, 2)
    a = np.einsum("n,nij->ij", w, proj)
    rhs = np.einsum("n,nij,nj->i", w, proj, p)
    if np.linalg.cond(a) > 1e6:
        raise Degenerate("bearing lines are (nearly) parallel")
    point = np.linalg.solve(a, rhs)
    return point, np.linalg.inv(a)


def kohonen_update(goal: Sequence[float], robot: Sequence[float], bearing: float, k: float = 0.8
                   ) -> tuple[float, float]:
    """S0's parallax update: move the old goal by k·d_e perpendicular toward the newest ray.

    d_o = |g_o − r|, φ = atan2(g_o − r), d_e = d_o sin(φ − α), g = g_o + k d_e (sin α, −cos α).
    """
    dx, dy = goal[0] - robot[0], goal[1] - robot[1]
    d_e = math.hypot(dx, dy) * math.sin(math.atan2(dy, dx) - bearing)
    return goal[0] + k * d_e * math.sin(bearing), goal[1] - k * d_e * math.cos(bearing)
