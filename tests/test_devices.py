"""The device table (rfhoming.protocol.devices) is complete: every kind's pieces exist and
agree -- decoder, driver, emulated boards and their firmware, roles, capture round trip, export
topics, a docs row -- and a new kind needs nothing but its record and the pieces it names."""

from __future__ import annotations

import inspect
from collections.abc import Mapping
import logging
import re
from dataclasses import replace
from pathlib import Path

import pytest

from rfhoming.emulator import devices as runners
from rfhoming.emulator.scenario import ScenarioError, load
from rfhoming.host import portspec
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.common import Driver
from rfhoming.host.drivers.rss import RssDriver
from rfhoming.host.replay import load_capture
from rfhoming.host.session import driver_class, make_driver, recorded_kind
from rfhoming.protocol import devices, pcapng
from test_api_kinds import item_types as api_items

ROOT = Path(__file__).resolve().parent.parent
KINDS = sorted(devices.KINDS)


@pytest.mark.parametrize("name", KINDS)
def test_each_kind_is_complete(name: str) -> None:
    record = devices.KINDS[name]
    decoder = devices.load(record.wire.decoder)()
    items = decoder.feed(b"\x00garbage\r\n" * 3)  # sans-IO: bytes in, a list of items out, no raise
    assert isinstance(items, list) and isinstance(decoder.counters, Mapping)  # what it drops, it counts
    driver = driver_class(record)
    assert issubclass(driver, Driver) and driver.kind == name
    assert set(record.roles) <= set(devices.ROLES) and record.roles
    assert record.settings and all(callable(parse) for parse in record.settings.values())
    assert set(driver.items) <= set(api_items()) and (record.usb is None or record.usb.vendors)
    assert record.setup_timeout_s > 0 and (record.boards or record.emulated_as)
    for board in record.boards:
        firmware = devices.load(board.firmware)
        assert inspect.isclass(firmware) and firmware.__module__.startswith("rfhoming.firmware.")
        runner = devices.load(board.runner)
        assert issubclass(runner, runners.DeviceRunner) and runner.board == board.name


def test_the_emulator_has_a_runner_for_every_board_and_no_other() -> None:
    boards = {cls.board for cls in vars(runners).values()
              if inspect.isclass(cls) and issubclass(cls, runners.DeviceRunner) and cls.board != "device"}
    assert boards == set(devices.BOARDS)


def test_a_kind_with_no_board_says_how_the_emulator_serves_it(tmp_path: Path) -> None:
    served = [k for k in devices.KINDS.values() if not k.boards]
    assert served
    for record in served:
        scenario = tmp_path / f"{record.name}.toml"
        scenario.write_text(f'name = "x"\nbounds = [0, 0, 5, 5]\n[devices.robot]\ntype = "{record.name}"\n')
        with pytest.raises(ScenarioError, match=re.escape(f"served by {record.emulated_as}")):
            load(scenario)


def test_every_role_defaults_to_a_kind_that_can_fill_it() -> None:
    for role in devices.ROLES.values():
        assert role.name in devices.KINDS[role.default_kind].roles


@pytest.mark.parametrize("name", KINDS)
def test_a_port_spec_names_each_kind_and_builds_its_driver(name: str) -> None:
    where = "serial:/dev/ttyUSB9" if name == "hci" else "/dev/ttyUSB9"
    spec = portspec.parse(f"{name}:{where}")
    assert spec.kind == name and spec.device is devices.KINDS[name]
    driver = make_driver(spec, [])
    assert driver.kind == name and driver.port.name == where.removeprefix("serial:")


@pytest.mark.parametrize(("alias", "name"), [(a, k.name) for k in devices.KINDS.values() for a in k.aliases])
def test_old_spellings_are_aliases_with_a_one_line_notice(alias: str, name: str, caplog) -> None:
    devices._told.discard(alias)
    with caplog.at_level(logging.WARNING):
        assert portspec.parse(f"{alias}:/dev/ttyUSB9").kind == name
        portspec.parse(f"{alias}:/dev/ttyUSB8")
    notices = [r.getMessage() for r in caplog.records if alias in r.getMessage()]
    assert len(notices) == 1 and name in notices[0] and "\n" not in notices[0]


