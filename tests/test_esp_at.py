"""ESP32 with Espressif's ESP-AT firmware: the +BLESCAN decoder, the firmware model, the driver,
and closed-loop S3 trilateration with its readings (live and replayed)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from receivers import s3_live, s3_replay
from strategies import chunked

from rfhoming.firmware.esp_at import EspAtFirmware
from rfhoming.host import portspec
from rfhoming.host.drivers.espat import EspAtDriver, EspAtSetup
from rfhoming.host.drivers.espat import setup_from_spec as esp_at_setup
from rfhoming.protocol.espat import MAX_LINE, EspAtDecoder, Final, Info, ScanReport, encode_scan, parse_scan

reports = st.builds(ScanReport, st.text("0123456789ABCDEF", min_size=12, max_size=12), st.integers(-128, 20),
                    st.binary(max_size=31), st.binary(max_size=31), st.integers(0, 3))


@given(st.lists(reports, max_size=20), st.lists(st.integers(1, 40), max_size=5))
def test_scan_lines_round_trip_in_any_chunking(items: list[ScanReport], sizes: list[int]) -> None:
    data = b"".join(encode_scan(r) for r in items)
    decoder, out = EspAtDecoder(), []
    for piece in chunked(data, sizes):
        out += decoder.feed(piece)
    assert out == items and decoder.counters["scan_report"] == len(items)


def test_documented_example_lines_decode() -> None:
    # the lines of Espressif's "Bluetooth LE AT Examples" page
    got = EspAtDecoder().feed(b'+BLESCAN:"5b:3b:6c:51:90:49",-87,02011a020a0c0aff4c001005071c3024dc,,1\r\n'
                              b'+BLESCAN:"24:0a:c4:d6:e4:46",-29,,,0\r\n+BLESCANDONE\r\n')
    assert got[0] == ScanReport("5B3B6C519049", -87, bytes.fromhex("02011a020a0c0aff4c001005071c3024dc"), b"", 1)
    assert got[1] == ScanReport("240AC4D6E446", -29, b"", b"", 0)
    assert got[2].kind == "event" and got[2].what == "blescandone"


@pytest.mark.parametrize("line", [b'+BLESCAN:"5b:3b:6c:51:90",-87,,,1', b'+BLESCAN:"5b:3b:6c:51:90:49",-300,,,1',
                                  b'+BLESCAN:"5b:3b:6c:51:90:49",-87,0g,,1', b'+BLESCAN:"5b:3b:6c:51:90:49",-87,,,9',
                                  b'+BLESCAN:"5b:3b:6c:51:90:49",-87,,1', b"+BLESCAN:\xff"])
def test_a_malformed_report_is_a_counted_drop(line: bytes) -> None:
    decoder = EspAtDecoder()
    out = decoder.feed(line + b"\r\n")
    assert [i.kind for i in out] == ["drop"] and decoder.counters["drop.scan"] == 1
    assert parse_scan(line).kind == "drop"


def test_an_overlong_line_is_dropped_and_the_next_survives() -> None:
    decoder = EspAtDecoder()
    out = decoder.feed(b"x" * 2000) + decoder.feed(b"yyy\r\nOK\r\n")
    assert [i.kind for i in out] == ["drop", "final"] and decoder.counters["drop.oversize"] == 1


near_limit_lines = st.lists(st.tuples(
    st.integers(MAX_LINE - 2, MAX_LINE + 2), st.sampled_from([b"x", b"+BLEINIT:", b"\r"]),
    st.sampled_from([b"", b"\r", b"\r\r"]), st.sampled_from([b"\r\n", b"\n", b"\r\r\n", b"\r" * 5 + b"\n", b"\r"])),
    min_size=1, max_size=4).map(lambda ls: b"".join(lead + (head + b"y" * n)[:n] + end for n, head, lead, end in ls))


@given(near_limit_lines, st.lists(st.integers(1, 900), min_size=1, max_size=5))
def test_lines_at_and_around_the_limit_decode_the_same_in_any_chunking(data: bytes, sizes: list[int]) -> None:
    """Before: a 700-byte line + CR LF decoded whole but was dropped as oversize in small chunks
    (the held tail counted its CR)."""
    whole, cut = EspAtDecoder(), EspAtDecoder()
    out = whole.feed(data)
    assert [i for piece in chunked(data, sizes) for i in cut.feed(piece)] == out
    assert cut.counters == whole.counters and len(cut._rest) <= MAX_LINE + 1


def test_a_line_of_exactly_the_limit_survives_small_chunks() -> None:
    line = b"+BLEINIT:" + b"1" * (MAX_LINE - 9)
    decoder = EspAtDecoder()
    out = [i for k in range(len(line) + 2) for i in decoder.feed((line + b"\r\n")[k : k + 1])]
    assert [i.kind for i in out] == ["info"]


def test_a_flood_of_crs_is_held_bounded() -> None:
    decoder = EspAtDecoder()
    for _ in range(100):
        decoder.feed(b"OK" + b"\r" * 10_000)
    assert len(decoder._rest) <= MAX_LINE + 1


def run(fw: EspAtFirmware, *commands: str) -> list:
    """Each command after the previous one's answer, as ESP-AT requires (else ``busy p...``)."""
    out = []
    for command in commands:
        fw.receive(command.encode() + b"\r\n")
        out += [i for i in EspAtDecoder().feed(fw.read()) if i.kind != "event"]
    return out


