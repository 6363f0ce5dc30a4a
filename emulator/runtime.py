"""The emulator's asyncio runtime: steps the world and every device, paced by a clock.

Clocks:
- real time (``speed=1``), scaled (``speed=N`` runs N× faster), as fast as possible
  (``speed=math.inf``);
- lockstep: after every control period the world waits until the host has answered with a
  velocity command (or ``lockstep_timeout`` wall seconds pass, counted), so closed-loop runs
  are fast and deterministic.

Seeds: every random stream is derived from the one seed, so identical seeds give identical
bytes on every link.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import tempfile
import time
from collections.abc import AsyncIterator, Iterable
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from rfhoming.emulator.devices import BaseRunner, DeviceRunner, target_positions
from rfhoming.emulator.faults import ByteFaults, Fault, FaultError
from rfhoming.emulator.links import Link, PipeLink, PtyLink, TcpLink
from rfhoming.emulator.scenario import Scenario, ScenarioError
from rfhoming.protocol import devices

if TYPE_CHECKING:
    from rfhoming.emulator.ros2pose import PoseFollower

TRANSPORTS = ("pty", "tcp", "pipe")
SETTLE_LIMIT = 1000
"""Yields after a step before an in-process host that is still busy is counted and stepped past."""


def _check_settings(transport: str, link_dir: Path | None, lockstep: bool, robot: dict[str, Any] | None,
                    pose_from: dict[str, Any] | None) -> None:
    """The settings that cannot go together, refused before anything is opened."""
    if transport not in TRANSPORTS:
        raise ScenarioError(f"transport must be one of {TRANSPORTS}")
    if transport == "pty" and link_dir is not None and not link_dir.is_dir():
        raise ScenarioError(f"link directory {link_dir} is not a directory (create it, or pass none for a temp dir)")
    if pose_from is not None and (lockstep or robot is not None):
        raise ScenarioError("--pose-from: the robot is a ROS 2 robot of its own; it takes neither --lockstep nor "
                            "--robot (nor a scenario with [robot.mavlink])")


class Emulator:
    def __init__(self, scenario: Scenario, *, transport: str = "pty", seed: int = 0,
                 step_ms: int = 10, speed: float = 1.0, lockstep: bool = False,
                 control_period_ms: int = 100, lockstep_timeout: float = 5.0,
                 faults: Iterable[Fault] = (), truth: IO[str] | None = None,
                 link_dir: Path | None = None, robot: dict[str, Any] | None = None,
                 pose_from: dict[str, Any] | None = None) -> None:
        """``robot``: the base as a ROS 2 robot (emulator/ros2robot.py), e.g. {"domain": 7, "ns": ""}, or
        as a MAVLink vehicle (emulator/mavlinkrobot.py), {"kind": "mavlink", "gcs": None, "options": {...}};
        by default the scenario's own (``[robot.mavlink]``), or the serial base. ``pose_from``: the
        robot is another, a ROS 2 robot whose pose comes on a topic (emulator/ros2pose.py), e.g.
        {"topic": "/ground_truth/pose", "domain": 7}: the scenario's base is not served."""
        robot = robot if robot is not None else scenario.vehicle
        _check_settings(transport, link_dir, lockstep, robot, pose_from)
        self.scenario = scenario
        self.world = scenario.world
        self.step_s = step_ms / 1000
        self.speed = speed
        self.lockstep = lockstep
        self.control_period_s = control_period_ms / 1000
        self.lockstep_timeout = lockstep_timeout
        self.transport = transport
        self.truth = truth
        self.t = 0.0
        self.counters = {"steps": 0, "lockstep_timeouts": 0, "settle_overruns": 0}
        self.link_dir = link_dir or Path(tempfile.mkdtemp(prefix="rfhoming-"))
        self.faults = list(faults)
        self.devices: list[DeviceRunner] = []
        self.pose_from = self._pose_follower(pose_from) if pose_from is not None else None
        start = scenario.world.robot
        self._start = (start.x, start.y, start.theta)
        self._check_faults()
        self._add_devices(seed, robot)
        self._timed = sorted([(f.params["at"], f) for f in self.faults if "at" in f.params], key=lambda x: x[0])
        triggers = {d: _HostTrigger([f for f in self.faults if "after_bytes" in f.params and f.hits(d.name)])
                    for d in self.devices}
        self._triggered = {d: trigger for d, trigger in triggers.items() if trigger.faults}
        self._base = next((d for d in self.devices if isinstance(d, BaseRunner)), None)
        self._others = [d for d in self.devices if d is not self._base]
        self._replugs: list[tuple[float, DeviceRunner]] = []
        self._next_truth = 0.0
        self._next_control = self.control_period_s
        if lockstep and self.base is None:
            raise ValueError("lockstep needs a robot base in the scenario: the host's velocity command is its answer")

    def _check_faults(self) -> None:
        """Every fault names a device of the scenario (or none: all of them)."""
        unknown = {f.device for f in self.faults if f.device} - {d.name for d in self.scenario.devices}
        if unknown:
            names = ", ".join(d.name for d in self.scenario.devices)
            raise FaultError(f"fault names unknown device(s) {sorted(unknown)}; this scenario has: {names}")

    def _add_devices(self, seed: int, robot: dict[str, Any] | None) -> None:
        """One runner per scenario device, each on its link, seeded by its index; no base when a
        ROS 2 robot of its own is followed (``pose_from``)."""
        for k, spec in enumerate(self.scenario.devices):
            if self.pose_from is not None and spec.type == "base":
                continue
            rng = np.random.default_rng([seed, k])
            link = (self._robot_link(robot) if robot is not None and spec.type == "base"
                    else self._link(self.transport, spec.name))
            byte_faults = ByteFaults([f for f in self.faults if f.hits(spec.name)], np.random.default_rng([seed, k, 1]))
            self.devices.append(self._device(spec.type, spec.name, k, link, byte_faults, rng, spec.options))

    @staticmethod
    def _robot_link(robot: dict[str, Any]) -> Link:
        """The base's link as a robot of another kind: a MAVLink vehicle, or a ROS 2 robot."""
        if robot.get("kind") == "mavlink":
            try:
                from rfhoming.emulator.mavlinkrobot import MavlinkLink  # pymavlink: the mavlink extra
                from rfhoming.firmware.mavlink_vehicle import VehicleOptions
            except ImportError as exc:
                raise ScenarioError(f"--robot mavlink needs {exc.name or exc}; install it with "
                                    "pip install 'rfhoming[mavlink]'") from None
            try:
                return MavlinkLink(robot.get("gcs"), VehicleOptions(**robot.get("options", {})))
            except (ValueError, TypeError) as exc:  # TypeError: an option the vehicle does not take
                raise ScenarioError(f"--robot mavlink or [robot.mavlink]: {exc}") from None
        try:
            from rfhoming.emulator.ros2robot import Ros2Link  # cyclonedds: the ros2 extra
        except ImportError as exc:
            raise ScenarioError(f"--robot ros2 needs {exc.name or exc}; install it with "
                                "pip install 'rfhoming[ros2]'") from None

        return Ros2Link(**robot)

    @staticmethod
    def _pose_follower(settings: dict[str, Any]) -> PoseFollower:
        try:
            from rfhoming.emulator.ros2pose import PoseFollower  # cyclonedds: the ros2 extra
        except ImportError as exc:
            raise ScenarioError(f"--pose-from ros2: needs {exc.name or exc}; install it with "
                                "pip install 'rfhoming[ros2]'") from None
        try:
            return PoseFollower(**settings)
        except (ValueError, TypeError) as exc:  # TypeError: a setting it does not take
            raise ScenarioError(f"--pose-from: {exc}") from None

    def _link(self, transport: str, name: str) -> Link:
        if transport == "pty":
            return PtyLink(self.link_dir / name)
        if transport == "tcp":
            return TcpLink()
        return PipeLink()

    def _device(self, board: str, name: str, k: int, link: Link, faults: ByteFaults,
                rng: np.random.Generator, options: dict[str, Any]) -> DeviceRunner:
        """The runner of one of the device table's boards (a scenario device's ``type``)."""
        found = devices.BOARDS.get(board)
        if found is None:
            raise ScenarioError(f"device {name!r} is of an unknown type {board!r}; the types are "
                                f"{', '.join(devices.BOARDS)} (the device table's boards)")
        runner: type[DeviceRunner] = devices.load(found[1].runner)
        device = runner.build(name, k, link, faults, rng, options, self.scenario)
        device.board = board  # a runner may build several boards that run its firmware model
        return device

    @property
    def base(self) -> BaseRunner | None:
        return self._base

    def device(self, name: str) -> DeviceRunner:
        for d in self.devices:
            if d.name == name:
                return d
        raise KeyError(name)

    def endpoints(self) -> list[dict[str, Any]]:
        return [d.describe() for d in self.devices]

    async def start(self) -> list[dict[str, Any]]:
        for d in self.devices:
            await d.link.start()
        if self.pose_from is not None:
            self.pose_from.start()
        if self.truth is not None:  # a header line: what a plot of the run needs to know
            header = {"scenario": self.scenario.name, "bounds": list(self.world.bounds),
                      "obstacles": [o.polygon for o in self.world.obstacles],
                      "devices": [d.name for d in self.devices]}
            self.truth.write(json.dumps(header) + "\n")
        self.write_truth()
        return self.endpoints()

    async def close(self) -> None:
        for d in self.devices:
            await d.link.close()
        if self.pose_from is not None:
            self.pose_from.close()

    async def step(self) -> None:
        """Advance the world and every device by one step, then deliver their bytes."""
        t0, t1 = self.t, self.t + self.step_s
        if self._base is not None:
            self._base.step(self.world, t0, t1)
        elif self.pose_from is not None and (pose := self.pose_from.pose(self._start)) is not None:
            r = self.world.robot
            r.x, r.y, r.theta = pose
        if self.pose_from is not None and self.pose_from.stale:
            self._step_deaf(t0, t1)
        else:
            for d in self._others:
                d.step(self.world, t0, t1)
        self.t = self.world.t = t1
        if self._replugs or self._timed or self._triggered:  # most steps have no fault to check
            await self._timed_faults()
        for d in self.devices:
            d.pump(t1)
        self.counters["steps"] += 1
        if t1 + 1e-9 >= self._next_truth:
            self.write_truth()

    def _step_deaf(self, t0: float, t1: float) -> None:
        """The devices' step with no target in the world: a ``--pose-from`` robot whose pose is
        stale is nowhere known, so its radios hear nothing (their firmware runs on)."""
        targets, self.world.targets = self.world.targets, []
        try:
            for d in self._others:
                d.step(self.world, t0, t1)
        finally:
            self.world.targets = targets

    async def _timed_faults(self) -> None:
        while self._replugs and self._replugs[0][0] <= self.t:
            _, device = self._replugs.pop(0)
            await device.link.replug()
        while self._timed and self._timed[0][0] <= self.t:
            _, fault = self._timed.pop(0)
            for d in self.devices:
                if fault.hits(d.name):
                    await self._fire(fault, d)
        for d, trigger in self._triggered.items():
            if (due := trigger.due(d.link.counters)) is not None:
                await self._fire(due, d)

    async def _fire(self, fault: Fault, d: DeviceRunner) -> None:
        if fault.kind == "unplug":
            await d.link.unplug()
            self._replugs.append((self.t + fault.params.get("for", math.inf), d))
            self._replugs.sort(key=lambda x: x[0])
        elif fault.kind == "reboot":
            d.reboot(self.t)
        elif fault.kind == "baud":
            d.forced_baud = int(fault.params["rate"])

    def write_truth(self) -> None:
        """One truth line now (also called by in-process users for the final pose)."""
        if self.truth is None:
            return
        r = self.world.robot
        line = {"t": round(self.t, 4), "robot": {"x": round(r.x, 4), "y": round(r.y, 4), "theta": round(r.theta, 5)},
                "targets": target_positions(self.world, self.t)}
        self.truth.write(json.dumps(line) + "\n")
        self.truth.flush()
        self._next_truth = self.t + 0.05

    async def run(self, duration: float | None = None) -> None:
        """Step until ``duration`` simulated seconds have passed (forever if None)."""
        wall0, sim0 = time.monotonic(), self.t
        end = math.inf if duration is None else self.t + duration
        while self.t + 1e-9 < end:
            await self.step()
            if self.lockstep:
                control = self.t + 1e-9 >= self._next_control
                await self._let_host_run(control)
                if control:
                    self._next_control += self.control_period_s
                    await self._await_host()
            elif math.isinf(self.speed):
                await asyncio.sleep(0)
            else:
                lag = sim0 + (time.monotonic() - wall0) * self.speed
                await asyncio.sleep(max(0.0, (self.t - lag) / self.speed))

    async def _let_host_run(self, control: bool = True) -> None:
        """Yield to the host after a step. In process (``pipe``), yield until every other task
        is idle -- waiting for bytes or a timer -- so the host has handled this step's bytes
        and sent its answer before the next step: a run's result then depends on the bytes
        alone, not on how many awaits the host takes between them. A step that woke nothing
        (no bytes came, nothing is ready to run) is not yielded after, but for a ``control``
        period's end, so that timers and other I/O still run at least once a period. Across
        processes a host's progress cannot be seen; the control-period wait
        (:meth:`_await_host`) paces it."""
        if self.transport != "pipe":
            await asyncio.sleep(0)
            return
        ready = asyncio.get_running_loop()._ready  # type: ignore[attr-defined]  # asyncio's run queue
        if not ready and not control:
            return
        await asyncio.sleep(0)
        for _ in range(SETTLE_LIMIT):
            if not ready:
                return
            await asyncio.sleep(0)
        self.counters["settle_overruns"] += 1  # a host that never idles: step on, counted

    async def _await_host(self) -> None:
        """At a control period's end: wait (up to ``lockstep_timeout``) for a velocity command
        since the last one."""
        base = self.base
        assert base is not None
        if not base.commanded.is_set():
            try:
                async with asyncio.timeout(self.lockstep_timeout):
                    await base.commanded.wait()
            except TimeoutError:
                self.counters["lockstep_timeouts"] += 1
        base.commanded.clear()


class _HostTrigger:
    """A device's ``after_bytes`` faults, in order: each is armed by a write from the host (after
    the fault before it fired) and fires once the device has sent ``after_bytes`` since the
    host's last write -- so it follows the host's progress, however slow the machine."""

    def __init__(self, faults: list[Fault]) -> None:
        self.faults = faults
        self.armed = False
        self.rx = self.tx_mark = 0

    def due(self, counters: dict[str, int]) -> Fault | None:
        if not self.faults:
            return None
        if counters["rx_bytes"] != self.rx:  # the host wrote: count from here
            self.rx, self.tx_mark, self.armed = counters["rx_bytes"], counters["tx_bytes"], True
        if not self.armed or counters["tx_bytes"] - self.tx_mark < self.faults[0].params["after_bytes"]:
            return None
        self.armed = False
        return self.faults.pop(0)


@contextlib.asynccontextmanager
async def running(emulator: Emulator, duration: float | None = None) -> AsyncIterator[Emulator]:
    """Start the emulator, run it in the background, and close it on exit."""
    await emulator.start()
    task = asyncio.create_task(emulator.run(duration))
    try:
        yield emulator
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        await emulator.close()
