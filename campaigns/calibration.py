"""Calibration runs: what a user measures before homing, done through the same emulated radios.

The host is never told the simulator's truth. Before a campaign's homing runs, the robot drives
a straight line toward (or, for S1, with its tag toward) a transmitter placed at a point the
"user" chose, stops at a known distance and dwells there, all in one lockstep emulator session
with its own seed, so its per-link biases and noise are those of a separate session, as on real
hardware. The host's readings (through the real drivers and codecs, as ``rfhoming capture``
records them) are paired with the odometry pose's distance to that point, and a log-distance
fit, RSSI = P0 − 10 n log10(d), through each 0.25 m distance bin's median gives the calibration
constants (medians: S0's ±1 m range noise piles readings at the floor near the stop, which
pulled a plain least-squares n from 2.2 to 2.7). For S2's four dishes the robot then turns in place by quarter turns at the stop, so that each dish faces the
transmitter in turn, which gives each dish's own offset.

Only the scenario's geometry (where to put the robot and the transmitter) is touched here; the
scenario's radio model is never read.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np

from rfhoming.campaigns import closed_loop
from rfhoming.emulator.links import pipe_end
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import Scenario
from rfhoming.emulator.world import Pose as WorldPose
from rfhoming.emulator.world import World
from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.rss import AntennaPowers
from rfhoming.host.estimation.ranging import LogDistance, fit_log_distance_binned
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import Device, Homing
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.types import ControllerDefaults, Decision, Pose

FAR_M = 5.0  # the drive starts this far from the transmitter
SPEED_MPS = 0.2
DWELL_S = 3.0  # at the stop distance


@dataclass(frozen=True)
class Fit:
    """A log-distance fit RSSI(d) = p0_dbm − 10 n log10(d / 1 m) and the RSSI at the stop."""

    p0_dbm: float
    n: float
    residual_db: float  # std of the readings around the fit
    stop_dbm: float  # mean RSSI while dwelling at the stop distance
    samples: int
    dish_offsets_db: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # S2: each dish's own offset

    def summary(self) -> dict[str, float | list[float]]:
        return {k: [round(x, 3) for x in v] if isinstance(v, tuple) else round(float(v), 3)
                for k, v in self.__dict__.items()}


BORESIGHTS_RAD = (0.0, math.pi, math.pi / 2, -math.pi / 2)
"""S2's dishes x1, x2, y1, y2 (host.estimation.particle's axes): where each one points."""
TURN_DWELL_S = 1.5


@dataclass
class Recorder(ControllerDefaults):
    """A controller for the homing loop that drives straight ahead until the odometry pose is
    ``stop_m`` from ``point``, dwells there, optionally turns in place by quarter turns (dwelling
    at each, so each of S2's dishes faces the transmitter in turn), and records every reading
    with the distance and the bearing of ``point`` from the robot's heading."""

    point: tuple[float, float]
    stop_m: float
    value: Any  # reading -> what to keep of it (RSSI in dBm, or the four dish powers), or None
    quarter_turns: int = 0
    source: str = "calibration"
    phase: str = "driving"
    reported: Any = None
    uses_planner: bool = False
    samples: list[tuple[float, float, str, Any]] = field(default_factory=list)  # distance, bearing, phase, value
    _until: float | None = None
    _turns_done: int = 0
    _heading: float | None = None
    _t: float = 0.0

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        value = self.value(item)
        if value is None:
            return None
        self._t = t
        bearing = math.remainder(math.atan2(self.point[1] - pose.y, self.point[0] - pose.x) - pose.theta, 2 * math.pi)
        self.samples.append((math.dist((pose.x, pose.y), self.point), bearing, self.phase, value))
        return {}

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        d = math.dist((pose.x, pose.y), self.point)
        if self.phase == "driving" and d > self.stop_m:
            return Decision(min(SPEED_MPS, d - self.stop_m + 0.02), 0.0, None, False, "calibration drive")
        if self._until is None:
            self.phase, self._until, self._heading = "dwelling", self._t + DWELL_S, pose.theta
        if self._t < self._until:
            return Decision(0.0, 0.0, None, False, "calibration dwell")
        if self._turns_done >= self.quarter_turns:
            return Decision(0.0, 0.0, None, True, "calibration done")
        self.phase = "turning"
        assert self._heading is not None  # set on arrival at the stop
        error = math.remainder(self._heading + (self._turns_done + 1) * math.pi / 2 - pose.theta, 2 * math.pi)
        if abs(error) > math.radians(2):
            return Decision(0.0, max(-0.6, min(0.6, 1.5 * error)), None, False, "calibration turn")
        self._turns_done += 1
        self._until = self._t + TURN_DWELL_S
        return Decision(0.0, 0.0, None, False, "calibration dwell")

    def estimate(self) -> dict[str, Any]:
        return {}


def _aoa_rssi(item: Any) -> float | None:
    return item.rssi if isinstance(item, Bearing) else None


def _dish_powers(item: Any) -> tuple[float, ...] | None:
    if isinstance(item, AntennaPowers) and all(p is not None for p in item.dbm):
        return tuple(float(p) for p in item.dbm)  # type: ignore[arg-type]
    return None


async def _record(scenario: Scenario, seed: int, device: str, recorder: Recorder) -> Recorder:
    em = Emulator(scenario, transport="pipe", seed=seed, lockstep=True, lockstep_timeout=2.0)
    await em.start()
    world = asyncio.create_task(em.run())
    try:
        def port(name: str) -> closed_loop.PipePort:
            return closed_loop.PipePort(name, pipe_end(em.device(name).link))

        role = "aoa" if device in ("aoa", "dock_aoa") else "rss"
        config = Config().for_lockstep()
        config = replace(config, avoid=replace(config.avoid, enabled=False),
                         loop=replace(config.loop, max_time_s=120.0))
        plan = Homing(recorder, [Device("base", port=port("base")), Device(role, port=port(device))], config)
        await asyncio.wait_for(assembly.run(plan), 600)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    return recorder


def _place(scenario: Scenario, robot: tuple[float, float, float], target: tuple[float, float] | None) -> Scenario:
    """The user's calibration set-up: an empty room with the robot and transmitter where chosen."""
    targets = scenario.world.targets
    if target is not None:
        targets = [replace(targets[0], position=target), *targets[1:]]
    scenario.world = World(WorldPose(*robot), targets, [], (-20.0, -20.0, 20.0, 20.0))
    return scenario


def calibrate(scenario: Scenario, seed: int) -> Fit:
    """Drive toward the scenario's first transmitter (or, with a docking station, the robot's
    tag toward the station) from FAR_M to its stop distance; fit the readings."""
    names = {d.name for d in scenario.devices}
    if "dock_aoa" in names:
        station = scenario.world.targets[0]
        sx, sy = station.position
        h = station.heading
        stop = Config().s1.standoff_m
        start = (sx - FAR_M * math.cos(h), sy - FAR_M * math.sin(h), h)
        rec = Recorder((sx, sy), stop, _aoa_rssi)
        device = "dock_aoa"
        scenario = _place(scenario, start, None)
    else:
        device = "aoa" if "aoa" in names else "rss"
        stop = 0.5 if device == "aoa" else 1.0
        rec = Recorder((FAR_M, 0.0), stop, _aoa_rssi) if device == "aoa" else Recorder((FAR_M, 0.0), stop, _dish_powers, 3)
        scenario = _place(scenario, (0.0, 0.0, 0.0), (FAR_M, 0.0))
    rec = asyncio.run(_record(scenario, seed, device, rec))
    if len(rec.samples) < 20 or not any(s[2] == "dwelling" for s in rec.samples):
        raise RuntimeError(f"calibration of {scenario.name} heard only {len(rec.samples)} readings")
    offsets = (0.0, 0.0, 0.0, 0.0)
    if device == "rss":
        offsets = dish_offsets(rec.samples)
        samples = [(d, b, ph, max(p - o for p, o in zip(v, offsets))) for d, b, ph, v in rec.samples if ph != "turning"]
    else:
        samples = rec.samples
    d = np.array([s[0] for s in samples])
    rssi = np.array([s[3] for s in samples])
    fit = fit_log_distance_binned(np.maximum(d, 0.05), rssi)
    assert isinstance(fit.model, LogDistance)
    stop_dbm = float(np.mean([s[3] for s in samples if s[2] == "dwelling"]))
    return Fit(fit.model.p0_dbm, fit.model.n, fit.rssi_residual_db or 0.0, stop_dbm, len(samples), offsets)


def dish_offsets(samples: list[tuple[float, float, str, Any]]) -> tuple[float, float, float, float]:
    """Each dish's power while it faced the transmitter (within 10°), at the stop distance,
    relative to the four dishes' mean: the chips' and dishes' own offsets, as S2's A1/A2
    calibration would take them."""
    means = []
    for i, boresight in enumerate(BORESIGHTS_RAD):
        facing = [v[i] for d, b, ph, v in samples if ph != "driving"
                  and abs(math.remainder(b - boresight, 2 * math.pi)) < math.radians(10)]
        if not facing:
            raise RuntimeError(f"calibration: dish {i} never faced the transmitter")
        means.append(float(np.mean(facing)))
    m = float(np.mean(means))
    return tuple(round(v - m, 2) for v in means)  # type: ignore[return-value]


CALIBRATION_SEED = 0xCA1
"""Calibration sessions use seeds of their own, never a homing run's."""


def with_noise(scenario: Scenario, noise: tuple[float, float, float] | None) -> Scenario:
    """The scenario with its radio's fast and per-link RSSI σ (dB) and AoA σ (°) replaced
    (a campaign's noise level; None keeps the scenario's)."""
    if noise is not None:
        fast, link, angle = noise
        scenario.path_loss = replace(scenario.path_loss, fast_sigma_db=fast, link_sigma_db=link)
        scenario.aoa = replace(scenario.aoa, angle_deg=angle)
    return scenario


def load(name: str, seed: int, aoa_preset: int | None = None, radio: str = "ideal") -> Scenario:
    from rfhoming.emulator.scenario import load as load_scenario

    return load_scenario(name, seed=seed, aoa_preset=aoa_preset, radio=radio)


@lru_cache(maxsize=32)
def cached(name: str, seed: int, aoa_preset: int | None = None,
           noise: tuple[float, float, float] | None = None, radio: str = "ideal") -> Fit:
    """One calibration per (scenario, campaign seed, noise, radios), reused by a process's jobs:
    deterministic, so inline, processes and Dask agree."""
    session = CALIBRATION_SEED + seed
    return calibrate(with_noise(load(name, session, aoa_preset, radio), noise), session)
