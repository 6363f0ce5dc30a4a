"""The homing loop's named steps, fed by hand: what the run log says across a base outage and
a base reset (robot time from the items alone, no emulator, no clock)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pytest

from loops import loop_on

from rfhoming.host.drivers.robot_base import Pose2D
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import HomingLoop, RunLog
from rfhoming.host.homing.types import ControllerDefaults, Decision, Pose
from rfhoming.host.ports import HostPort


class Steady(ControllerDefaults):
    """Takes every non-odometry item as a reading and drives straight on."""

    source = "aoa"
    phase = "homing"
    reported = None

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        return {}

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        return Decision(0.2, 0.0, None, False, "on")

    def estimate(self) -> dict[str, Any]:
        return {}


def loop_and_log(tmp_path: Path) -> tuple[HomingLoop, io.StringIO]:
    out = io.StringIO()
    loop = loop_on(Steady(), HostPort(str(tmp_path / "base")), HostPort(str(tmp_path / "aoa")), Config(), RunLog(out),
                   role="aoa")
    loop.base.send_velocity = lambda v, w: True  # type: ignore[method-assign]  # nothing is open
    loop.base.brake = lambda on: True  # type: ignore[method-assign]
    loop.base.stop = lambda: True  # type: ignore[method-assign]
    return loop, out


def odometry(t: float) -> Pose2D:
    return Pose2D(t, t, 0.0, 0.0, 0.0, 0.0, 0.0, 0)


def drive(loop: HomingLoop, start: float, end: float, *, readings: bool = True, clock: float = 0.0) -> None:
    """Odometry every 20 ms of base clock (``clock`` added), a reading just before each."""
    for k in range(round(start / 0.02), round(end / 0.02)):
        if readings:
            loop._on_reading(object())
        loop._on_odometry(odometry(k * 0.02 + clock))


def events(out: io.StringIO) -> list[str]:
    return [r["what"] for r in map(json.loads, out.getvalue().splitlines()) if r["kind"] == "event"]


def test_readings_during_a_base_outage_do_not_call_the_sensor_stale(tmp_path: Path) -> None:
    loop, out = loop_and_log(tmp_path)
    drive(loop, 0.0, 1.0)
    loop.odometry_stale = True  # what _next_item finds after odometry_wall_timeout_s without odometry
    for _ in range(30):  # the XPLR-AOA goes on for 3 s; robot time cannot move without odometry
        loop._on_reading(object())
    drive(loop, 4.0, 5.0)  # the base is back; its clock ran on
    said = events(out)
    assert "odometry fresh again" in said
    assert not any("stale: stop" in e for e in said), said


class Surveying(Steady):
    """A survey: it flies its pattern whether or not anything is heard."""

    needs_fresh_readings = False


def test_a_survey_flies_on_through_silence_and_a_homing_stops(tmp_path: Path) -> None:
    """Silence is what a search meets before it finds anything: the survey's commands go on
    with no reading at all, while a homing controller stops on the same silence."""
    sent: dict[str, list[float]] = {}
    for name, controller in (("homing", Steady()), ("survey", Surveying())):
        loop = loop_on(controller, HostPort(str(tmp_path / "base")), HostPort(str(tmp_path / "aoa")), Config(),
                       RunLog(io.StringIO()), role="aoa")
        speeds = sent[name] = []
        loop.base.send_velocity = lambda v, w, speeds=speeds: speeds.append(v) or True  # type: ignore[method-assign]
        loop.base.brake = lambda on: True  # type: ignore[method-assign]
        loop.base.stop = lambda: True  # type: ignore[method-assign]
        drive(loop, 0.0, 2.0, readings=False)
    assert sent["homing"] and not any(sent["homing"])
    assert sent["survey"] and all(v == 0.2 for v in sent["survey"])


def test_brake_mode_events_say_each_change_once_across_a_base_reset(tmp_path: Path) -> None:
    loop, out = loop_and_log(tmp_path)
    drive(loop, 0.0, 1.0)
    drive(loop, 1.0, 2.0, readings=False)  # the readings stop: slowed, then stale, braking
    drive(loop, 2.0, 3.0)  # fresh again
    drive(loop, 0.0, 1.0, clock=0.0)  # the base restarted: its clock runs from 0 again
    said = events(out)
    after_reset = said[said.index("base clock reset: re-anchored"):]
    assert not any(e.startswith("brake mode") for e in after_reset), said  # re-sent, but the mode did not change
    # stale until the first reading, fresh, stale, fresh: each change said once
    assert [e for e in said if e.startswith("brake mode")] == ["brake mode on", "brake mode off"] * 2, said


@pytest.mark.slow
async def test_the_garbage_collector_leaves_start_up_alone_during_a_run(monkeypatch) -> None:
    """A full collection over start-up's objects (modules, maps, drivers) stalled the real-time
    loop for tens of milliseconds: they are frozen while a run goes, and collectable after it."""
    import gc

    from test_homing import closed_loop_scenario

    from rfhoming.host.homing import loop

    frozen: list[int] = []
    control = loop.HomingLoop._control

    def watched(self, *args, **kwargs):
        frozen.append(gc.get_freeze_count())
        return control(self, *args, **kwargs)

    monkeypatch.setattr(loop.HomingLoop, "_control", watched)
    outcome, _, _ = await closed_loop_scenario("s0-open", 1)
    assert outcome.arrived and frozen and min(frozen) > 10_000  # every control step: start-up frozen
    assert gc.get_freeze_count() == 0  # and given back when the run ended


async def test_a_backlog_is_worked_through_in_bounded_steps(tmp_path: Path, monkeypatch) -> None:
    """Live, the loop hands the event loop back once a pass has worked its step budget, so a
    backlog (the process held up, a slow fix tick) leaves room for the drivers and timers; the
    clock is the test's: every reading costs 2 ms of it, whatever the machine."""
    import asyncio

    from rfhoming.host.homing import loop as homing_loop

    now = [0.0]
    monkeypatch.setattr(homing_loop, "_step_clock", lambda: now[0])
    loop, _ = loop_and_log(tmp_path)
    taken: list[int] = []

    class Slow(Steady):
        def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
            now[0] += 0.002
            taken.append(len(taken))
            return {}

    loop.controller = Slow()
    for k in range(50):  # a backlog: a reading and an odometry record each 20 ms of base clock
        loop.inputs.put(odometry(k * 0.02))
        loop.inputs.put(object())
    seen: list[int] = []  # readings taken each time another task had the event loop

    async def other_work() -> None:
        while len(taken) < 50:
            seen.append(len(taken))
            await asyncio.sleep(0)

    homing, other = asyncio.create_task(loop._loop()), asyncio.create_task(other_work())
    await asyncio.wait_for(other, 10)
    homing.cancel()
    await asyncio.gather(homing, return_exceptions=True)
    steps = [b - a for a, b in zip(seen, seen[1:] + [50]) if b > a]
    assert len(steps) >= 10 and max(steps) <= 3, steps  # a 5 ms budget: three readings a pass


