"""The 2-D world: the robot's true pose, radio targets, obstacles, line of sight, range scans.

Frames: world x/y in metres, headings counter-clockwise from +x in radians (as S0 and REP 103).
Obstacles are polygons (a rectangle is a 4-gon); walls are thin rectangles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rfhoming.emulator.multipath import Path, Reflections


@dataclass
class Pose:
    x: float
    y: float
    theta: float

    def advance(self, v: float, w: float, dt: float) -> None:
        """Exact unicycle integration over ``dt`` at constant (v, ω)."""
        if abs(w) < 1e-9:
            self.x += v * dt * math.cos(self.theta)
            self.y += v * dt * math.sin(self.theta)
        else:
            th2 = self.theta + w * dt
            self.x += v / w * (math.sin(th2) - math.sin(self.theta))
            self.y -= v / w * (math.cos(th2) - math.cos(self.theta))
            self.theta = th2
        self.theta = math.remainder(self.theta, 2 * math.pi)


@dataclass
class Target:
    """A radio source: an AoA tag, a BLE beacon, a 915 MHz emitter or a docking station."""

    id: str
    kind: str  # "aoa_tag", "ble_beacon", "rf_emitter", "dock"
    position: tuple[float, float]
    height: float = 0.0
    path: list[tuple[float, float]] = field(default_factory=list)
    speed: float = 0.0
    interval_ms: float = 20.0
    jitter_ms: float = 0.0
    tx_power_dbm: float = 0.0
    heading: float = 0.0  # docks: the approach direction

    def position_at(self, t: float) -> tuple[float, float]:
        """Static, or moving along ``path`` (looped) at ``speed`` m/s."""
        if not self.path or self.speed <= 0:
            return self.position
        points = [self.position, *self.path, self.position]
        lengths = [math.dist(a, b) for a, b in zip(points, points[1:])]
        s = (self.speed * t) % sum(lengths)
        for (a, b), length in zip(zip(points, points[1:]), lengths):
            if s <= length and length > 0:
                f = s / length
                return (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]))
            s -= length
        return self.position


@dataclass
class Obstacle:
    polygon: list[tuple[float, float]]

    @classmethod
    def rect(cls, x0: float, y0: float, x1: float, y1: float) -> Obstacle:
        return cls([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])

    def edges(self) -> list[tuple[tuple[float, float], tuple[float, float]]]:
        p = self.polygon
        return list(zip(p, p[1:] + p[:1]))

    def contains(self, x: float, y: float) -> bool:
        inside = False
        for (x1, y1), (x2, y2) in self.edges():
            if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
                inside = not inside
        return inside


class World:
    """Geometry queries over all obstacles, vectorised over edges with numpy."""

    def __init__(self, robot: Pose, targets: list[Target], obstacles: list[Obstacle],
                 bounds: tuple[float, float, float, float]) -> None:
        self.robot = robot
        self.targets = targets
        self.obstacles = obstacles
        self.bounds = bounds
        self.t = 0.0
        edges = [e for o in obstacles for e in o.edges()]
        self._a = np.array([e[0] for e in edges], dtype=float).reshape(-1, 2)
        self._b = np.array([e[1] for e in edges], dtype=float).reshape(-1, 2)
        self._owner = np.array([i for i, o in enumerate(obstacles) for _ in o.edges()], dtype=int)
        self._boxes = [(min(x for x, _ in o.polygon), min(y for _, y in o.polygon), max(x for x, _ in o.polygon),
                        max(y for _, y in o.polygon)) for o in obstacles]
        self._reflections: dict[bool, Reflections] = {}

    def reflected_paths(self, source: tuple[float, float], receiver: tuple[float, float],
                        bounds_reflect: bool = False) -> tuple[Path, ...]:
        """First-order reflections off the obstacles (and the bounds) from source to receiver."""
        r = self._reflections.get(bounds_reflect)
        if r is None:
            r = self._reflections[bounds_reflect] = Reflections(self.obstacles, self.bounds if bounds_reflect else None)
        return r.paths(source, receiver)

    def obstacles_crossed(self, p: tuple[float, float], q: tuple[float, float]) -> int:
        """How many distinct obstacles the segment p-q passes through (0 = line of sight).
        Only obstacles whose box meets the segment's box can be crossed: the edge test runs on
        those (per radio reception, most of a house's obstacles are out of the way)."""
        lo_x, hi_x, lo_y, hi_y = min(p[0], q[0]) - 1e-9, max(p[0], q[0]) + 1e-9, min(p[1], q[1]) - 1e-9, max(p[1], q[1]) + 1e-9
        near = [k for k, (x0, y0, x1, y1) in enumerate(self._boxes) if x0 <= hi_x and lo_x <= x1 and y0 <= hi_y and lo_y <= y1]
        if not near:
            return 0
        edges = np.isin(self._owner, near)
        a, owner = self._a[edges], self._owner[edges]
        p_, q_ = np.asarray(p, float), np.asarray(q, float)
        d = q_ - p_
        e = self._b[edges] - a
        denom = d[0] * e[:, 1] - d[1] * e[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            w = a - p_
            t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / denom
            u = (w[:, 0] * d[1] - w[:, 1] * d[0]) / denom
        hit = (np.abs(denom) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
        return int(np.count_nonzero(np.bincount(owner[hit])))  # distinct owners; faster than np.unique

    def cast(self, origin: tuple[float, float], angles: np.ndarray, max_range: float) -> np.ndarray:
        """Range along each world angle to the nearest obstacle edge; inf beyond ``max_range``."""
        if not len(self._a):
            return np.full(len(angles), np.inf)
        o = np.asarray(origin, float)
        d = np.stack([np.cos(angles), np.sin(angles)], axis=1)[:, None, :]  # (n,1,2)
        e = (self._b - self._a)[None, :, :]  # (1,m,2)
        w = (self._a - o)[None, :, :]
        denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / denom
            u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / denom
        valid = (np.abs(denom) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
        t = np.where(valid, t, np.inf).min(axis=1)
        return np.where(t <= max_range, t, np.inf)

    def collides(self, x: float, y: float, radius: float) -> bool:
        """Whether a disc of ``radius`` at (x, y) touches an obstacle. Only obstacles whose box,
        grown by ``radius``, holds the centre can (this runs every step: most steps meet none)."""
        near = [k for k, (x0, y0, x1, y1) in enumerate(self._boxes)
                if x0 - radius <= x <= x1 + radius and y0 - radius <= y <= y1 + radius]
        if not near:
            return False
        if any(self.obstacles[k].contains(x, y) for k in near):
            return True
        edges = np.isin(self._owner, near)
        a, e = self._a[edges], self._b[edges] - self._a[edges]
        p = np.array([x, y])
        s = np.clip(np.einsum("ij,ij->i", p - a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-12), 0, 1)
        nearest = a + s[:, None] * e
        return bool(np.min(np.hypot(*(nearest - p).T)) < radius)
