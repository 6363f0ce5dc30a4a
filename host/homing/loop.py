"""The homing loop: devices -> decoders -> filters -> estimator -> controller -> base.

Time is the robot's own: each odometry record carries the base's clock, and every decision,
staleness check and limit is measured on it. So the loop behaves the same at real time and in
the emulator's lockstep (where wall time means nothing). One velocity command goes out per
control period, after the odometry that closes the period.

Fail-safes, each logged:
- a required stream older than ``slow_after_s`` -> the speed falls linearly with its age, to 0 at
  the stale timeout, with the base in brake mode (it sheds speed at its emergency deceleration);
  older than the stale timeout (robot time) -> stop in brake mode, resume when fresh. Together
  they bound the distance driven on stale data (docs/BENCHMARKS.md, bench/stopping_bench.py).
  The timeout is ``stale_timeout_s``, or ``stale_intervals`` times the stream's median interval
  between readings when that is longer: a tag advertising every second (u-connectLocate 2.x
  allows 1000 ms) must not stop the robot between its readings;
- the base itself silent for ``stale_timeout_s`` of wall time -> stop commands (its watchdog
  stops it anyway);
- the base's clock going backwards (an MCU reset restarts ``t_us`` at 0) -> robot time is
  re-anchored to continue from where it was, so no deadline waits for the old clock to return;
- arrival -> stop, done; ``max_time_s`` -> stop, failed;
- any exception or cancellation (Ctrl-C) -> stop (the base driver's context manager).

Run log: JSON lines of every measurement, estimate and command with robot time, and the
byte-in -> command-out latency of every command.
"""

from __future__ import annotations

import asyncio
import json
from collections import deque
import logging
import statistics
import time
from dataclasses import dataclass, field
from collections.abc import Callable
from typing import IO, Any, Protocol

from rfhoming.host.drivers.aoa import AoaDriver, TimedAngle
from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.drivers.base import BaseDriver, Pose2D, Scan
from rfhoming.host.homing.anchors import AnchorsController
from rfhoming.host.homing.avoidance import ObstacleAvoidance
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.grid import OccupancyGrid, lookahead
from rfhoming.host.homing.s0_aoa import S0Homing
from rfhoming.host.homing.s1_dock import DockController
from rfhoming.host.homing.s2_rss import RssController
from rfhoming.host.homing.s3_trilat import TrilatController
from rfhoming.host.homing.types import Decision, Pose
from rfhoming.host.site import Site

log = logging.getLogger(__name__)

ODOMETRY_PERIOD_S = 0.02  # the base's documented 50 Hz odometry: the step assumed across a reset


@dataclass
class Outcome:
    arrived: bool
    reason: str
    robot_time_s: float
    pose: Pose | None
    goal: tuple[float, float] | None
    commands: int
    stale_stops: int
    latency_ms: list[float] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        lat = sorted(self.latency_ms)
        pick = (lambda q: round(lat[min(len(lat) - 1, int(q * len(lat)))], 3)) if lat else (lambda q: None)
        return {"arrived": self.arrived, "reason": self.reason, "robot_time_s": round(self.robot_time_s, 3),
                "pose": None if self.pose is None else [round(v, 4) for v in self.pose],
                "goal": None if self.goal is None else [round(v, 4) for v in self.goal],
                "commands": self.commands, "stale_stops": self.stale_stops,
                "latency_ms_p50": pick(0.5), "latency_ms_p99": pick(0.99)}


class RunLog:
    """JSON lines, one per event, flushed as they come (a killed run keeps its log)."""

    def __init__(self, out: IO[str] | None, listeners: list[Callable[[dict[str, Any]], None]] | None = None) -> None:
        self.out = out
        self.listeners = listeners or []  # each record also goes to these (an MCAP recorder, a live view)

    def write(self, kind: str, t: float, **fields: Any) -> None:
        record = {"kind": kind, "t": round(t, 4), **fields}
        if self.out is not None:
            self.out.write(json.dumps(record) + "\n")
            self.out.flush()
        for listener in self.listeners:
            listener(record)


