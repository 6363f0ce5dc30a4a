"""Occupancy grid from range scans, and A* on it (S2's full system; also S0 in a house).

Grid: cells of ``resolution`` m around the start, each unknown, free or occupied. A scan marks
the cells along each beam free and the cell it ends in occupied (hit counts beat miss counts,
so a wall seen once is not erased by one grazing beam).

Costs (S2): occupied 100, free 1, unknown 2; occupied cells are first grown by the robot's
radius (a 0.25 m robot cannot use a cell beside a wall), then each cell's cost is summed with
its four neighbours' (S2's inflation). A*: 4-connected, Manhattan heuristic, plus
``turn_cost`` per 90° change of direction, so plans prefer straight runs.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from rfhoming.host.drivers.robot_base import Scan
from rfhoming.host.homing.schema import M, setting
from rfhoming.host.homing.types import Pose

UNKNOWN_COST, FREE_COST, OCCUPIED_COST = 2, 1, 100
MOVES = ((1, 0), (0, 1), (-1, 0), (0, -1))


@dataclass(frozen=True)
class GridParams:
    resolution: float = setting(0.15, low=0.01, high=1, unit=M)
    size_m: float = setting(40.0, low=0, above=True, high=10000, unit=M)
    robot_radius: float = setting(0.3, low=0, high=5, unit=M)
    turn_cost: float = setting(4.0, low=0, high=1000, unit="(cost of a turn, in cells)")
    max_range: float = setting(7.5, low=0, above=True, high=100, unit=M)  # beams beyond this mark free space only


class OccupancyGrid:
    def __init__(self, origin: tuple[float, float], params: GridParams = GridParams()) -> None:
        self.params = params
        n = int(params.size_m / params.resolution)
        self.n = n
        self.x0 = origin[0] - params.size_m / 2
        self.y0 = origin[1] - params.size_m / 2
        self.hits = np.zeros((n, n), np.int32)
        self.misses = np.zeros((n, n), np.int32)

    def cell(self, x: float, y: float) -> tuple[int, int]:
        r = self.params.resolution
        return (min(max(int((x - self.x0) / r), 0), self.n - 1), min(max(int((y - self.y0) / r), 0), self.n - 1))

    def centre(self, cell: tuple[int, int]) -> tuple[float, float]:
        r = self.params.resolution
        return self.x0 + (cell[0] + 0.5) * r, self.y0 + (cell[1] + 0.5) * r

    def integrate(self, pose: Pose, scan: Scan) -> None:
        """One scan taken at ``pose``: beams free the cells they cross (once per beam), returns
        mark hits. All beams at once: a beam-by-beam loop was a tenth of a run's time."""
        p, r, n = self.params, self.params.resolution, self.n
        ranges = np.array([np.inf if d is None else d for d in scan.ranges])
        angles = pose.theta + scan.angle_min + scan.angle_increment * np.arange(len(ranges))
        cos = np.array([math.cos(a) for a in angles])[:, None]  # libm, as a scalar loop would
        sin = np.array([math.sin(a) for a in angles])[:, None]
        reach = np.minimum(ranges, p.max_range)
        steps = np.arange(0, reach.max() + 1e-9, r / 2)[None, :]
        xs = ((pose.x + steps * cos - self.x0) / r).astype(int)
        ys = ((pose.y + steps * sin - self.y0) / r).astype(int)
        along = (steps < reach[:, None] - r / 2) & (xs >= 0) & (xs < n) & (ys >= 0) & (ys < n)
        beam = np.broadcast_to(np.arange(len(ranges))[:, None], xs.shape)
        crossed = np.unique(beam[along] * (n * n) + xs[along] * n + ys[along]) % (n * n)
        self.misses += np.bincount(crossed, minlength=n * n).reshape(n, n).astype(np.int32)
        hit = np.isfinite(ranges) & (ranges <= p.max_range)
        if hit.any():
            hx = np.clip(((pose.x + ranges[hit] * cos[hit, 0] - self.x0) / r).astype(int), 0, n - 1)
            hy = np.clip(((pose.y + ranges[hit] * sin[hit, 0] - self.y0) / r).astype(int), 0, n - 1)
            self.hits += 3 * np.bincount(hx * n + hy, minlength=n * n).reshape(n, n).astype(np.int32)

    def occupied(self) -> np.ndarray:
        return self.hits > self.misses

    def known(self) -> np.ndarray:
        return (self.hits + self.misses) > 0

    def costs(self) -> np.ndarray:
        occ = self.occupied()
        grow = int(math.ceil(self.params.robot_radius / self.params.resolution))
        grown = occ.copy()
        for dx in range(-grow, grow + 1):
            for dy in range(-grow, grow + 1):
                if dx * dx + dy * dy <= grow * grow:
                    grown |= np.roll(np.roll(occ, dx, axis=0), dy, axis=1)
        base = np.where(grown, OCCUPIED_COST, np.where(self.known(), FREE_COST, UNKNOWN_COST)).astype(np.float64)
        summed = base.copy()
        for axis in (0, 1):
            for shift in (1, -1):
                summed += np.roll(base, shift, axis=axis)
        return summed

    def plan(self, start: tuple[float, float], goal: tuple[float, float], max_expansions: int = 200_000
             ) -> list[tuple[float, float]] | None:
        """A* from start to goal (world coordinates); the path as cell centres, or None."""
        cost = self.costs()
        s, g = self.cell(*start), self.cell(*goal)
        turn = self.params.turn_cost
        open_: list[tuple[float, float, tuple[int, int], int]] = [(0.0, 0.0, s, -1)]
        best = {(s, -1): 0.0}
        parent: dict[tuple[tuple[int, int], int], tuple[tuple[int, int], int]] = {}
        expansions = 0
        while open_ and expansions < max_expansions:
            _, g_cost, cell, heading = heapq.heappop(open_)
            if cell == g:
                path, key = [cell], (cell, heading)
                while key in parent:
                    key = parent[key]
                    path.append(key[0])
                return [self.centre(c) for c in reversed(path)]
            if g_cost > best.get((cell, heading), math.inf):
                continue
            expansions += 1
            for d, (dx, dy) in enumerate(MOVES):
                nx, ny = cell[0] + dx, cell[1] + dy
                if not (0 <= nx < self.n and 0 <= ny < self.n):
                    continue
                step = cost[nx, ny] + (turn if heading not in (-1, d) else 0.0)
                new = g_cost + step
                key = ((nx, ny), d)
                if new < best.get(key, math.inf):
                    best[key] = new
                    parent[key] = (cell, heading)
                    h = 5 * (abs(g[0] - nx) + abs(g[1] - ny))  # Manhattan × the least summed cell cost
                    heapq.heappush(open_, (new + h, new, (nx, ny), d))
        return None


def lookahead(path: list[tuple[float, float]], pose: Pose, distance: float = 1.0) -> tuple[float, float]:
    """The first path point at least ``distance`` from the robot (the last one if none is)."""
    for point in path:
        if math.hypot(point[0] - pose.x, point[1] - pose.y) >= distance:
            return point
    return path[-1]
