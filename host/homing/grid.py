"""Occupancy grid from range scans, and the costs a path is planned on (S2's full system; also S0 in a house).

Grid: cells of ``resolution`` m around the start, each unknown, free or occupied. A scan marks
the cells along each beam free and the cell it ends in occupied (hit counts beat miss counts,
so a wall seen once is not erased by one grazing beam).

Costs (S2): occupied 100, free 1, unknown 2; occupied cells are first grown by the robot's
radius (a 0.25 m robot cannot use a cell beside a wall), then each cell's cost is summed with
its four neighbours' (S2's inflation). Paths: host/homing/planner.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfhoming.host.drivers.robot import Scan
from rfhoming.host.homing.planner import Planner, TcodPlanner
from rfhoming.host.homing.schema import M, setting
from rfhoming.host.homing.types import Pose

UNKNOWN_COST, FREE_COST, OCCUPIED_COST = 2, 1, 100


@dataclass(frozen=True)
class GridParams:
    resolution: float = setting(0.15, low=0.01, high=1, unit=M)
    size_m: float = setting(40.0, low=0, above=True, high=10000, unit=M)
    robot_radius: float = setting(0.3, low=0, high=5, unit=M)
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
        key = xs * n + ys
        # a straight beam crosses each cell in one run of samples: a sample in another cell than
        # the one before it is a new cell (no sort, where np.unique took a fifth of a house run)
        new = np.ones(key.shape, bool)
        new[:, 1:] = key[:, 1:] != key[:, :-1]
        _count(self.misses, key[along & new], 1)
        hit = np.isfinite(ranges) & (ranges <= p.max_range)
        if hit.any():
            hx = np.clip(((pose.x + ranges[hit] * cos[hit, 0] - self.x0) / r).astype(int), 0, n - 1)
            hy = np.clip(((pose.y + ranges[hit] * sin[hit, 0] - self.y0) / r).astype(int), 0, n - 1)
            _count(self.hits, hx * n + hy, 3)

    def occupied(self) -> np.ndarray:
        return self.hits > self.misses

    def known(self) -> np.ndarray:
        return (self.hits + self.misses) > 0

    def blocked(self, cells: list[tuple[int, int]]) -> np.ndarray:
        """Whether each cell is within the robot's radius of an occupied one (the costs' grown
        obstacles), looked up around those cells alone: cheap enough after every scan."""
        grow = int(math.ceil(self.params.robot_radius / self.params.resolution))
        offsets = np.array([(dx, dy) for dx in range(-grow, grow + 1) for dy in range(-grow, grow + 1)
                            if dx * dx + dy * dy <= grow * grow])
        at = np.asarray(cells, dtype=np.intp).reshape(-1, 1, 2) + offsets[None, :, :]
        xs, ys = at[..., 0] % self.n, at[..., 1] % self.n  # wrapped, as the costs' np.roll grows them
        return np.asarray((self.hits[xs, ys] > self.misses[xs, ys]).any(axis=1))

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

    def plan(self, start: tuple[float, float], goal: tuple[float, float], planner: Planner | None = None
             ) -> list[tuple[float, float]] | None:
        """A path from start to goal (world coordinates) as cell centres, or None; here and now
        (the homing loop plans in a worker thread instead: host/homing/planner.py)."""
        cells = (planner or TcodPlanner())(self.costs(), self.cell(*start), self.cell(*goal))
        return None if cells is None else [self.centre(c) for c in cells]


def _count(counts: np.ndarray, cells: np.ndarray, weight: int) -> None:
    """Add ``weight`` to ``counts`` (a grid, by flat index) once per entry of ``cells``, counted
    over the span of indices a scan touched alone: a whole-grid bincount per scan (or
    ``np.add.at``) was most of a scan's integration."""
    if not len(cells):
        return
    lo = int(cells.min())
    span = counts.reshape(-1)[lo:]
    per = np.bincount(cells - lo)
    span[: len(per)] += (weight * per).astype(counts.dtype)


def lookahead(path: list[tuple[float, float]], pose: Pose, distance: float = 1.0,
              goal: tuple[float, float] | None = None) -> tuple[float, float]:
    """The first path point at least ``distance`` from the robot after the point nearest it
    (the last one if none is): a plan made a moment ago starts behind the robot. With ``goal``,
    the path's end is the goal as it is now: an estimate moves on after the plan, by less than
    a re-plan takes, and the last stretch should follow it."""
    i = _ahead(path, pose, distance)
    return goal if goal is not None and i == len(path) - 1 else path[i]


def _ahead(path: list[tuple[float, float]], pose: Pose, distance: float) -> int:
    d = np.hypot(np.array([p[0] for p in path]) - pose.x, np.array([p[1] for p in path]) - pose.y)
    nearest = int(np.argmin(d))
    beyond = np.flatnonzero(d[nearest:] >= distance)
    return nearest + int(beyond[0]) if len(beyond) else len(path) - 1
