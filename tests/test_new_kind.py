"""A new device kind from the template (host/drivers/driver_proto.py) and its one record, added to
the device table at test time, works through the same paths as every kind: the port spec with
its own setting, the session and the run assembly building its driver, sniffing, the emulator's
runner for its board, the Python API's items, a capture and the MCAP export's topics."""

from __future__ import annotations

import asyncio
import contextlib
import typing
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

import rfhoming
from rfhoming.api import Item
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import ScenarioError, load
from rfhoming.host.drivers.driver_proto import RECORD, ProtoDriver
from rfhoming.host.export.recorder import export
from rfhoming.host.homing.assembly import Device, Homing, build
from rfhoming.host.homing.config import Config
from rfhoming.host.portspec import PortSpecError, parse
from rfhoming.host.replay import load_capture
from rfhoming.host.session import make_driver, recorded_kind, what_speaks
from rfhoming.protocol import devices
from rfhoming.protocol.frames import AdvReport, Odometry, encode_frame

DEADLINE_S = 60.0  # generous: the items come as fast as the loaded machine lets the emulator run
WANTED = 20  # AdvReports read before the stream is left


@pytest.fixture
def proto(monkeypatch: pytest.MonkeyPatch) -> Iterator[devices.DeviceKind]:
    """The template's record in the device table (and its board in BOARDS) for one test."""
    monkeypatch.setitem(devices.KINDS, RECORD.name, RECORD)
    for board in RECORD.boards:
        monkeypatch.setitem(devices.BOARDS, board.name, (RECORD, board))
    yield RECORD


def test_without_its_record_the_kind_is_unknown() -> None:
    with pytest.raises(PortSpecError, match="unknown device kind 'proto-node'"):
        parse("proto-node:/dev/ttyUSB7")


def test_its_port_spec_takes_its_own_setting(proto: devices.DeviceKind) -> None:
    spec = parse("proto-node:/dev/ttyUSB7,baud=230400,min_rssi=-80")
    assert spec.device is proto and dict(spec.settings) == {"baud": 230400, "min_rssi": -80}
    with pytest.raises(PortSpecError, match=r"bad min_rssi='loud'.*dBm from -127 to 20"):
        parse("proto-node:/dev/ttyUSB7,min_rssi=loud")
    with pytest.raises(PortSpecError, match=r"unknown setting 'tags'.*min_rssi"):
        parse("proto-node:/dev/ttyUSB7,tags=CCF9578E0D8A")
    with pytest.raises(PortSpecError, match="unknown setting 'min_rssi'"):
        parse("rss-node:/dev/ttyUSB7,min_rssi=-80")  # the setting is the kind's, not everyone's


def test_the_session_and_the_run_assembly_build_its_driver(proto: devices.DeviceKind) -> None:
    driver = make_driver(parse("proto-node:/dev/ttyUSB7,baud=230400,min_rssi=-80"), [])
    assert isinstance(driver, ProtoDriver) and driver.min_rssi == -80 and driver.port.baud == 230400
    anchors = {"AABBCCDDEE01": [0.0, 0.0], "AABBCCDDEE02": [4.0, 0.0], "AABBCCDDEE03": [0.0, 4.0]}
    config = replace(Config(), trilat=replace(Config().trilat, anchors=anchors))
    plan = Homing("trilat", [Device("ble", "proto-node:/dev/ttyUSB7,min_rssi=-70"), Device("base", "base:/dev/ttyUSB8")],
                  config)
    sensor, = build(plan).loop.sensors
    assert isinstance(sensor, ProtoDriver) and sensor.min_rssi == -70


def test_sniffing_tells_it_by_its_drivers_test(proto: devices.DeviceKind) -> None:
    advert = encode_frame(AdvReport(1, 1, 1000, b"\x01\x02\x03\x04\x05\x06", 0, 0, -60, 127, 37, b""))
    odometry = encode_frame(Odometry(1, 2, 1000, 0, 0, 0, 0, 0, 0))
    assert what_speaks(advert) == "proto-node"  # its test is stricter, so it is tried first
    assert what_speaks(odometry) == "rss-node"  # any other frame is still a node's


def test_the_items_it_yields_are_api_items() -> None:
    assert set(ProtoDriver.items) <= set(typing.get_args(Item))


async def test_its_emulated_board_is_sniffed_read_captured_and_exported(proto: devices.DeviceKind,
                                                                         tmp_path: Path) -> None:
    scenario = load("s3-arena", seed=3)
    receiver = next(d for d in scenario.devices if d.type == "esp32")
    receiver.type = "proto-node"
    em = Emulator(scenario, transport="pty", seed=3, speed=4.0, link_dir=tmp_path)
    endpoint = next(e for e in await em.start() if e["device"] == receiver.name)
    assert endpoint["type"] == "proto-node" and endpoint["kind"] == "proto-node"
    run = asyncio.create_task(em.run())
    adverts: list[AdvReport] = []
    try:
        devices_ = rfhoming.open(endpoint["path"], capture=tmp_path / "c.pcapng")  # no KIND: sniffed
        async with asyncio.timeout(DEADLINE_S), contextlib.aclosing(devices_.stream()) as stream:
            async for got in stream:
                assert isinstance(got.item, typing.get_args(Item))
                adverts += [got.item] if isinstance(got.item, AdvReport) else []
                if len(adverts) >= WANTED:
                    break
        assert [type(d) for d in devices_.drivers] == [ProtoDriver]
    finally:
        run.cancel()
        await asyncio.gather(run, return_exceptions=True)
        await em.close()
    interfaces, _, _ = load_capture(tmp_path / "c.pcapng")
    assert recorded_kind(interfaces[0]) is proto
    summary = export(tmp_path / "c.mcap", capture=tmp_path / "c.pcapng")
    assert summary["topics"]["/rfhoming/ble/rssi"] >= WANTED


def test_an_unknown_board_is_an_error_naming_it() -> None:
    scenario = load("s3-arena", seed=3)
    next(d for d in scenario.devices if d.type == "esp32").type = "proto-node"  # no record: no such board
    with pytest.raises(ScenarioError, match=r"unknown type 'proto-node'.*esp32"):
        Emulator(scenario, transport="pipe")


def test_the_checklist_names_every_field_of_a_record() -> None:
    """docs/architecture.md says what each field of a record is for: none is left out."""
    text = (Path(__file__).resolve().parent.parent / "docs" / "architecture.md").read_text()
    for table in (devices.DeviceKind, devices.Board, devices.UsbBridge):
        missing = [f for f in table.__dataclass_fields__ if f"`{f}`" not in text]
        assert not missing, (table.__name__, missing)
