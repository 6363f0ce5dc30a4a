"""Path planners on the house's own grids: time per plan, path cost, and whether the event loop
keeps running while a plan is computed in a worker thread.

    python bench/planner_bench.py [--seed 1] [--json]

One S0 homing in the four-room house (s0-house, in lockstep in this process) records the cost
grid, start and goal of every plan its loop asks for; each candidate then plans on each of them:

- ``tcod`` -- host/homing/planner.py's TcodPlanner as the loop runs it (libtcod A*, octile,
  then the straightening pass);
- ``tcod-raw`` -- libtcod's octile A* alone; ``tcod-heading`` -- libtcod on a 4 x n x n graph of
  cells and headings, the old search's exact cost model (4-connected, a turn costs 4);
- ``mcp`` -- scikit-image's ``graph.MCP_Geometric`` (8-connected); ``pyastar2d`` (8-connected);
  those two only if installed (they are not rfhoming's dependencies);
- ``python`` -- the pure-Python 4-connected A* with a turn cost that the loop used to run on its
  event loop, kept here for the comparison.

``gil_gap_ms``: the longest gap between the beats of a 1 ms heartbeat in the main thread while a
worker thread plans the slowest grid over and over for about a second; a planner that holds the
GIL stalls the heartbeat (and the homing loop) for a whole plan.
"""

from __future__ import annotations

import argparse
import asyncio
import heapq
import json
import math
import statistics
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import tcod.path

from rfhoming.campaigns.closed_loop import PipePort
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import Device, Homing
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.planner import TcodPlanner

Cell = tuple[int, int]
MOVES = ((1, 0), (0, 1), (-1, 0), (0, -1))
TURN = 4


class Recorder:
    """The loop's planner, keeping every grid it is asked to plan on."""

    def __init__(self) -> None:
        self.asked: list[tuple[np.ndarray, Cell, Cell]] = []

    def __call__(self, costs: np.ndarray, start: Cell, goal: Cell) -> list[Cell] | None:
        self.asked.append((costs.copy(), start, goal))
        return TcodPlanner()(costs, start, goal)


async def record(seed: int) -> list[tuple[np.ndarray, Cell, Cell]]:
    em = Emulator(load("s0-house", seed=seed), transport="pipe", seed=seed, lockstep=True, lockstep_timeout=60.0)
    await em.start()
    world = asyncio.create_task(em.run())
    recorder = Recorder()
    base, aoa = (PipePort(name, em.device(name).link.host) for name in ("base", "aoa"))
    try:
        await assembly.run(Homing("aoa", [Device("base", port=base), Device("aoa", port=aoa)], Config().for_lockstep(),
                                  planner=recorder))
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    return recorder.asked


def python_astar(cost: np.ndarray, s: Cell, g: Cell) -> list[Cell] | None:
    """The old planner: 4-connected A*, Manhattan heuristic x 5, TURN per change of direction."""
    n = cost.shape[0]
    open_: list[tuple[float, float, Cell, int]] = [(0.0, 0.0, s, -1)]
    best = {(s, -1): 0.0}
    parent: dict[tuple[Cell, int], tuple[Cell, int]] = {}
    while open_:
        _, g_cost, cell, heading = heapq.heappop(open_)
        if cell == g:
            path, key = [cell], (cell, heading)
            while key in parent:
                key = parent[key]
                path.append(key[0])
            return path[::-1]
        if g_cost > best.get((cell, heading), math.inf):
            continue
        for d, (dx, dy) in enumerate(MOVES):
            nx, ny = cell[0] + dx, cell[1] + dy
            if 0 <= nx < n and 0 <= ny < n:
                new = g_cost + cost[nx, ny] + (TURN if heading not in (-1, d) else 0.0)
                if new < best.get(((nx, ny), d), math.inf):
                    best[((nx, ny), d)] = new
                    parent[((nx, ny), d)] = (cell, heading)
                    heapq.heappush(open_, (new + 5 * (abs(g[0] - nx) + abs(g[1] - ny)), new, (nx, ny), d))
    return None