async def test_a_replay_stops_where_the_live_runs_odometry_watchdog_fired(tmp_path: Path) -> None:
    """The watchdog fires on the wall clock, which a capture does not hold: the live run notes the
    robot time and the items taken after that odometry, and its replay (watchdog off) stops there
    too -- the same run log, the same stops. Without the note the replay drives through."""
    from dataclasses import replace

    def loop(config: Config, **plan: Any) -> tuple[HomingLoop, io.StringIO, list[float]]:
        out, stops = io.StringIO(), []
        made = loop_on(Steady(), HostPort(str(tmp_path / "base")), HostPort(str(tmp_path / "aoa")), config, RunLog(out),
                       role="aoa", **plan)
        made.base.send_velocity = lambda v, w: True  # type: ignore[method-assign]  # nothing is open
        made.base.brake = lambda on: True  # type: ignore[method-assign]
        made.base.stop = lambda: stops.append(made.t) or True  # type: ignore[method-assign]
        return made, out, stops

    async def feed(loop: HomingLoop, silent_before: int | None = None) -> None:
        """Odometry every 20 ms for 2 s, a reading before each; after the one at 1 s, three
        readings and no odometry (live: the wall clock says silent before the ``silent_before``-th)."""
        items: list[Any] = []
        for k in range(100):
            items += [object(), odometry(k * 0.02)] + ([object(), object(), object()] if k == 50 else [])
        for i, item in enumerate(items):
            if i == silent_before:
                loop.last_odometry_wall -= 2 * loop.config.loop.odometry_wall_timeout_s
            loop.inputs.put(item)
            got = await loop._next_item()
            if isinstance(got, Pose2D):
                loop._on_odometry(got)
            else:
                loop._on_reading(got)

    # live, its watchdog long (no machine's load fires it here), told it fired before the third reading
    live_config = replace(Config(), loop=replace(Config().loop, odometry_wall_timeout_s=3600.0))
    live, live_out, live_stops = loop(live_config)
    noted: list[dict[str, Any]] = []
    live.note = noted.append
    await feed(live, silent_before=2 * 51 + 2)
    assert noted == [{"odometry_stale": 1.0, "after_items": 2}]
    assert events(live_out).count("odometry stale: stop") == 1 and "odometry fresh again" in events(live_out)
    at = frozenset((n["odometry_stale"], n["after_items"]) for n in noted)
    replayed, replay_out, replay_stops = loop(Config().for_lockstep(), odometry_stale_at=at)
    await feed(replayed)
    assert replay_out.getvalue() == live_out.getvalue() and replay_stops == live_stops == [1.0]
    unnoted, unnoted_out, unnoted_stops = loop(Config().for_lockstep())
    await feed(unnoted)
    assert "odometry stale: stop" not in events(unnoted_out) and unnoted_stops == []


@pytest.mark.parametrize("note", [{"odometry_stale": "soon", "after_items": 2}, {"odometry_stale": 1.0},
                                  {"plan_asked": 1.0, "plan_taken": "late"}, {"plan_asked": [1], "plan_taken": None}])
def test_a_malformed_note_in_a_capture_is_a_capture_error_not_a_traceback(tmp_path: Path, monkeypatch, note) -> None:
    """A capture is input: a host note with a wrong type or a missing field says which capture."""
    from rfhoming.host.capture import CaptureWriter
    from rfhoming.host.homing import assembly
    from rfhoming.protocol.pcapng import CaptureFormatError

    writer = CaptureWriter(tmp_path / "run.pcapng")
    writer.describe("/dev/ttyUSB0", kind="xplr-aoa")
    writer.tap("/dev/ttyUSB0", "in", 1.0, b"+STARTUP\r\n")
    writer.close()
    monkeypatch.setattr(assembly, "_record", lambda path, comments: {"devices": [], "site": None})
    monkeypatch.setattr(assembly, "notes", lambda path: [note])
    with pytest.raises(CaptureFormatError, match="run.pcapng: a host note in the capture is malformed"):
        assembly.replay_plan(tmp_path / "run.pcapng")
