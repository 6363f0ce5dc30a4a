"""Path planning off the event loop, applied on robot time.

:class:`TcodPlanner` searches the occupancy grid's cost array with libtcod's A* (``tcod.path``,
compiled, and it releases the GIL while it searches), 8-connected with octile step costs: a
straight step costs 2 x the cell's cost, a diagonal 3 x. Diagonal steps take the place of the old
4-connected search's turn penalty: runs come out straight or diagonal instead of staircases
(docs/architecture.md says why this library and how it was measured).

:class:`PlanScheduler` runs each plan in one worker thread and hands the result to the loop at a
fixed robot time, ``latency_s`` after the request, whatever the wall clock did: so a run on the
emulator's lockstep, in-process or replayed makes the same decisions however slow the machine.
There (``wait``) the loop waits for a plan that is not done by its robot time; a live run does not
wait: it keeps controlling on the old path and counts the plan as late.
"""

from __future__ import annotations

import concurrent.futures
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import tcod.path

Cell = tuple[int, int]


class Planner(Protocol):
    """Cells from ``start`` to ``goal`` over a cost grid (each cell's cost of entering it, > 0),
    or None. Called in a worker thread: it must not touch the loop's state."""

    def __call__(self, costs: np.ndarray, start: Cell, goal: Cell) -> list[Cell] | None: ...


class TcodPlanner:
    """A* on libtcod: 8-connected, octile steps, the grid's cheapest cell cost as the heuristic's
    unit (admissible: the path is a cheapest one)."""

    CARDINAL, DIAGONAL = 2, 3

    def __call__(self, costs: np.ndarray, start: Cell, goal: Cell) -> list[Cell] | None:
        cost = np.ascontiguousarray(costs, dtype=np.int32)
        graph = tcod.path.SimpleGraph(cost=cost, cardinal=self.CARDINAL, diagonal=self.DIAGONAL,
                                      greed=max(1, int(cost.min())))
        finder = tcod.path.Pathfinder(graph)
        finder.add_root(start)
        path = finder.path_to(goal)
        if len(path) == 0 or tuple(path[-1]) != goal:
            return None
        return [(int(x), int(y)) for x, y in straighten(cost, path)]


def straighten(cost: np.ndarray, path: np.ndarray) -> np.ndarray:
    """The path with its zigzags pulled straight: from each corner, the farthest later cell that
    a straight line reaches at no more cost than the stretch of path it replaces (cost summed
    along each, per cell length), so a shortcut never cuts a corner the search went round;
    then cell by cell along it. This is what the old search's turn penalty was for: a robot
    steering at a point ahead on a staircase path wobbles."""
    n = len(path)
    step = np.hypot(*np.diff(path, axis=0).T)  # 1 or sqrt(2) cells
    along_path = np.concatenate(([0.0], np.cumsum(cost[path[1:, 0], path[1:, 1]] * step)))
    out = [path[0]]
    i = 0
    while i < n - 1:
        ends = path[i + 2:]
        if len(ends) == 0:
            out.append(path[i + 1])
            break
        samples = int(2 * np.abs(ends - path[i]).max()) + 1  # half-cell samples along the longest line
        frac = (np.arange(samples) + 0.5)[None, :, None] / samples
        at = np.rint(path[i] + frac * (ends - path[i])[:, None, :]).astype(np.intp)
        length = np.hypot(*(ends - path[i]).T)
        line = cost[at[..., 0], at[..., 1]].mean(axis=1) * length
        allowed = line <= along_path[i + 2:] - along_path[i] + 1e-9
        j = i + 1 if not allowed.any() else i + 2 + int(np.flatnonzero(allowed)[-1])
        out.extend(_cells_between(path[i], path[j]))
        i = j
    return np.array(out)


def _cells_between(a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """The cells of the line a -> b, a excluded, b included, one per step of the longer axis."""
    k = int(np.abs(b - a).max())
    return [np.rint(a + (b - a) * s / k).astype(np.intp) for s in range(1, k + 1)]


@dataclass
class Request:
    """A plan asked for at robot time ``t``, to take effect at ``due`` (robot time)."""

    t: float
    due: float
    goal: tuple[float, float]
    map_version: int
    future: concurrent.futures.Future[list[Cell] | None]
    taken_at: float | None = None  # a replay: when the live run took it (it was late then; inf: never)
    late: bool = False

    def ready(self, t: float) -> bool:
        """Whether the plan may be taken at robot time ``t`` (its due time has come)."""
        if self.taken_at is not None:  # the live run's own rounding, as the run log and the note
            return round(t, 4) >= self.taken_at
        return self.future.done()


class PlanScheduler:
    """At most one plan in flight, computed in a worker thread, taken at its robot time."""

    def __init__(self, planner: Planner, latency_s: float, wait: bool, taken: dict[float, float] | None = None) -> None:
        """``taken``: when each plan of a live run took effect, by the robot time it was asked
        for (rounded to 0.1 ms, as the run log): a replay takes a plan that was late then."""
        self.planner, self.latency_s, self.wait = planner, latency_s, wait
        self.taken = taken or {}
        self.pending: Request | None = None
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None

    def request(self, t: float, costs: np.ndarray, start: Cell, goal_cell: Cell, goal: tuple[float, float],
                map_version: int) -> None:
        if self._pool is None:
            self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="planner")
        future = self._pool.submit(self.planner, costs, start, goal_cell)
        self.pending = Request(t, t + self.latency_s, goal, map_version, future, self.taken.get(round(t, 4)))

    def due(self, t: float) -> Request | None:
        """The pending plan if its robot time has come (done or not)."""
        request = self.pending
        return request if request is not None and t + 1e-9 >= request.due else None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