def test_a_command_before_the_previous_answer_gets_busy() -> None:
    """"all commands are executed serially ... Otherwise, you will receive busy p..." (ESP-AT,
    Get Started, What is ESP-AT; FAQ "Why does AT return busy p...?")."""
    fw = EspAtFirmware()
    fw.read()
    fw.receive(b"AT\r\nAT+BLEINIT=1\r\n")
    events = [getattr(i, "what", i.kind) for i in EspAtDecoder().feed(fw.read())]
    assert "busy p..." in events and fw.role == 0


@pytest.mark.parametrize(("version", "scan", "reported"), [
    ("3.2", 'AT+BLESCAN=1,0,1,"ac:00:00"', set()),  # prefixes are documented on master only: whole MACs
    ("master", 'AT+BLESCAN=1,0,1,"ac:00:00"', {"AC0000000001", "AC0000000002"}),
    ("master", 'AT+BLESCAN=1,0,2,"be"', {"AC0000000002"}),
    ("master", 'AT+BLESCAN=1,0,3,"feaa"', {"AC0000000001"}),
    ("master", "AT+BLESCAN=1,0,4,-70", {"AC0000000001"}),
    ("master", 'AT+BLESCAN=1,0,1,"ac:00:00",1', {"AC0000000001", "AC0000000002"}),
    ("3.2", "AT+BLESCAN=1,0,4,-70", None),
])
def test_espressif_example_filters_per_version(version: str, scan: str, reported: set[str] | None) -> None:
    """The filters of the BLE AT Commands page, per documented version (esp-at's docs at each release tag)."""
    fw = EspAtFirmware(version)
    assert run(fw, "AT+BLEINIT=1", "AT+BLESCANPARAM=0,0,0,160,160") == [Final(True), Final(True)]
    answer = run(fw, scan)
    if reported is None:
        assert answer == [Final(False)]
        return
    assert answer == [Final(True)]
    eddystone = bytes.fromhex("0303aafe")
    named = bytes.fromhex("0309") + b"be"
    fw.on_advertisement(1_000, 37, "AC0000000001", -60.0, eddystone)
    fw.on_advertisement(2_000, 37, "AC0000000002", -80.0, named)
    fw.on_advertisement(4_000, 37, "AC0000000001", -60.0, eddystone)  # a duplicate
    got = [i.address for i in EspAtDecoder().feed(fw.read()) if i.kind == "scan_report"]
    assert set(got) == reported
    if scan.endswith(",1"):
        assert len(got) == len(reported)  # the duplicate check


def test_dual_role_from_5_0() -> None:
    assert run(EspAtFirmware("3.2"), "AT+BLEINIT=3") == [Final(False)]
    fw = EspAtFirmware("5.0")
    assert run(fw, "AT+BLEINIT=3", "AT+BLESCANPARAM=0,0,0,160,80", "AT+BLESCAN=1") == [Final(True)] * 3


def test_scan_defaults_and_blescandone_per_version() -> None:
    assert (EspAtFirmware("master").interval, EspAtFirmware("master").window) == (0x140, 0x30)  # ESP32
    fw = EspAtFirmware("2.4")
    run(fw, "AT+BLEINIT=1", "AT+BLESCAN=1,1")
    fw.tick(2_000_000)
    assert not any(getattr(i, "what", "") == "blescandone" for i in EspAtDecoder().feed(fw.read()))


def test_firmware_answers_as_documented() -> None:
    fw = EspAtFirmware()
    assert run(fw, "AT+BLESCAN=1") == [Final(False)]  # not initialised
    assert run(fw, "AT+BLEINIT=1", "AT+BLEINIT?") == [Final(True), Info("BLEINIT", "1"), Final(True)]
    assert run(fw, "AT+BLEINIT=2") == [Final(False)]  # the role cannot change without AT+RST
    assert run(fw, "AT+BLESCANPARAM=0,0,0,50,100") == [Final(False)]  # window > interval
    assert run(fw, "AT+BLESCANPARAM=0,0,0,3,3") == [Final(False)]  # below 2.5 ms
    assert run(fw, "AT+BLESCANPARAM=1,0,0,160,80", "AT+BLESCANPARAM?") == [
        Final(True), Info("BLESCANPARAM", "1,0,0,160,80"), Final(True)]
    assert run(fw, "AT+BOGUS") == [Final(False)]


