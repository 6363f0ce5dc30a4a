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
- a base with no brake mode (the device table's ``brakes``: a ROS 2 base) sheds speed at its
  normal deceleration at best, so for it the loop bounds the speed: no faster than lets it stop
  within ``stop_within_m`` of where the data ended (:meth:`HomingLoop.stopping_speed`);
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
import gc
import contextlib
import json
import logging
import math
import statistics
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO, Any

from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host import outputs
from rfhoming.host.losses import with_losses
from rfhoming.host.drivers.robot import Pose2D, RobotBase, Scan, TakenOver
from rfhoming.host.homing.avoidance import ObstacleAvoidance
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.grid import OccupancyGrid, lookahead
from rfhoming.host.homing.planner import Planner, PlanScheduler, TcodPlanner
from rfhoming.host.homing.types import Controller, Decision, Pose
from rfhoming.host.loopstall import StallMonitor
from rfhoming.host.ports import PortError
from rfhoming.protocol import devices

log = logging.getLogger(__name__)

ODOMETRY_PERIOD_S = 0.02  # the base's documented 50 Hz odometry: the step assumed across a reset
STEP_BUDGET_S = 0.005
"""Wall time the live loop works through queued items before it hands the event loop back: a
backlog (after the process was held up) is taken in bounded steps, with the drivers' reads and
the timers between them, not as one long callback (an anchors fix tick alone takes 3-7 ms here)."""
_step_clock = time.perf_counter


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
    links: dict[str, dict[str, Any]] = field(default_factory=dict)  # each driver's health at the end, by kind
    stalls: dict[str, Any] = field(default_factory=dict)  # the event loop's (host/loopstall.py)
    plans: int = 0
    plans_late: int = 0
    taken_over: dict[str, Any] | None = None  # the base was taken over: its mode and why (reason "taken over")

    def summary(self) -> dict[str, Any]:
        lat = sorted(self.latency_ms)
        pick = (lambda q: round(lat[min(len(lat) - 1, int(q * len(lat)))], 3)) if lat else (lambda q: None)
        return {"arrived": self.arrived, "reason": self.reason, "robot_time_s": round(self.robot_time_s, 3),
                "pose": None if self.pose is None else [round(v, 4) for v in self.pose],
                "goal": None if self.goal is None else [round(v, 4) for v in self.goal],
                "commands": self.commands, "stale_stops": self.stale_stops,
                "latency_ms_p50": pick(0.5), "latency_ms_p99": pick(0.99),
                "loop_stall_ms_max": self.stalls.get("loop_stall_ms_max"),
                "loop_stall_ms_p99": self.stalls.get("loop_stall_ms_p99"),
                **({"plans": self.plans, "plans_late": self.plans_late} if self.plans else {}),
                **({"taken_over": self.taken_over} if self.taken_over else {})}


class RunLog:
    """JSON lines, one per event, flushed as they come (a killed run keeps its log: in
    ``NAME.part`` when written through an :class:`~rfhoming.host.outputs.Output`).

    Written through an Output, the log is the run's (it replaces NAME however the run ends)
    once the run has begun (:meth:`began`: its base answered): the loop's own records before
    that -- "no brake mode", a stall while the ports open -- do not make a run whose devices
    never connected replace the old log.

    A write that fails (a full disk) ends the run with an error naming the file and how many
    records it kept: a run without its record is not what was asked for."""

    def __init__(self, out: IO[str] | outputs.Output | None,
                 listeners: list[Callable[[dict[str, Any]], None]] | None = None) -> None:
        self.out = out
        self.listeners = listeners or []  # each record also goes to these (an MCAP recorder, a live view)
        self.written = 0  # records on disk

    def began(self) -> None:
        """The run has begun: from now on its log replaces the old one, however it ends."""
        if isinstance(self.out, outputs.Output):
            self.out.own()

    def write(self, kind: str, t: float, **fields: Any) -> None:
        """One record; a non-finite number in it is a bug (every decoder refuses one), raised
        here as ValueError: the log stays strict JSON, never a bare NaN or Infinity token."""
        record = {"kind": kind, "t": round(t, 4), **fields}
        if self.out is not None:
            try:
                line = json.dumps(record, allow_nan=False)
            except ValueError:
                raise ValueError(f"a {kind} record at t={t} holds a number that is not finite: {record!r}") from None
            try:
                file = self.out.file if isinstance(self.out, outputs.Output) else self.out  # owned at began()
                file.write(line + "\n")
                file.flush()
            except OSError as exc:
                out, self.out = self.out, None
                kept = f"it holds the run's first {self.written} records (export skips a torn last line)"
                if isinstance(out, outputs.Output):
                    raise outputs.failed(out, exc, kept) from None
                with contextlib.suppress(OSError):  # what it still holds cannot be written either
                    out.close()
                raise outputs.failed(getattr(out, "name", "the run log"), exc, kept) from None
            self.written += 1
        for listener in self.listeners:
            listener(record)


class HomingLoop:
    """The base plus its sensor drivers (one, or several fixed anchors) and a controller.

    Every driver was built to hand its items to ``inputs`` (host/homing/assembly.py builds
    them so): the loop sees odometry, scans and readings in arrival order, so its decisions
    depend on the bytes alone and a replay reproduces them exactly."""

    def __init__(self, base: RobotBase, sensors: list[Driver], controller: Controller, config: Config,
                 runlog: RunLog, inputs: BoundedStream[Any], planner: Planner | None = None,
                 plans_taken: dict[float, float] | None = None,
                 odometry_stale_at: frozenset[tuple[float, int]] = frozenset()) -> None:
        assert base.out is inputs and all(d.out is inputs for d in sensors), "every driver hands its items to the loop's stream"
        self.base, self.sensors, self.config = base, sensors, config
        self.controller = controller
        self.source = controller.source
        self.log = runlog
        self.inputs = inputs
        self.stale_stops = 0
        self.commands = 0
        self.latency_ms: deque[float] = deque(maxlen=10_000)  # bounded: the latest commands
        self.avoidance = (ObstacleAvoidance(config.avoid) if config.avoid_obstacles and not controller.own_avoidance
                          else None)
        self._planning = config.plan.enabled and controller.uses_planner
        self.grid: OccupancyGrid | None = None  # built from the first scan, if the base sends any
        self._path: list[tuple[float, float]] | None = None
        self._path_cells: list[tuple[int, int]] = []
        self._path_goal: tuple[float, float] | None = None
        self._path_blocked = 0  # path cells near an obstacle when it was planned
        self._planned_map = -1  # the map's version the path was planned on
        self._map_version = 0  # scans integrated so far
        self._next_plan = 0.0
        self._last_request = -math.inf
        self._next_integrate = 0.0
        self.scheduler = PlanScheduler(planner or TcodPlanner(), config.plan.latency_s, config.plan.wait, plans_taken)
        self.note: Callable[[dict[str, Any]], None] | None = None  # a run's capture keeps what replays must repeat
        self.plans = 0
        self.plans_late = 0
        self.stalls = StallMonitor(on_stall=self._on_stall)
        self.intervals: deque[float] = deque(maxlen=20)  # robot-time gaps between readings
        self._braking: bool | None = None  # base brake mode as last sent; None: unknown, send it
        self._brake_logged = False  # brake mode as the run log last said
        self.driving = True  # False once a goal is handed to a planner (:meth:`hand_over`)
        self._tasks: list[asyncio.Task[None]] = []
        self._step_began = _step_clock()  # when this pass of the loop took the event loop
        self.brakes = devices.kind(base.kind, notice=False).brakes
        self.speed_limit = self.stopping_speed()  # m/s; inf for a base with a brake mode
        # the loop's state, on robot time
        self.t = 0.0
        self.t0: float | None = None
        self.pose: Pose | None = None
        self.last_reading: float | None = None
        self.next_control: float | None = None
        self.stale = False
        self.clock_offset = 0.0  # robot time = base clock + offset, re-anchored on a base reset
        self.last_odometry_wall = time.monotonic()
        self.odometry_stale = False
        self._read_while_odometry_stale = False
        self._since_odometry = 0  # items taken since the last odometry: where the watchdog fired, with self.t
        self.odometry_stale_at = odometry_stale_at
        """A replay's: where the live run's wall-clock odometry watchdog fired (robot time, items
        taken after that odometry), from the capture's notes; the replay's watchdog is off."""
        if self.speed_limit < math.inf:
            cfg = self.config.loop
            self.log.write("event", 0.0, what="no brake mode: speed bounded", v_max=round(self.speed_limit, 4),
                           stop_within_m=cfg.stop_within_m, decel_m_s2=cfg.brakeless_decel_m_s2)

    def stopping_speed(self) -> float:
        """The fastest a base without a brake mode may drive and still stop within
        ``stop_within_m`` of where its data ended, at the configured stale timeout. It drives on
        until the loop's first slowed command (``slow_after_s`` plus up to one control period),
        then follows the ramp to 0 at the stale timeout, or its own deceleration a if that is
        gentler: v·lag + v²/(2a) and v·lag + v·ramp/2 must both fit. inf for a base with a brake
        mode (it stops at its emergency deceleration: the serial base's distance)."""
        if self.brakes:
            return math.inf
        cfg = self.config.loop
        a, lag = cfg.brakeless_decel_m_s2, cfg.slow_after_s + cfg.control_period_s
        ramp = cfg.stale_timeout_s - cfg.slow_after_s
        return min(a * (math.sqrt(lag * lag + 2 * cfg.stop_within_m / a) - lag), cfg.stop_within_m / (lag + ramp / 2))

    async def run(self) -> Outcome:
        # start-up's garbage goes now, not as a pause mid-run, and what start-up built (modules,
        # drivers, maps) is left out of the collections during the run: a full collection
        # over it took tens of milliseconds, a stall the control period feels
        gc.collect()
        gc.freeze()
        tasks = [asyncio.create_task(self.base.run())] + [asyncio.create_task(s.run()) for s in self.sensors]
        self._tasks = tasks
        try:
            async with self.stalls as stalls, self.base:
                await self._base_connected(tasks[0])
                self.log.began()  # the base answered: the run's log is this one now
                self.base.stop()  # a known state, and the emulator's lockstep gets its first answer
                self.last_odometry_wall = time.monotonic()  # the base's silence counts once it is there
                outcome = await self._loop()
                outcome.stalls = stalls.summary()
                if self._wall_time_matters():
                    self.log.write("stall", self.t, **outcome.stalls, over_threshold=stalls.over_count)
                return outcome
        finally:
            gc.unfreeze()  # collectable again once the run ends (a campaign worker runs many)
            self.scheduler.close()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    def _wall_time_matters(self) -> bool:
        """False in lockstep and replays (the world waits for the host; a stall delays nothing):
        their run logs hold what the robot did alone, the same on any machine."""
        return not math.isinf(self.config.loop.odometry_wall_timeout_s)

    def _on_stall(self, took_ms: float, ran: str) -> None:
        if self._wall_time_matters():
            log.warning("event loop blocked %.0f ms by %s", took_ms, ran)
            self.log.write("stall", self.t, ms=round(took_ms, 1), ran=ran)

    def _raise_if_a_driver_died(self) -> None:
        """A driver whose task ended with an error ends the run with it: nothing else may be
        watching (a replay, the in-process pipe), and its stream would stay silent for ever."""
        for task in self._tasks:
            if task.done() and not task.cancelled() and task.exception() is not None:
                raise task.exception()  # type: ignore[misc]

    async def _base_connected(self, base_task: asyncio.Task[None]) -> None:
        """Wait for the base's port, or raise why its driver ended (a port that never opened)."""
        connected = asyncio.create_task(self.base.connected.wait())
        try:
            await asyncio.wait({connected, base_task}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            connected.cancel()
        if not self.base.connected.is_set():
            base_task.result()  # raises the driver's error
            raise PortError(f"{self.base.port.name} ended before it connected (an empty recording?)")

    async def _loop(self) -> Outcome:
        while True:
            item = await self._next_item()
            if item is None:
                self._raise_if_a_driver_died()
                if self.base.state == "ended":  # a replay's recording is over, and nothing is left to read
                    elapsed = self.t - self.t0 if self.t0 is not None else 0.0
                    return self._outcome(False, "end of recording", elapsed, self.pose, self.controller.reported)
                continue
            if isinstance(item, Scan):
                self._on_scan(item)
            elif isinstance(item, Pose2D):
                outcome = self._on_odometry(item)
                if outcome is not None:
                    return outcome
            elif isinstance(item, TakenOver):  # a ground station, the pilot or a failsafe has the base now
                log.warning("%s: %s", self.base.port.name, item.why)
                elapsed = self.t - self.t0 if self.t0 is not None else 0.0
                return self._outcome(False, "taken over", elapsed, self.pose, self.controller.reported,
                                     taken_over={"mode": item.mode, "why": item.why})
            else:
                self._on_reading(item)

    async def _next_item(self) -> Any:
        """The next input, or None after a wait that found none; stops the robot when the base
        has been silent too long on the wall clock (its own clock is gone with it)."""
        cfg = self.config.loop
        if _step_clock() - self._step_began > STEP_BUDGET_S and self._wall_time_matters():
            await asyncio.sleep(0)  # lockstep and replays need not: the world waits for the host
            self._step_began = _step_clock()
        if (self.odometry_stale_at and not self.odometry_stale
                and (round(self.t, 6), self._since_odometry) in self.odometry_stale_at):
            self._odometry_went_stale()  # a replay, where the live run's watchdog fired
        item = self.inputs.get_nowait()  # most items are already here: no timer, no task
        if item is None:
            try:  # asyncio.timeout, not wait_for: no task per item, and a cancellation stays one
                async with asyncio.timeout(min(cfg.stale_timeout_s, cfg.odometry_wall_timeout_s)):
                    item = await self.inputs.get()
            except TimeoutError:
                item = None
            self._step_began = _step_clock()
        if (not isinstance(item, Pose2D) and not self.odometry_stale
                and time.monotonic() - self.last_odometry_wall > cfg.odometry_wall_timeout_s):
            if self.note is not None:  # the wall clock's doing: the capture says where, for a replay
                self.note({"odometry_stale": round(self.t, 6), "after_items": self._since_odometry})
            self._odometry_went_stale()
        if item is not None:
            self._since_odometry = 0 if isinstance(item, Pose2D) else self._since_odometry + 1
        return item

    def _odometry_went_stale(self) -> None:
        """The base has been silent too long on the wall clock: stop it, until odometry comes again."""
        self.odometry_stale = True
        log.warning("odometry stale: stopping the robot (its watchdog stops it too)")
        self.log.write("event", self.t, what="odometry stale: stop")
        self.base.stop()

    def _on_scan(self, scan: Scan) -> None:
        if self.avoidance is not None:
            self.avoidance.on_scan(scan)
        self.controller.on_scan(scan)
        if self._planning and self.pose is not None and self.t >= self._next_integrate:
            self._next_integrate = self.t + self.config.plan.integrate_s
            if self.grid is None:
                self.grid = OccupancyGrid((self.pose.x, self.pose.y), self.config.plan.grid)
            self.grid.integrate(self.pose, scan)
            self._map_version += 1

    def _on_reading(self, item: Any) -> None:
        """A sensor reading, on the robot time of the latest odometry."""
        if self.pose is None:
            return
        fields = self.controller.on_input(self.t, self.pose, item)
        if fields is None:
            return
        if self.last_reading is not None:
            self.intervals.append(self.t - self.last_reading)
        self.last_reading = self.t
        self._read_while_odometry_stale |= self.odometry_stale
        self.log.write("measurement", self.t, source=self.source, **fields)

    def _on_odometry(self, odo: Pose2D) -> Outcome | None:
        """Robot time moves on; once per control period, decide and command."""
        self.last_odometry_wall = time.monotonic()
        if self.odometry_stale:
            self.odometry_stale = False
            self.log.write("event", self.t, what="odometry fresh again")
        self._advance_clock(odo)
        self.base.acting_on(odo)  # what it sends from here on is stamped on this odometry, live and in a replay
        if self._read_while_odometry_stale:
            # readings kept coming while the base was silent: their robot time is unknown, and the
            # newest is as old as the gap at most -- the sensor was not stale, the base was
            self._read_while_odometry_stale = False
            self.last_reading = self.t
        self.pose = Pose(odo.x, odo.y, odo.theta)
        if self.next_control is None:
            self.next_control = self.t
        if self.t + 1e-9 < self.next_control:
            return None
        self.next_control += self.config.loop.control_period_s
        return self._control(odo)

    def _advance_clock(self, odo: Pose2D) -> None:
        """Robot time from the base's clock, continued across a base reset (its clock runs from
        0 again): one odometry period on, so staleness, cadence and limits keep running."""
        if self.t0 is not None and odo.t_robot + self.clock_offset < self.t:
            before = self.t - self.clock_offset
            log.warning("base clock went back from %.3f s to %.3f s (a base reset?): re-anchored", before, odo.t_robot)
            self.log.write("event", self.t, what="base clock reset: re-anchored",
                           base_clock_before=round(before, 6), base_clock_now=round(odo.t_robot, 6))
            self.clock_offset = self.t + ODOMETRY_PERIOD_S - odo.t_robot
            self._braking = None  # a reset clears the base's brake mode: send it again
        self.t = odo.t_robot + self.clock_offset
        self.t0 = self.t if self.t0 is None else self.t0

    def _control(self, odo: Pose2D) -> Outcome | None:
        """One control period: stop on stale data, else the controller's (planned, avoided,
        slowed) command; the outcome when the run ends."""
        t, pose, cfg = self.t, self.pose, self.config.loop
        assert pose is not None and self.t0 is not None
        fresh_needed = self.controller.needs_fresh_readings
        if fresh_needed and (self.last_reading is None or t - self.last_reading > self.stale_timeout()):
            if not self.stale and self.last_reading is not None:
                self.stale_stops += 1
                log.warning("%s stream stale for %.2f s: stopping the robot", self.source, t - self.last_reading)
                self.log.write("event", t, what=f"{self.source} stale: stop")
            self.stale = True
            self._brake(True, t)
            self._send(Decision(0.0, 0.0, None, False, "stale"), t, odo)
            if t - self.t0 > cfg.max_time_s:
                return self._outcome(False, "time limit", t - self.t0, pose, None)
            return None
        if self.stale:
            self.log.write("event", t, what=f"{self.source} fresh again: resume")
        self.stale = False
        waypoint = self._waypoint(t, pose)
        decision = self.controller.decide(pose, steer_to=waypoint)
        if self.avoidance is not None:
            decision = self.avoidance.adjust(decision, t, emergency_only=waypoint is not None)
        self.log.write("estimate", t, **self.controller.estimate(), phase=self.controller.phase,
                       pose=[round(v, 4) for v in pose])
        if abs(decision.v) > self.speed_limit:  # along the same arc (v and ω scaled alike)
            scale = self.speed_limit / abs(decision.v)
            decision = decision._replace(v=decision.v * scale, w=decision.w * scale)
        slow = self._age_factor(t - self.last_reading) if fresh_needed and self.last_reading is not None else 1.0
        self._brake(slow < 1.0, t)
        if slow < 1.0:
            decision = decision._replace(v=decision.v * slow, w=decision.w * slow)
        self._send(decision, t, odo, **({"slowed": round(slow, 3)} if slow < 1.0 else {}))
        if decision.arrived:
            return self._outcome(True, "arrived", t - self.t0, pose, decision.goal)
        if t - self.t0 > cfg.max_time_s:
            return self._outcome(False, "time limit", t - self.t0, pose, decision.goal)
        return None

    def stale_timeout(self) -> float:
        """``stale_timeout_s``, or ``stale_intervals`` median reading intervals if longer."""
        cfg = self.config.loop
        if not self.intervals or cfg.stale_intervals <= 0:
            return cfg.stale_timeout_s
        return max(cfg.stale_timeout_s, cfg.stale_intervals * statistics.median(self.intervals))

    def _waypoint(self, t: float, pose: Pose) -> tuple[float, float] | None:
        """With a map: take a plan whose robot time has come, ask for one when the map or the
        goal changed materially, and steer to a point ahead on the path."""
        goal = self.controller.reported
        if self.grid is None or goal is None or self.controller.phase != "homing":
            return None
        cfg = self.config.plan
        self._take_plan(t)
        goal_xy = (float(goal[0]), float(goal[1]))
        if self.scheduler.pending is None and t + 1e-9 >= self._next_plan:
            why = self._replan_why(t, pose, goal_xy)
            if why is not None:
                self._next_plan = t + cfg.replan_s
                self._last_request = t
                self.scheduler.request(t, self.grid.costs(), self.grid.cell(pose.x, pose.y), self.grid.cell(*goal_xy),
                                       goal_xy, self._map_version)
                self.plans += 1
                self.log.write("event", t, what="plan asked", why=why, due=round(t + cfg.latency_s, 4))
        if not self._path:
            return None
        return lookahead(self._path, pose, cfg.lookahead_m, goal_xy)

    def _replan_why(self, t: float, pose: Pose, goal: tuple[float, float]) -> str | None:
        """Why the path no longer does, or None: a material change, not every new scan."""
        cfg, grid = self.config.plan, self.grid
        assert grid is not None
        if self._path_goal is None:
            return "first"
        if not self._path:
            return "no path yet"
        if math.dist(goal, self._path_goal) >= cfg.goal_moved_m:
            return "goal moved"
        if self._path_cells and self._planned_map != self._map_version:
            if int(grid.blocked(self._path_cells).sum()) > self._path_blocked:
                return "obstacle on the path"
            if t - self._last_request >= cfg.refresh_s:
                return "map grew"
        if self._path and min(math.dist(p, (pose.x, pose.y)) for p in self._path) > cfg.strayed_m:
            return "off the path"
        return None

    def _take_plan(self, t: float) -> None:
        """The pending plan, at its robot time: its path, or (live, not done yet) late. In
        lockstep and replays (``plan.wait``) this waits for it, blocking: an in-process world
        steps on while the host's loop is idle, so the loop must not yield here."""
        request = self.scheduler.due(t)
        if request is None:
            return
        if not request.ready(t) and (not self.scheduler.wait or request.taken_at is not None):
            if not request.late:
                request.late = True
                self.plans_late += 1
                log.warning("plan asked at %.2f s not done by its robot time %.2f s: steering on the old path",
                            request.t, request.due)
                self.log.write("event", t, what="plan late", asked=round(request.t, 4))
                if self.note is not None:  # not taken yet: a run that ends now never took it
                    self.note({"plan_asked": round(request.t, 4), "plan_taken": None})
            return
        self.scheduler.pending = None
        cells = request.future.result()
        assert self.grid is not None
        self._path_goal, self._planned_map = request.goal, request.map_version
        self._path_cells = cells or []
        self._path_blocked = int(self.grid.blocked(self._path_cells).sum()) if cells else 0
        self._path = None if cells is None else [self.grid.centre(c) for c in cells]
        self.log.write("plan", t, cells=len(cells or ()), goal=_round(request.goal), asked=round(request.t, 4),
                       **({"late": True} if request.late else {}))
        if request.late and self.note is not None:  # when, on the wall clock: the replay takes it then too
            self.note({"plan_asked": round(request.t, 4), "plan_taken": round(t, 4)})

    def _age_factor(self, age: float) -> float:
        """1 for data younger than slow_after_s, falling linearly to 0 at the stale timeout."""
        slow_after, timeout = self.config.loop.slow_after_s, self.stale_timeout()
        if age <= slow_after:
            return 1.0
        return max(0.0, (timeout - age) / (timeout - slow_after))

    def hand_over(self) -> None:
        """Another planner drives from now on (``rfhoming node``'s Nav2 mode): one stop, then the
        loop only estimates -- it logs the commands it would send, and sends none. The final stop
        at the run's end is still sent."""
        if self.driving:
            self.driving = False
            self.base.stop()
            self.log.write("event", self.t, what="handed over: another planner drives")

    def _brake(self, on: bool, t: float) -> None:
        """Base brake mode (emergency deceleration) on or off; sent on change (and again after a
        base reset), logged when the mode itself changes."""
        if not self.driving:
            return
        if on != self._braking and self.base.brake(on):  # not sent (base away): try again next time
            self._braking = on
            if on != self._brake_logged:
                self._brake_logged = on
                self.log.write("event", t, what="brake mode " + ("on" if on else "off"))

    def _send(self, decision: Decision, t: float, odo: Pose2D, **fields: Any) -> None:
        if not self.driving:
            self.log.write("command", t, v=round(decision.v, 4), w=round(decision.w, 4), note=decision.note,
                           unsent=True, **fields)
            return
        self.base.send_velocity(decision.v, decision.w)
        self.commands += 1
        self.latency_ms.append((time.time() - odo.t_host) * 1000)
        self.log.write("command", t, v=round(decision.v, 4), w=round(decision.w, 4), note=decision.note, **fields)

    def _outcome(self, arrived: bool, reason: str, duration: float, pose: Pose | None, goal: Any,
                 taken_over: dict[str, Any] | None = None) -> Outcome:
        self.base.stop()
        self.log.write("event", duration, what=reason, **(taken_over or {}))
        drivers: list[Driver | RobotBase] = [*self.sensors, self.base]
        kinds = [d.kind for d in drivers]
        links = {(d.kind if kinds.count(d.kind) == 1 else f"{d.kind}:{d.port.name}"): with_losses(d.health())
                 for d in drivers}
        return Outcome(arrived, reason, duration, pose, goal, self.commands, self.stale_stops, list(self.latency_ms),
                       links, plans=self.plans, plans_late=self.plans_late, taken_over=taken_over)


def _round(v: Any) -> list[float] | None:
    return None if v is None else [round(float(x), 4) for x in v]