class Controller(Protocol):
    """What the loop needs of a homing controller."""

    phase: str
    reported: Any  # the goal estimate (x, y) or None

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        """One sensor reading; returns the fields to log, or None if it was not a reading."""

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision: ...

    def estimate(self) -> dict[str, Any]:
        """What to log of the current estimate."""


class AoaController:
    """S0 behind the loop's interface: board azimuth -> θs (mounting), RSSI -> distance."""

    source = "aoa"

    def __init__(self, config: Config) -> None:
        self.config = config
        self.s0 = S0Homing(config.s0)

    @property
    def phase(self) -> str:
        return self.s0.phase

    @property
    def reported(self) -> Any:
        return self.s0.reported

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, TimedAngle):
            return None
        event = item.event
        theta_s = self.config.mounting.to_robot(event.azimuth)
        distance = float(self.config.calibration.model.distance(event.rssi1))
        self.s0.on_reading(t, pose, theta_s, distance)
        return {"azimuth": event.azimuth, "rssi": event.rssi1, "theta_s": round(theta_s, 4), "distance": round(distance, 3)}

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        return self.s0.decide(pose, steer_to)

    def estimate(self) -> dict[str, Any]:
        return {"goal": _round(self.s0.reported), "g_p": _round(self.s0.g_p), "g_v": _round(self.s0.g_v)}