def test_firmware_scans_in_its_window_with_its_filter_and_duration() -> None:
    fw = EspAtFirmware()
    run(fw, "AT+BLEINIT=1", "AT+BLESCANPARAM=0,0,0,160,80", 'AT+BLESCAN=1,2,1,"ac:00:00:00:00:01"')
    fw.on_advertisement(1_000, 37, "AC0000000001", -60.4, b"")  # heard
    fw.on_advertisement(2_000, 37, "AC0000000002", -60.0, b"")  # filtered out
    fw.on_advertisement(60_000, 37, "AC0000000001", -60.0, b"")  # outside the 50 ms window
    fw.on_advertisement(101_000, 37, "AC0000000001", -60.0, b"")  # interval 2 listens on 38
    fw.on_advertisement(201_000, 39, "AC0000000001", -99.0, b"")  # below sensitivity
    fw.tick(2_000_000)
    out = EspAtDecoder().feed(fw.read())
    assert [i for i in out if i.kind == "scan_report"] == [ScanReport("AC0000000001", -60, b"", b"", 0)]
    assert out[-1].kind == "event" and out[-1].what == "blescandone"
    assert {k: fw.counters[k] for k in ("filtered", "duty_cycle", "wrong_channel", "below_sensitivity")} == dict.fromkeys(
        ("filtered", "duty_cycle", "wrong_channel", "below_sensitivity"), 1)


def test_reset_answers_ok_then_reboots_to_defaults() -> None:
    fw = EspAtFirmware()
    run(fw, "AT+BLEINIT=1")
    fw.receive(b"AT+RST\r\n")
    kinds = [(i.kind, getattr(i, "what", None)) for i in EspAtDecoder().feed(fw.read())]
    assert kinds == [("event", "echo"), ("final", None), ("event", "ready")] and fw.role == 0


def test_port_spec_settings_reach_the_scan_commands() -> None:
    spec = portspec.parse("esp-at:/dev/ttyUSB0,baud=115200,active=yes,interval=50,window=25,adname=Beacon-1")
    setup = esp_at_setup(spec, EspAtSetup())
    assert setup.commands() == ["AT+BLESCANPARAM=1,0,0,80,40", 'AT+BLESCAN=1,0,2,"Beacon-1"']
    with pytest.raises(portspec.PortSpecError, match="interval"):
        portspec.parse("esp-at:/dev/ttyUSB0,interval=1")


async def test_s3_homes_on_esp_at_readings_and_the_capture_replays_them_exactly(tmp_path: Path) -> None:
    live = await s3_live(tmp_path, "esp-at", "esp-at")
    assert live["outcome"].arrived and live["error"] < 1.0
    assert live["sensor"].counters["setups"] == 1 and len(live["readings"]) > 50
    fw = live["emulator"].device("ble").firmware
    assert fw.counters["reported"] >= len(live["readings"]) and fw.counters["errors"] == 0
    replayed = await s3_replay(tmp_path, live, "esp-at")
    assert replayed["readings"] == live["readings"]
    assert replayed["log"] == live["log"]


@pytest.mark.slow
def test_demo_runs_s3_on_an_esp_at_board(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "rfhoming", "demo", "--scenario", "s3-arena", "--receiver", "esp-at",
                           "--radio", "ideal", "--json", "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["success"] and "esp-at" in summary["links"]


class _Wire:
    """The driver's port wired straight to a firmware model (no pty): what it writes, in order."""

    name = "esp-at-test"

    def __init__(self, fw: EspAtFirmware) -> None:
        self.fw, self.sent = fw, []
        self.counters = {"bytes_in": 0}

    def write(self, data: bytes) -> None:
        self.sent.append(data.decode().strip())
        self.fw.receive(data)


async def _set_up(fw: EspAtFirmware) -> tuple[EspAtDriver, _Wire]:
    import asyncio

    wire = _Wire(fw)
    driver = EspAtDriver(wire)  # type: ignore[arg-type]

    async def pump() -> None:
        while True:
            driver.on_chunk(fw.read(), 0.0)
            await asyncio.sleep(0.001)

    task = asyncio.create_task(pump())
    try:
        async with asyncio.timeout(10):
            await driver._set_up()
    finally:
        task.cancel()
    return driver, wire


async def test_driver_stops_an_earlier_scan_before_its_parameters() -> None:
    """A board still scanning from an earlier run gets AT+BLESCAN=0 first: its scan may still run from an earlier run."""
    fw = EspAtFirmware()
    run(fw, "AT+BLEINIT=1", "AT+BLESCAN=1")
    _, wire = await _set_up(fw)
    assert wire.sent.index("AT+BLESCAN=0") < next(i for i, c in enumerate(wire.sent) if c.startswith("AT+BLESCANPARAM"))


async def test_driver_keeps_a_dual_role() -> None:
    fw = EspAtFirmware("5.0")
    run(fw, "AT+BLEINIT=3")
    driver, wire = await _set_up(fw)
    assert "AT+BLEINIT=0" not in wire.sent and fw.role == 3 and fw.scanning and driver.state == "streaming"
