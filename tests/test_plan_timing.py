"""Planning never blocks control: a planner that takes a second of wall time per plan, given to
the run assembly, leaves the loop commanding every control period, and its plans take effect
at their fixed robot time. Every assertion is on robot time and counts, none on wall time."""

from __future__ import annotations

import asyncio
import io
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rfhoming.campaigns.closed_loop import PipePort
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import Device, Homing, replay_plan, run_record
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import ODOMETRY_PERIOD_S, Outcome, RunLog
from rfhoming.host.homing.planner import TcodPlanner

SCENARIO, SEED = "s0-house", 1


class SlowPlanner:
    """libtcod's plan, handed back after ``seconds`` of wall time and once ``gate`` says so."""

    def __init__(self, seconds: float = 1.0, gate: Any = None) -> None:
        self.seconds, self.gate, self.calls = seconds, gate, 0

    def __call__(self, costs: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> Any:
        self.calls += 1
        time.sleep(self.seconds)
        while self.gate is not None and not self.gate():
            time.sleep(0.01)
        return TcodPlanner()(costs, start, goal)


async def home(config: Config, planner: Any = None, listener: Any = None, capture: Path | None = None
               ) -> tuple[Outcome, list[dict[str, Any]]]:
    """S0 in the house, in lockstep on the in-process pipe; the world waits for the host as long
    as it takes (no lockstep timeout to race the slow planner). ``capture``: a capture of the
    run, with its record, as `rfhoming demo --in-process` makes."""
    em = Emulator(load(SCENARIO, seed=SEED), transport="pipe", seed=SEED, lockstep=True, lockstep_timeout=600.0)
    await em.start()
    world = asyncio.create_task(em.run())
    out = io.StringIO()
    runlog = RunLog(out, [listener] if listener else [])
    base, aoa = (PipePort(name, em.device(name).link.host) for name in ("base", "aoa"))
    plan = Homing("aoa", [Device("aoa", port=aoa, kind="xplr-aoa"), Device("base", port=base)], config,
                  runlog=runlog, planner=planner)
    if capture is not None:
        plan.capture = CaptureWriter(capture, comment=run_record(plan))
        for device in plan.devices:
            device.port.taps.append(plan.capture.tap)
            plan.capture.describe(device.port.name, kind=device.kind or "base", role=device.role)
    try:
        outcome = await asyncio.wait_for(assembly.run(plan), 600)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
        if plan.capture is not None:
            plan.capture.close()
    return outcome, [json.loads(line) for line in out.getvalue().splitlines()]


def live(replan_s: float = 60.0) -> tuple[Config, SlowPlanner, Any]:
    """A run that does not wait for its plans (as live), on the lockstep world; its planner takes
    a second and hands its plan back only once the loop has sent ten commands since it asked, so
    the plan is late by count, whatever the machine's speed. And a run log listener to count."""
    config = lockstep(replan_s)
    sent: dict[str, int] = {"commands": 0}  # and "asked": the count when the first plan was asked for

    def listen(record: dict[str, Any]) -> None:
        sent["commands"] += record["kind"] == "command"
        if record.get("what") == "plan asked":
            sent.setdefault("asked", sent["commands"])

    slow = SlowPlanner(1.0, gate=lambda: "asked" in sent and sent["commands"] - sent["asked"] >= 10)
    return replace(config, plan=replace(config.plan, wait=False)), slow, listen


def lockstep(replan_s: float = 1.0) -> Config:
    config = Config().for_lockstep()
    return replace(config, plan=replace(config.plan, replan_s=replan_s))


@pytest.mark.slow
def test_a_slow_planner_changes_nothing_in_lockstep_its_plans_land_at_their_robot_time() -> None:
    config = lockstep()
    fast, fast_log = asyncio.run(home(config))
    slow = SlowPlanner(1.0)
    outcome, log = asyncio.run(home(config, slow))
    assert outcome.plans >= 2
    assert log == fast_log  # line for line: a second per plan moved nothing the robot did
    assert outcome.summary()["commands"] == fast.summary()["commands"]
    asked = {r["t"]: r for r in log if r.get("what") == "plan asked"}
    plans = [r for r in log if r["kind"] == "plan"]
    period = config.loop.control_period_s
    assert plans and len(plans) >= len(asked) - 1  # the last may still be pending at arrival
    unplanned = sorted(set(asked) - {plan["asked"] for plan in plans})
    assert unplanned in ([], [max(asked)]), unplanned  # only the last
    # every plan asked reached the planner, but the last may not have started when the run arrived
    assert slow.calls == outcome.plans or (unplanned and slow.calls == outcome.plans - 1), (slow.calls, outcome.plans)
    for plan in plans:
        assert plan["asked"] in asked and "late" not in plan
        # taken at the first control period at or after asked + latency, in robot time
        assert plan["t"] - plan["asked"] == pytest.approx(asked[plan["asked"]]["due"] - plan["asked"], abs=period + 1e-6)
        assert plan["t"] >= asked[plan["asked"]]["due"] - 1e-6
    commands = [r["t"] for r in log if r["kind"] == "command"]
    assert max(np.diff(commands)) <= period + ODOMETRY_PERIOD_S  # a command every control period, plans or not
    assert outcome.plans_late == 0


@pytest.mark.slow
def test_live_the_loop_commands_every_period_while_a_slow_plan_is_computed() -> None:
    """Live (the loop does not wait): the plan is late, the robot is controlled on regardless,
    and the plan is logged late."""
    config, slow, listen = live()

    outcome, log = asyncio.run(home(config, slow, listen))
    asked = next(r for r in log if r.get("what") == "plan asked")
    late = next(r for r in log if r.get("what") == "plan late")
    assert outcome.plans_late >= 1 and late["t"] >= asked["due"] - 1e-6
    applied = next((r for r in log if r["kind"] == "plan"), None)
    until = applied["t"] if applied is not None else outcome.robot_time_s
    while_planning = [r["t"] for r in log if r["kind"] == "command" and asked["t"] <= r["t"] <= until]
    period = config.loop.control_period_s
    assert len(while_planning) >= 10
    assert max(np.diff(while_planning)) <= period + ODOMETRY_PERIOD_S  # one every control period, none skipped
    assert applied is None or (applied["late"] and applied["asked"] == asked["t"])
    events = {r.get("what") for r in log}
    assert not any(str(e).endswith("stale: stop") for e in events)


@pytest.mark.slow
def test_a_live_run_whose_plan_was_late_replays_to_the_same_run_log(tmp_path: Path) -> None:
    """When a late plan took effect depended on the wall clock; the capture notes it, and
    `replay --run` (which waits for its plans) takes it at that robot time again."""
    config, slow, listen = live(replan_s=5.0)
    outcome, log = asyncio.run(home(config, slow, listen, capture=tmp_path / "run.pcapng"))
    assert outcome.plans_late >= 1 and any(r["kind"] == "plan" and r.get("late") for r in log)
    again = replay_plan(tmp_path / "run.pcapng")
    assert again.config.plan.wait and again.plans_taken
    out = io.StringIO()
    again.runlog = RunLog(out)
    asyncio.run(assembly.run(again))
    ports = [d.port for d in again.devices]
    assert sum(p.counters["diverged"] + p.counters["unanswered"] for p in ports) == 0
    live_log = [r for r in log if r["kind"] != "stall"]  # the live loop's stalls: wall time
    assert [json.loads(line) for line in out.getvalue().splitlines()] == live_log