class HomingLoop:
    """The base plus one sensor driver (or several: fixed anchors) and a controller."""

    def __init__(self, base: BaseDriver, sensor: Driver | list[Driver], controller: Controller,
                 config: Config = Config(), runlog: RunLog | None = None) -> None:
        self.sensors = sensor if isinstance(sensor, list) else [sensor]
        sensor = self.sensors[0]
        self.base, self.sensor, self.config = base, sensor, config
        self.controller = controller
        self.source = getattr(controller, "source", sensor.kind)
        self.log = runlog or RunLog(None)
        self.stale_stops = 0
        self.commands = 0
        self.latency_ms: deque[float] = deque(maxlen=10_000)  # bounded: the latest commands
        # one stream for both drivers: the loop sees odometry and readings in arrival order, so
        # its decisions depend on the bytes alone (a replay reproduces them exactly)
        self.inputs = BoundedStream[Any](4000)
        base.odometry = base.scans = self.inputs
        for each in self.sensors:
            for name in ("events", "readings"):
                if hasattr(each, name):
                    setattr(each, name, self.inputs)
        own = getattr(controller, "own_avoidance", False)  # S2's preliminary system has its own rules
        self.avoidance = ObstacleAvoidance(config.avoid) if config.avoid_obstacles and not own else None
        self._planning = config.plan.enabled and getattr(controller, "uses_planner", True)
        self.grid: OccupancyGrid | None = None  # built from the first scan, if the base sends any
        self._path: list[tuple[float, float]] | None = None
        self._next_plan = 0.0
        self._next_integrate = 0.0
        self.plans = 0
        self.intervals: deque[float] = deque(maxlen=20)  # robot-time gaps between readings
        self._braking: bool | None = None  # base brake mode as last sent; None: unknown, send it
        self.clock_resets = 0

    async def run(self) -> Outcome:
        tasks = [asyncio.create_task(self.base.run())] + [asyncio.create_task(s.run()) for s in self.sensors]
        try:
            async with self.base:
                await self.base.connected.wait()
                self.base.stop()  # a known state, and the emulator's lockstep gets its first answer
                return await self._loop()
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _loop(self) -> Outcome:
        cfg = self.config.loop
        last_reading: float | None = None
        next_control: float | None = None
        stale = False
        t0: float | None = None
        pose: Pose | None = None
        t = 0.0
        last_odometry_wall = time.monotonic()
        odometry_stale = False
        clock_offset = 0.0  # robot time = base clock + offset, re-anchored on a base reset
        while True:
            item = self.inputs.get_nowait()  # most items are already here: no timer, no task
            if item is None:
                try:  # asyncio.timeout, not wait_for: no task per item, and a cancellation stays one
                    async with asyncio.timeout(min(cfg.stale_timeout_s, cfg.odometry_wall_timeout_s)):
                        item = await self.inputs.get()
                except TimeoutError:
                    item = None
            if not isinstance(item, Pose2D) and time.monotonic() - last_odometry_wall > cfg.odometry_wall_timeout_s:
                if not odometry_stale:  # the base's own clock is gone: wall time is all there is
                    odometry_stale = True
                    log.warning("odometry stale: stopping the robot (its watchdog stops it too)")
                    self.log.write("event", t, what="odometry stale: stop")
                    self.base.stop()
            if item is None:
                continue
            if isinstance(item, Scan):
                if self.avoidance is not None:
                    self.avoidance.on_scan(item)
                if hasattr(self.controller, "on_scan"):
                    self.controller.on_scan(item)
                if self._planning and pose is not None and t >= self._next_integrate:
                    self._next_integrate = t + self.config.plan.integrate_s
                    if self.grid is None:
                        self.grid = OccupancyGrid((pose.x, pose.y), self.config.plan.grid)
                    self.grid.integrate(pose, item)
                continue
            if not isinstance(item, Pose2D):  # a reading: robot time of the latest odometry
                if pose is not None:
                    fields = self.controller.on_input(t, pose, item)
                    if fields is not None:
                        if last_reading is not None:
                            self.intervals.append(t - last_reading)
                        last_reading = t
                        self.log.write("measurement", t, source=self.source, **fields)
                continue
            odo = item
            last_odometry_wall, odometry_stale = time.monotonic(), False
            if t0 is not None and odo.t_robot + clock_offset < t:
                # the base restarted (its clock runs from 0 again): continue robot time one
                # odometry period on, so staleness, control cadence and limits keep running
                new_offset = t + ODOMETRY_PERIOD_S - odo.t_robot
                self.clock_resets += 1
                log.warning("base clock went back from %.3f s to %.3f s (a base reset?): re-anchored",
                            t - clock_offset, odo.t_robot)
                self.log.write("event", t, what="base clock reset: re-anchored",
                               base_clock_before=round(t - clock_offset, 6), base_clock_now=round(odo.t_robot, 6))
                clock_offset = new_offset
                self._braking = None  # a reset clears the base's brake mode: send it again
            t = odo.t_robot + clock_offset
            t0 = t if t0 is None else t0
            pose = Pose(odo.x, odo.y, odo.theta)
            if next_control is None:
                next_control = t
            if t + 1e-9 < next_control:
                continue
            next_control += cfg.control_period_s
            if last_reading is None or t - last_reading > self.stale_timeout():
                if not stale and last_reading is not None:
                    self.stale_stops += 1
                    log.warning("%s stream stale for %.2f s: stopping the robot", self.source, t - last_reading)
                    self.log.write("event", t, what=f"{self.source} stale: stop")
                stale = True
                self._brake(True, t)
                self._send(Decision(0.0, 0.0, None, False, "stale"), t, odo)
                if t - t0 > cfg.max_time_s:
                    return self._outcome(False, "time limit", t - t0, pose, None)
                continue
            if stale:
                self.log.write("event", t, what=f"{self.source} fresh again: resume")
            stale = False
            waypoint = self._waypoint(t, pose)
            decision = self.controller.decide(pose, steer_to=waypoint)
            if self.avoidance is not None:
                decision = self.avoidance.adjust(decision, t, emergency_only=waypoint is not None)
            self.log.write("estimate", t, **self.controller.estimate(), phase=self.controller.phase,
                           pose=[round(v, 4) for v in pose])
            slow = self._age_factor(t - last_reading)
            self._brake(slow < 1.0, t)
            if slow < 1.0:
                decision = decision._replace(v=decision.v * slow, w=decision.w * slow)
            self._send(decision, t, odo, **({"slowed": round(slow, 3)} if slow < 1.0 else {}))
            if decision.arrived:
                return self._outcome(True, "arrived", t - t0, pose, decision.goal)
            if t - t0 > cfg.max_time_s:
                return self._outcome(False, "time limit", t - t0, pose, decision.goal)

    def stale_timeout(self) -> float:
        """``stale_timeout_s``, or ``stale_intervals`` median reading intervals if longer."""
        cfg = self.config.loop
        if not self.intervals or cfg.stale_intervals <= 0:
            return cfg.stale_timeout_s
        return max(cfg.stale_timeout_s, cfg.stale_intervals * statistics.median(self.intervals))

    def _waypoint(self, t: float, pose: Pose) -> tuple[float, float] | None:
        """With a map: re-plan to the current goal every replan_s, steer to a point ahead."""
        goal = self.controller.reported
        if self.grid is None or goal is None or self.controller.phase != "homing":
            return None
        cfg = self.config.plan
        if t >= self._next_plan or self._path is None:
            self._next_plan = t + cfg.replan_s
            self._path = self.grid.plan((pose.x, pose.y), (float(goal[0]), float(goal[1])))
            self.plans += 1
            if self._path is not None:
                self.log.write("plan", t, cells=len(self._path), goal=_round(goal))
        if not self._path:
            return None
        return lookahead(self._path, pose, cfg.lookahead_m)

    def _age_factor(self, age: float) -> float:
        """1 for data younger than slow_after_s, falling linearly to 0 at the stale timeout."""
        slow_after, timeout = self.config.loop.slow_after_s, self.stale_timeout()
        if age <= slow_after:
            return 1.0
        return max(0.0, (timeout - age) / (timeout - slow_after))

    def _brake(self, on: bool, t: float) -> None:
        """Base brake mode (emergency deceleration) on or off; sent on change only."""
        if on != self._braking and self.base.brake(on):  # not sent (base away): try again next time
            self._braking = on
            self.log.write("event", t, what="brake mode " + ("on" if on else "off"))

    def _send(self, decision: Decision, t: float, odo: Pose2D, **fields: Any) -> None:
        self.base.send_velocity(decision.v, decision.w)
        self.commands += 1
        self.latency_ms.append((time.time() - odo.t_host) * 1000)
        self.log.write("command", t, v=round(decision.v, 4), w=round(decision.w, 4), note=decision.note, **fields)

    def _outcome(self, arrived: bool, reason: str, duration: float, pose: Pose, goal) -> Outcome:
        self.base.stop()
        self.log.write("event", duration, what=reason)
        return Outcome(arrived, reason, duration, pose, goal, self.commands, self.stale_stops, list(self.latency_ms))


