"""What "arrived" means when the emulator or a campaign judges a run: what a user means.

A run succeeds when the robot stands within the arrival distance of the tag AND sees it: no
wall or piece of furniture between the robot's centre and the tag. A robot 0.5 m from a tag on
the other side of a wall has not found it (a user would have to walk round through the next
doorway). The host is never told any of this: it decides by itself that it has arrived; the
emulator and the campaigns check that claim against the simulator's truth here.

Random targets keep ``TARGET_CLEARANCE_M`` from every obstacle, so a robot of the scenarios'
radius can stand beside one in its line of sight: a tag 7 cm from a wall is reachable only
through the wall's far side, if at all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Point = tuple[float, float]
Polygon = Sequence[Sequence[float]]

TARGET_CLEARANCE_M = 0.7
"""Free space around a random target: a robot (radius 0.25 m) can stand beside it, in sight."""


def _edges(polygon: Polygon) -> list[tuple[Point, Point]]:
    points = [(float(p[0]), float(p[1])) for p in polygon]
    return list(zip(points, points[1:] + points[:1]))


def _segments_cross(p: Point, q: Point, a: Point, b: Point) -> bool:
    """Whether the segments p-q and a-b meet (touching counts)."""
    dx, dy = q[0] - p[0], q[1] - p[1]
    ex, ey = b[0] - a[0], b[1] - a[1]
    denom = dx * ey - dy * ex
    wx, wy = a[0] - p[0], a[1] - p[1]
    if abs(denom) <= 1e-12:  # parallel: they meet only if collinear and overlapping
        if abs(wx * dy - wy * dx) > 1e-12:
            return False
        length = dx * dx + dy * dy
        if length <= 1e-24:
            return math.dist(p, a) <= 1e-9 or math.dist(p, b) <= 1e-9
        s0 = (wx * dx + wy * dy) / length
        s1 = ((b[0] - p[0]) * dx + (b[1] - p[1]) * dy) / length
        return max(s0, s1) >= 0 and min(s0, s1) <= 1
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    return 0 <= t <= 1 and 0 <= u <= 1


def inside(point: Point, polygon: Polygon) -> bool:
    """Whether ``point`` lies inside ``polygon`` (even-odd rule)."""
    x, y = point
    result = False
    for (x1, y1), (x2, y2) in _edges(polygon):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            result = not result
    return result


def line_of_sight(p: Point, q: Point, obstacles: Sequence[Polygon]) -> bool:
    """Whether the straight line from ``p`` to ``q`` passes no obstacle (an end inside one
    is blocked too)."""
    for polygon in obstacles:
        if inside(p, polygon) or inside(q, polygon):
            return False
        if any(_segments_cross(p, q, a, b) for a, b in _edges(polygon)):
            return False
    return True


def clearance(point: Point, obstacles: Sequence[Polygon]) -> float:
    """The distance from ``point`` to the nearest obstacle (0 inside one; inf with none)."""
    best = math.inf
    for polygon in obstacles:
        if inside(point, polygon):
            return 0.0
        for a, b in _edges(polygon):
            ex, ey = b[0] - a[0], b[1] - a[1]
            ee = max(ex * ex + ey * ey, 1e-24)
            s = min(1.0, max(0.0, ((point[0] - a[0]) * ex + (point[1] - a[1]) * ey) / ee))
            best = min(best, math.hypot(a[0] + s * ex - point[0], a[1] + s * ey - point[1]))
    return best


def arrived(robot: Point, target: Point, within_m: float, obstacles: Sequence[Polygon]) -> bool:
    """A user's "arrived": the robot's centre within ``within_m`` of the target, and in its line
    of sight."""
    return math.dist(robot, target) < within_m and line_of_sight(robot, target, obstacles)
