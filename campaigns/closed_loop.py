"""One closed-loop homing run: the emulator and the real host stack in one process, joined by
the emulator's byte pipe, stepped in lockstep (deterministic per seed, ~100x real time)."""

from __future__ import annotations

import asyncio
import json
import math
import time
from dataclasses import dataclass
from typing import Any

from rfhoming.emulator import arrival
from rfhoming.emulator.links import PipeEnd, pipe_end
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import Scenario
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import SENSORS, Device, Homing
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import Outcome, RunLog
from rfhoming.host.ports import Chunk, Tap
from rfhoming.protocol import devices


class PipePort:
    """A HostPort-shaped view of one end of the emulator's in-process pipe."""

    def __init__(self, name: str, end: PipeEnd) -> None:
        self.name = self.spec = name
        self.end = end
        self.baud = 115200
        self.taps: list[Tap] = []
        self.counters = {"bytes_in": 0, "bytes_out": 0, "chunks_in": 0, "opens": 0, "disconnects": 0, "dropped_bytes": 0}

    async def open(self) -> None:
        self.counters["opens"] += 1

    def set_baud(self, baud: int) -> None:
        self.baud = baud

    async def read(self) -> Chunk:
        data = await self.end.read()
        self.counters["bytes_in"] += len(data)
        chunk = Chunk(time.time(), data)
        for tap in self.taps:  # a capture hears it, as on a HostPort
            tap(self.name, "in", chunk.t, data)
        return chunk

    def write(self, data: bytes) -> None:
        self.counters["bytes_out"] += len(data)
        for tap in self.taps:
            tap(self.name, "out", time.time(), data)
        self.end.write(data)

    async def close(self) -> None:
        pass


class Trajectory:
    """The emulator's truth stream, kept in memory: the robot's true path for the metrics."""

    def __init__(self) -> None:
        self.points: list[tuple[float, float, float, float]] = []  # t, x, y, theta

    def write(self, line: str) -> None:
        record = json.loads(line)
        if "robot" in record:
            r = record["robot"]
            self.points.append((record["t"], r["x"], r["y"], r["theta"]))

    def flush(self) -> None:
        pass

    @property
    def length_m(self) -> float:
        return sum(math.dist(a[1:3], b[1:3]) for a, b in zip(self.points, self.points[1:]))


@dataclass
class Run:
    outcome: Outcome
    trajectory: Trajectory
    emulator: Emulator
    wall_s: float

    @property
    def robot(self) -> tuple[float, float, float]:
        r = self.emulator.world.robot
        return r.x, r.y, r.theta


def plan(scenario: Scenario, em: Emulator, config: Config, runlog: RunLog | None = None) -> Homing:
    """The homing run a scenario's devices call for, on the emulator's pipes."""
    def port(name: str) -> PipePort:
        return PipePort(name, pipe_end(em.device(name).link))

    names = {d.name: d.type for d in scenario.devices}
    sensor = next((name for name in SENSORS if name in names), None)
    if sensor is None:
        raise ValueError(f"scenario {scenario.name} has no device a homing loop can use: {sorted(names)}")
    controller, role = SENSORS[sensor]
    kind = devices.BOARDS[names[sensor]][0].name
    return Homing(controller, [Device("base", port=port("base")), Device(role, port=port(sensor), kind=kind)],
                  config, runlog=runlog)


async def _run(scenario: Scenario, config: Config, seed: int, timeout_s: float, runlog: RunLog | None) -> Run:
    trajectory = Trajectory()
    em = Emulator(scenario, transport="pipe", seed=seed, lockstep=True, lockstep_timeout=2.0, truth=trajectory)  # type: ignore[arg-type]
    await em.start()
    world = asyncio.create_task(em.run())
    wall0 = time.perf_counter()
    try:
        outcome = await asyncio.wait_for(assembly.run(plan(scenario, em, config, runlog)), timeout_s)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    em.write_truth()  # the final pose
    return Run(outcome, trajectory, em, time.perf_counter() - wall0)


ARRIVED_M = 1.0
"""A run succeeds with the robot this near the target and in its line of sight (S0's metric)."""


def run(scenario: Scenario, config: Config, seed: int, timeout_s: float = 600.0, runlog: RunLog | None = None) -> Run:
    """Run one homing to its end (arrival or the config's time limit).

    In lockstep wall time means nothing (the world waits for the host), so the loop's wall-clock
    check on the base is switched off: a loaded machine must not change a run's result."""
    return asyncio.run(_run(scenario, config.for_lockstep(), seed, timeout_s, runlog))


def metrics(run_: Run, target: tuple[float, float]) -> dict[str, Any]:
    """S0 Table 3's metrics of one run against the true ``target``."""
    start = run_.trajectory.points[0]
    x, y, _ = run_.robot
    straight = math.dist(start[1:3], (x, y))
    travelled = run_.trajectory.length_m
    final = math.dist((x, y), target)
    goal = run_.outcome.goal
    t = run_.outcome.robot_time_s
    seen = arrival.arrived((x, y), target, ARRIVED_M, [o.polygon for o in run_.emulator.world.obstacles])
    return {"arrived": run_.outcome.arrived, "success": run_.outcome.arrived and seen,
            "time_s": round(t, 3), "net_velocity_mps": round(straight / t, 4) if t > 0 else None,
            "goal_error_m": None if goal is None else round(math.dist(goal, target), 4),
            "final_error_m": round(final, 4),
            "path_efficiency": round(straight / travelled, 4) if travelled > 0 else None,
            "wall_s": round(run_.wall_s, 3)}