def tcod_raw(cost: np.ndarray, s: Cell, g: Cell) -> list[Cell] | None:
    c = cost.astype(np.int32)
    finder = tcod.path.Pathfinder(tcod.path.SimpleGraph(cost=c, cardinal=2, diagonal=3, greed=int(c.min())))
    finder.add_root(s)
    return [tuple(p) for p in finder.path_to(g).tolist()]


def tcod_heading(cost: np.ndarray, s: Cell, g: Cell) -> list[Cell] | None:
    n, c = cost.shape[0], cost.astype(np.int32)
    graph = tcod.path.CustomGraph((4, n, n))
    for h in range(4):
        layer = np.zeros((4, n, n), np.int8)
        layer[h] = 1
        for d, (dx, dy) in enumerate(MOVES):
            graph.add_edge((d - h, dx, dy), 1, cost=np.broadcast_to(c + (0 if d == h else TURN), (4, n, n)).copy(),
                           condition=layer)
    graph.set_heuristic(cardinal=5, diagonal=10, z=0)
    finder = tcod.path.Pathfinder(graph)
    for h in range(4):
        finder.add_root((h, *s))
    for h in range(4):
        finder.resolve((h, *g))
    best = int(np.argmin(finder.distance[:, g[0], g[1]]))
    return [tuple(p[1:]) for p in finder.path_to((best, *g)).tolist()]


def candidates() -> dict[str, Callable[[np.ndarray, Cell, Cell], Any]]:
    out: dict[str, Callable[[np.ndarray, Cell, Cell], Any]] = {
        "tcod": TcodPlanner(), "tcod-raw": tcod_raw, "tcod-heading": tcod_heading}
    try:
        from skimage.graph import MCP_Geometric

        def mcp(cost: np.ndarray, s: Cell, g: Cell) -> Any:
            m = MCP_Geometric(cost)
            m.find_costs([s], [g])
            return m.traceback(g)
        out["mcp"] = mcp
    except ImportError:
        pass
    try:
        import pyastar2d

        out["pyastar2d"] = lambda cost, s, g: pyastar2d.astar_path(cost.astype(np.float32), s, g, allow_diagonal=True)
    except ImportError:
        pass
    out["python"] = python_astar
    return out


def length_m(path: Any, resolution: float = 0.15) -> float:
    p = np.asarray(path, float)
    return float(np.hypot(*np.diff(p, axis=0).T).sum() * resolution) if len(p) > 1 else 0.0


def gil_gap_ms(plan: Callable[..., Any], grid: tuple[np.ndarray, Cell, Cell], seconds: float = 1.0) -> float:
    done = threading.Event()

    def work() -> None:
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            plan(*grid)
        done.set()

    worker = threading.Thread(target=work)
    worst, last = 0.0, time.perf_counter()
    worker.start()
    while not done.is_set():
        time.sleep(0.001)
        now = time.perf_counter()
        worst, last = max(worst, now - last), now
    worker.join()
    return round(worst * 1000, 1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    grids = asyncio.run(record(args.seed))
    result: dict[str, Any] = {"scenario": "s0-house", "seed": args.seed, "plans": len(grids), "planners": {}}
    for name, plan in candidates().items():
        times, lengths = [], []
        for grid in grids:
            t0 = time.perf_counter()
            path = plan(*grid)
            times.append(time.perf_counter() - t0)
            lengths.append(length_m(path))
        slowest = grids[int(np.argmax(times))]
        result["planners"][name] = {
            "ms_median": round(1000 * statistics.median(times), 1), "ms_max": round(1000 * max(times), 1),
            "path_m_mean": round(statistics.mean(lengths), 2), "gil_gap_ms": gil_gap_ms(plan, slowest)}
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"s0-house seed {args.seed}: {len(grids)} plans")
    for name, r in result["planners"].items():
        print(f"  {name:<13} median {r['ms_median']:7.1f} ms  max {r['ms_max']:7.1f} ms  path {r['path_m_mean']:5.2f} m  "
              f"heartbeat gap beside it {r['gil_gap_ms']:6.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
