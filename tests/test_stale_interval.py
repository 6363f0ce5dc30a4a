"""The stale timeout follows the tag's advertising interval (20 ms to 1 s; a fixed
0.5 s timeout stopped a 1000 ms tag's robot for good), closed loop in lockstep."""

from __future__ import annotations

import asyncio
import io
import json
from dataclasses import replace
from pathlib import Path

import pytest
from loops import loop_on

from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.homing.config import Config, LoopSettings
from rfhoming.host.homing.loop import RunLog
from rfhoming.host.ports import HostPort


async def run_with_tag_interval(tmp_path: Path, interval_ms: float, loop: LoopSettings):
    scenario = load("s0-open", seed=2, target=(6.0, 4.0))
    scenario.world.targets[0].interval_ms = interval_ms  # a 2.x tag may advertise once a second
    em = Emulator(scenario, transport="pty", seed=2, lockstep=True, link_dir=tmp_path, lockstep_timeout=2.0)
    await em.start()
    world = asyncio.create_task(em.run())
    out = io.StringIO()
    homing = loop_on("aoa", HostPort(str(tmp_path / "base")), HostPort(str(tmp_path / "aoa")),
                     replace(Config(), loop=loop).for_lockstep(), RunLog(out))
    try:
        outcome = await asyncio.wait_for(homing.run(), 90)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    return outcome, homing, [json.loads(line) for line in out.getvalue().splitlines()]


async def test_a_one_second_tag_does_not_stop_the_robot_between_readings(tmp_path: Path) -> None:
    outcome, homing, log = await run_with_tag_interval(tmp_path, 1000.0, LoopSettings(max_time_s=15.0))
    assert outcome.stale_stops <= 1  # at most before the first interval is known
    assert homing.stale_timeout() == pytest.approx(3.0, abs=0.3)
    late = [e for e in log if e["kind"] == "command" and e["t"] > 5.0]
    assert late and sum(e["note"] == "stale" for e in late) == 0


async def test_the_rule_can_be_switched_off(tmp_path: Path) -> None:
    outcome, homing, log = await run_with_tag_interval(tmp_path, 1000.0, LoopSettings(max_time_s=8.0, stale_intervals=0))
    assert homing.stale_timeout() == homing.config.loop.stale_timeout_s  # the fixed timeout only
    readings = [r for r in log if r["kind"] == "measurement"]
    # stopped between every two readings (how many come in 8 s depends on how long the set-up took)
    assert len(readings) >= 3 and outcome.stale_stops >= len(readings) - 1
