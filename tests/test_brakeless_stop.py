"""Stale data stops a base without a brake mode (a ROS 2 base) within ``[loop] stop_within_m``.

The loop is fed by hand (robot time from the items alone, no clock) and drives a model base
that follows its commands as the emulated one does: speed changes at most ``a`` m/s² -- its
normal rate, or 4 m/s² in brake mode for rfhoming's serial base. The readings end; the test
measures the distance the model drives from then until it is at rest.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from loops import loop_on

from rfhoming.host.drivers.robot_base import Pose2D
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import HomingLoop, RunLog
from rfhoming.host.homing.types import ControllerDefaults, Decision, Pose
from rfhoming.host.ports import HostPort

STEP_S = 0.02  # the base's 50 Hz odometry
EMERGENCY_DECEL = 4.0  # rfhoming's base in brake mode (firmware_py/robot_base.py)


class FullSpeed(ControllerDefaults):
    """Takes every non-odometry item as a reading and asks for 0.7 m/s straight on, always."""

    source = "aoa"
    phase = "homing"
    reported = None

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        return {}

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        return Decision(0.7, 0.2, None, False, "on")

    def estimate(self) -> dict[str, Any]:
        return {}


class ModelBase:
    """A base's wheels: speed moves toward the command at ``decel`` (``EMERGENCY_DECEL`` while
    shedding in brake mode, if it ``brakes``), speeding up at 1 m/s²."""

    def __init__(self, decel: float, brakes: bool) -> None:
        self.decel, self.brakes = decel, brakes
        self.v = self.target = 0.0
        self.braking = False
        self.commands: list[float] = []

    def command(self, v: float, w: float) -> bool:
        self.target = v
        self.commands.append(v)
        return True

    def brake(self, on: bool) -> bool:
        self.braking = on and self.brakes
        return True

    def step(self, dt: float) -> float:
        """Advance ``dt`` seconds; returns the distance driven."""
        shedding = abs(self.target) < abs(self.v)
        a = (EMERGENCY_DECEL if self.braking else self.decel) if shedding else 1.0
        before = self.v
        self.v += max(-a * dt, min(a * dt, self.target - self.v))
        return (before + self.v) / 2 * dt


def loop_with(tmp_path: Path, base_kind: str, config: Config) -> tuple[HomingLoop, ModelBase, io.StringIO]:
    out = io.StringIO()
    loop = loop_on(FullSpeed(), HostPort(str(tmp_path / "base")), HostPort(str(tmp_path / "aoa")), config,
                   RunLog(out), role="aoa", base_kind=base_kind)
    model = ModelBase(config.loop.brakeless_decel_m_s2, brakes=base_kind == "base")
    loop.base.send_velocity = model.command  # type: ignore[method-assign]  # nothing is open
    loop.base.brake = model.brake  # type: ignore[method-assign]
    loop.base.stop = lambda: model.command(0.0, 0.0)  # type: ignore[method-assign]
    return loop, model, out


def driven_after_data_ends(loop: HomingLoop, model: ModelBase, data_ends_s: float, until_s: float = 8.0) -> float:
    """Readings before every odometry until ``data_ends_s``, none after; the model's distance
    from then until ``until_s`` (it must be at rest by then)."""
    x = driven = 0.0
    for k in range(round(until_s / STEP_S)):
        t = k * STEP_S
        if t < data_ends_s:
            loop._on_reading(object())
        loop._on_odometry(Pose2D(t, t, x, 0.0, 0.0, model.v, 0.0, 0))
        step = model.step(STEP_S)
        x += step
        if t >= data_ends_s:
            driven += step
    assert model.v == 0.0 and model.target == 0.0
    return driven


def test_a_brakeless_base_stops_within_the_distance_when_the_data_ends(tmp_path: Path) -> None:
    config = Config()
    for ends in (3.0, 3.02, 3.04, 3.06, 3.08):  # every phase of the 0.1 s control period
        loop, model, out = loop_with(tmp_path, "ros2", config)
        driven = driven_after_data_ends(loop, model, ends)
        assert driven <= config.loop.stop_within_m, (ends, driven)
    assert max(model.commands) == loop.speed_limit < 0.7  # bounded, not stopped
    said = [json.loads(line) for line in out.getvalue().splitlines()]
    assert said[0]["what"] == "no brake mode: speed bounded" and said[0]["v_max"] == round(loop.speed_limit, 4)


def test_a_base_with_brake_mode_keeps_its_full_speed_and_stops_as_soon(tmp_path: Path) -> None:
    config = Config()
    loop, model, out = loop_with(tmp_path, "base", config)
    assert driven_after_data_ends(loop, model, 3.0) <= config.loop.stop_within_m
    assert loop.speed_limit == math.inf and max(model.commands) == 0.7
    assert "speed bounded" not in out.getvalue()


@settings(max_examples=40, deadline=None)
@given(decel=st.floats(0.3, 5.0), within=st.floats(0.1, 1.0), slow_after=st.sampled_from([0.0, 0.04, 0.1, 0.2]),
       ends=st.floats(2.5, 2.6))
def test_the_bound_follows_the_configured_deceleration_and_distance(tmp_path_factory: Any, decel: float,
                                                                     within: float, slow_after: float,
                                                                     ends: float) -> None:
    base = Config()
    config = replace(base, loop=replace(base.loop, brakeless_decel_m_s2=decel, stop_within_m=within,
                                        slow_after_s=slow_after))
    loop, model, _ = loop_with(tmp_path_factory.mktemp("loop"), "ros2", config)
    # one odometry step of slack: the loop sees time in 20 ms steps
    assert driven_after_data_ends(loop, model, ends) <= within + loop.speed_limit * STEP_S