def aoa_loop(base: BaseDriver, aoa: AoaDriver, config: Config = Config(), runlog: RunLog | None = None) -> HomingLoop:
    """S0 homing: one XPLR-AOA and the base."""
    return HomingLoop(base, aoa, AoaController(config), config, runlog)


def rss_loop(base: BaseDriver, rss: Driver, config: Config = Config(), runlog: RunLog | None = None) -> HomingLoop:
    """S2 homing: the four-dish AT86RF212 node and the base."""
    return HomingLoop(base, rss, RssController(config.s2), config, runlog)


def dock_loop(base: BaseDriver, station: AoaDriver, config: Config = Config(), runlog: RunLog | None = None) -> HomingLoop:
    """S1 docking: the station's AoA/RSSI readings of the robot's tag, and the base."""
    return HomingLoop(base, station, DockController(config.s1), config, runlog)


def trilat_loop(base: BaseDriver, ble: Driver, config: Config = Config(), runlog: RunLog | None = None) -> HomingLoop:
    """S3: go to a goal, localised by trilateration on BLE beacons at known places."""
    return HomingLoop(base, ble, TrilatController(config.trilat), config, runlog)


def anchors_loop(base: BaseDriver, anchors: list[Driver], site: Site, config: Config = Config(),
                 runlog: RunLog | None = None) -> HomingLoop:
    """Homing on fixed anchors: the site's anchors locate the robot's tag and the target's."""
    return HomingLoop(base, anchors, AnchorsController(site), config, runlog)


def _round(v: Any) -> list[float] | None:
    return None if v is None else [round(float(x), 4) for x in v]
