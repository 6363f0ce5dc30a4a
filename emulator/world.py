"""The 2-D world: the robot's true pose, radio targets, obstacles, line of sight, range scans.

Frames: world x/y in metres, headings counter-clockwise from +x in radians (as S0 and REP 103).
Obstacles are polygons (a rectangle is a 4-gon); walls are thin rectangles.
"""

from __future__ import annotations

import bisect
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
    heading: float = 0.0  # docks: the approach direction; a tag: the way its carrier faces while static
    timetable: list[tuple[float, float, float]] = field(default_factory=list)  # (t, x, y): a walk on a clock

    def position_at(self, t: float) -> tuple[float, float]:
        """Static, on its ``timetable`` (straight lines between its points, held at the ends), or
        moving along ``path`` (looped) at ``speed`` m/s."""
        if self.timetable:
            times = [p[0] for p in self.timetable]
            return (float(np.interp(t, times, [p[1] for p in self.timetable])),
                    float(np.interp(t, times, [p[2] for p in self.timetable])))
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

    def heading_at(self, t: float, dt: float = 0.05) -> float:
        """The way it moves at ``t`` (rad), or, standing, the way it last moved (``heading``
        before it ever moved): the way the body that carries a tag faces."""
        if self.timetable:
            points = self.timetable
            after = bisect.bisect_right([p[0] for p in points], t)
            for i in range(min(after, len(points) - 1), 0, -1):  # the segment into point i, going back
                dx, dy = points[i][1] - points[i - 1][1], points[i][2] - points[i - 1][2]
                if math.hypot(dx, dy) > 1e-9:
                    return math.atan2(dy, dx)
            return self.heading
        if not self.path or self.speed <= 0:
            return self.heading
        (x0, y0), (x1, y1) = self.position_at(t - dt), self.position_at(t)
        return math.atan2(y1 - y0, x1 - x0)


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
    """Geometry queries over all obstacles, vectorised over edges with numpy.

    Static geometry (each obstacle's edges, boxes and the edge rows of each set of nearby
    obstacles) is computed once: the queries run every step, the obstacles never move."""

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
        self._edge_box = (np.minimum(self._a, self._b), np.maximum(self._a, self._b))
        # per obstacle: its edges as (ax, ay, ex, ey, |e|² floored) for the collision test, in
        # the order of the vectorised test, and its row range in the edge arrays
        self._obstacle_edges = [[_edge(a, b) for a, b in o.edges()] for o in obstacles]
        ends = np.cumsum([len(o.polygon) for o in obstacles], dtype=int)
        self._rows = [(int(e) - len(o.polygon), int(e)) for o, e in zip(obstacles, ends)]
        self._near_edges: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._grown: tuple[float, list[tuple[float, float, float, float, int]]] | None = None
        self._reflections: dict[bool, Reflections] = {}

    def reflected_paths(self, source: tuple[float, float], receiver: tuple[float, float],
                        bounds_reflect: bool = False) -> tuple[Path, ...]:
        """First-order reflections off the obstacles (and the bounds) from source to receiver."""
        r = self._reflections.get(bounds_reflect)
        if r is None:
            r = self._reflections[bounds_reflect] = Reflections(self.obstacles, self.bounds if bounds_reflect else None)
        return r.paths(source, receiver)

    def _edges_of(self, near: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(start, direction, owner) of the edges of obstacles ``near``, in edge order (as a
        mask over all edges picks them); cached per set, as a robot meets the same sets again."""
        key = tuple(near)
        found = self._near_edges.get(key)
        if found is None:
            if len(self._near_edges) >= NEAR_CACHE_LIMIT:
                self._near_edges.clear()
            rows = np.concatenate([np.arange(*self._rows[k]) for k in near])
            a = self._a[rows]
            found = self._near_edges[key] = (a, self._b[rows] - a, self._owner[rows])
        return found

    def obstacles_crossed(self, p: tuple[float, float], q: tuple[float, float]) -> int:
        """How many distinct obstacles the segment p-q passes through (0 = line of sight).
        Only obstacles whose box meets the segment's box can be crossed: the edge test runs on
        those (per radio reception, most of a house's obstacles are out of the way), in plain
        floats (a few edges: numpy's per-call cost would be most of the time), each operation
        as the vectorised test over all edges does it."""
        px, py, qx, qy = float(p[0]), float(p[1]), float(q[0]), float(q[1])
        lo_x, hi_x, lo_y, hi_y = min(px, qx) - 1e-9, max(px, qx) + 1e-9, min(py, qy) - 1e-9, max(py, qy) + 1e-9
        crossed = 0
        dx, dy = qx - px, qy - py
        for k, (x0, y0, x1, y1) in enumerate(self._boxes):
            if not (x0 <= hi_x and lo_x <= x1 and y0 <= hi_y and lo_y <= y1):
                continue
            for ax, ay, ex, ey, _ in self._obstacle_edges[k]:
                denom = dx * ey - dy * ex
                if not abs(denom) > 1e-12:
                    continue
                wx, wy = ax - px, ay - py
                t = (wx * ey - wy * ex) / denom
                u = (wx * dy - wy * dx) / denom
                if 0 <= t <= 1 and 0 <= u <= 1:
                    crossed += 1
                    break
        return crossed

    def cast(self, origin: tuple[float, float], angles: np.ndarray, max_range: float) -> np.ndarray:
        """Range along each world angle to the nearest obstacle edge; inf beyond ``max_range``.
        Edges whose box lies farther than ``max_range`` cannot give a range (a hit is on the
        edge, at least that far), so only the others are tested: the same minimum."""
        if not len(self._a):
            return np.full(len(angles), np.inf)
        o = np.asarray(origin, float)
        lo, hi = self._edge_box
        gap = np.maximum(np.maximum(lo - o, o - hi), 0.0)
        reach = max_range * (1 + 1e-9) + 1e-6  # margin over rounding: never drops an edge in range
        keep = np.flatnonzero(gap[:, 0] ** 2 + gap[:, 1] ** 2 <= reach * reach)
        if not len(keep):
            return np.full(len(angles), np.inf)
        a, b = self._a[keep], self._b[keep]
        e0, e1 = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]  # (m,): each edge's direction
        w0, w1 = a[:, 0] - o[0], a[:, 1] - o[1]
        dc, ds = np.cos(angles)[:, None], np.sin(angles)[:, None]  # (n,1): each beam's
        denom = dc * e1 - ds * e0  # (n,m)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w0 * e1 - w1 * e0) / denom
            u = w0 * ds
            u -= w1 * dc
            u /= denom
        valid = np.abs(denom) > 1e-12
        valid &= t > 0
        valid &= u >= 0
        valid &= u <= 1
        t = np.where(valid, t, np.inf).min(axis=1)
        return np.where(t <= max_range, t, np.inf)

    def collides(self, x: float, y: float, radius: float) -> bool:
        """Whether a disc of ``radius`` at (x, y) touches an obstacle. Only obstacles whose box,
        grown by ``radius``, holds the centre can (this runs every step: most steps meet none).
        The distances are computed in plain floats, as the vectorised test
        (:meth:`_collides_exact`) does them; a distance within rounding of ``radius`` is left to
        that test, so the answer is always its answer."""
        if self._grown is None or self._grown[0] != radius:
            self._grown = (radius, [(x0 - radius, x1 + radius, y0 - radius, y1 + radius, k)
                                    for k, (x0, y0, x1, y1) in enumerate(self._boxes)])
        near = [k for x0, x1, y0, y1, k in self._grown[1] if x0 <= x <= x1 and y0 <= y <= y1]
        if not near:
            return False
        if any(self.obstacles[k].contains(x, y) for k in near):
            return True
        hypot = math.hypot
        for k in near:
            for ax, ay, ex, ey, ee in self._obstacle_edges[k]:
                s = ((x - ax) * ex + (y - ay) * ey) / ee
                s = 0.0 if s < 0 else 1.0 if s > 1 else s
                gap = hypot(ax + s * ex - x, ay + s * ey - y) - radius
                if abs(gap) <= 1e-9 * (1 + radius):
                    return self._collides_exact(x, y, radius, near)
                if gap < 0:
                    return True
        return False

    def _collides_exact(self, x: float, y: float, radius: float, near: list[int]) -> bool:
        """The vectorised edge-distance test of :meth:`collides`, for the distances at ``radius``."""
        a, e, _ = self._edges_of(near)
        p = np.array([x, y])
        s = np.clip(np.einsum("ij,ij->i", p - a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-12), 0, 1)
        nearest = a + s[:, None] * e
        return bool(np.min(np.hypot(*(nearest - p).T)) < radius)


def _edge(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float, float, float, float]:
    ex, ey = float(b[0]) - float(a[0]), float(b[1]) - float(a[1])
    return float(a[0]), float(a[1]), ex, ey, max(ex * ex + ey * ey, 1e-12)


NEAR_CACHE_LIMIT = 4096
"""Sets of nearby obstacles whose edge rows are kept (bounded; a world meets few)."""