@pytest.mark.parametrize("name", KINDS)
def test_a_capture_records_the_canonical_kind_and_replay_needs_no_guessing(name: str, tmp_path: Path) -> None:
    writer = CaptureWriter(tmp_path / "c.pcapng")
    alias = (devices.KINDS[name].aliases or (name,))[0]
    writer.describe("/dev/ttyUSB9", kind=alias)
    writer.tap("/dev/ttyUSB9", "in", 1.0, b"x")
    writer.close()
    interfaces, _, _ = load_capture(tmp_path / "c.pcapng")
    assert "kind=" + name in interfaces[0].description
    assert interfaces[0].linktype == devices.KINDS[name].wire.linktype
    assert recorded_kind(interfaces[0]) is devices.KINDS[name]


@pytest.mark.parametrize(("description", "linktype", "name"), [
    ("protocol=ublox-aoa kind=xplr-aoa", pcapng.LINKTYPE_UCONNECT, "xplr-aoa"),  # before the device table
    ("protocol=rss kind=base", pcapng.LINKTYPE_FRAMES, "base"),
    ("protocol=rss kind=rss-node", pcapng.LINKTYPE_FRAMES, "rss-node"),
    ("protocol=rss kind=esp32", pcapng.LINKTYPE_FRAMES, "rss-node"),
    ("protocol=rss", pcapng.LINKTYPE_FRAMES, "rss-node"),
    ("protocol=esp-at kind=esp-at", pcapng.LINKTYPE_ESP_AT, "esp-at"),
    ("protocol=hci kind=hci", pcapng.LINKTYPE_H4_STREAM, "hci"),
    ("", pcapng.LINKTYPE_UCONNECT, "xplr-aoa"),
])
def test_older_captures_keep_working(description: str, linktype: int, name: str) -> None:
    assert recorded_kind(pcapng.Interface("/dev/x", description, linktype)).name == name


def test_docs_architecture_has_a_row_per_kind_and_the_checklist() -> None:
    text = (ROOT / "docs" / "architecture.md").read_text()
    rows = set(re.findall(r"^\| `([a-z0-9-]+)` \|", text, flags=re.M))
    assert set(devices.KINDS) <= rows
    assert "## Adding a device" in text


class ProbeDriver(RssDriver):
    """A new kind's driver: rfhoming's frames from a made-up board."""

    kind = "probe-node"


def test_a_new_kind_needs_only_its_record(monkeypatch, tmp_path: Path) -> None:
    """docs/architecture.md "Adding a device", tried: one record naming its pieces, and the
    port spec, driver, capture and replay all know the kind."""
    record = replace(devices.KINDS["rss-node"], name="probe-node", driver=f"{__name__}:ProbeDriver", aliases=(),
                     roles=("ble",), boards=())
    monkeypatch.setitem(devices.KINDS, "probe-node", record)
    spec = portspec.parse("probe-node:/dev/ttyUSB7,baud=230400")
    driver = make_driver(spec, [])
    assert isinstance(driver, ProbeDriver) and driver.port.baud == 230400
    writer = CaptureWriter(tmp_path / "p.pcapng")
    writer.describe("/dev/ttyUSB7", kind="probe-node")
    writer.tap("/dev/ttyUSB7", "in", 1.0, b"\x00")  # a capture is written once a port gave it a packet
    writer.close()
    assert recorded_kind(load_capture(tmp_path / "p.pcapng")[0][0]) is record
    with pytest.raises(portspec.PortSpecError, match="unknown device kind 'probe-nod'"):
        portspec.parse("probe-nod:/dev/ttyUSB7")


def test_devices_kinds_says_what_each_kind_reports(capsys) -> None:
    """``rfhoming devices --kinds``: every kind, and an AoA board's azimuths, elevation and rate
    (a kind that fills the anchor role must say them: a site's field of view rests on them)."""
    import json

    from rfhoming.cli.main import main

    for name in KINDS:
        r = devices.KINDS[name].reports
        assert r.readings, name
        if "anchor" in devices.KINDS[name].roles:
            assert r.azimuth_deg is not None and r.rate, name
    assert main(["devices", "--kinds", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [x["kind"] for x in lines] == [*devices.KINDS, "angles"]
    assert lines[0]["azimuth_deg"] == [-90.0, 90.0] and lines[0]["elevation"] is True
    assert lines[-1]["azimuth_deg"] == [-180.0, 180.0]
    assert main(["devices", "--kinds"]) == 0
    assert "xplr-aoa   bearings (+UUDF); azimuth -90..90 deg, elevation yes; RSSI" in capsys.readouterr().out
