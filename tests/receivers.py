"""Closed-loop S3 trilateration through an emulated BLE RSSI receiver, shared by the tests of
the ESP-AT and HCI receivers: the live run (with a capture) and its replay."""

from __future__ import annotations

import asyncio
import io
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from loops import loop_on

from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.common import Driver
from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import HomingLoop, RunLog
from rfhoming.host.homing.s3_trilat import TrilatParams
from rfhoming.host.ports import HostPort
from rfhoming.host.replay import ReplayPort, Sequencer, load_capture
from rfhoming.host.session import recorded_kind

GOAL = (4.0, 4.0)


def s3_config(scenario: Any) -> Config:
    """S3 without its survey at the goal (tests/test_s3_survey.py has it): these runs check a
    receiver's bytes through the loop and its replay, and the survey only makes them longer."""
    anchors = {t.id: list(t.position) for t in scenario.world.targets}
    return replace(Config().for_lockstep(), trilat=TrilatParams(anchors=anchors, goal=list(GOAL), survey_m=0.0))


def reading_log(driver: Driver, into: list) -> None:
    """Collect every BLE RSSI reading the driver puts out (the loop shares the stream with the
    base's odometry, so only BleRssi items are taken)."""
    put = driver.out.put

    def tap(item: Any) -> None:
        if isinstance(item, BleRssi):
            into.append(tuple(item))
        put(item)

    driver.out.put = tap


def consumed(loop: HomingLoop, readings: list) -> None:
    """Keep the readings the loop took: one decoded while the loop made its last decision is
    left in its stream, live or replayed, depending on which task ran first."""
    left = sum(isinstance(item, BleRssi) for item in loop.inputs.unread())
    del readings[len(readings) - left:]


async def s3_live(tmp_path: Path, receiver: str, kind: str, seed: int = 1) -> dict[str, Any]:
    """S3 homing with the robot's receiver served as ``receiver``; a capture of both links."""
    sc = load("s3-arena", seed=seed, receiver=receiver)
    em = Emulator(sc, transport="pty", seed=seed, lockstep=True, link_dir=tmp_path, lockstep_timeout=2.0)
    await em.start()
    world = asyncio.create_task(em.run())
    writer = CaptureWriter(tmp_path / "run.pcapng")
    baud = 1_000_000 if kind == "hci" else 115_200  # an HCI controller's UART: bumble's serial default
    base = HostPort(str(tmp_path / "base"), taps=[writer.tap])
    ble = HostPort(str(tmp_path / "ble"), baud=baud, taps=[writer.tap])
    writer.describe(base.name, kind="base")
    writer.describe(ble.name, kind=kind)
    out, readings = io.StringIO(), []
    loop = loop_on("trilat", base, ble, s3_config(sc), RunLog(out), kind=kind)
    sensor = loop.sensors[0]
    reading_log(sensor, readings)
    try:
        outcome = await asyncio.wait_for(loop.run(), 120)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
        writer.close()
    consumed(loop, readings)
    error = math.hypot(em.world.robot.x - GOAL[0], em.world.robot.y - GOAL[1])
    return {"outcome": outcome, "error": error, "log": [json.loads(x) for x in out.getvalue().splitlines()],
            "readings": readings, "sensor": sensor, "emulator": em, "scenario": sc}


async def s3_replay(tmp_path: Path, live: dict[str, Any], kind: str) -> dict[str, Any]:
    """The same loop on the capture's bytes: its readings and log."""
    interfaces, packets, _ = load_capture(tmp_path / "run.pcapng")
    sequencer = Sequencer({iface.name: packets[i] for i, iface in enumerate(interfaces)})
    ports = {recorded_kind(i).name: ReplayPort(i.name, packets[n], sequencer=sequencer) for n, i in enumerate(interfaces)}
    out, readings = io.StringIO(), []
    loop = loop_on("trilat", ports["base"], ports[kind], s3_config(live["scenario"]), RunLog(out), kind=kind)
    sensor = loop.sensors[0]
    reading_log(sensor, readings)
    outcome = await asyncio.wait_for(loop.run(), 60)
    consumed(loop, readings)
    for port in ports.values():  # the replayed host wrote exactly what the live one did
        assert port.counters["diverged"] == port.counters["unanswered"] == 0, (port.name, port.counters)
    return {"outcome": outcome, "log": [json.loads(x) for x in out.getvalue().splitlines()], "readings": readings}
