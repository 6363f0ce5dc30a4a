"""Bluetooth HCI controllers through bumble: the H4 splitter, AD filters, the controller model
(bumble's controller plus the radio), the driver over a pty and over a bumble transport, and
closed-loop S3 trilateration on HCI advertising reports (live and replayed)."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

pytest.importorskip("bumble", reason="the hci receiver needs bumble: pip install 'rfhoming[hci]'")

from bumble import hci  # noqa: E402
from receivers import s3_live, s3_replay  # noqa: E402
from strategies import chunked  # noqa: E402

from rfhoming.emulator.runtime import Emulator  # noqa: E402
from rfhoming.emulator.scenario import load  # noqa: E402
from rfhoming.firmware.hci_controller import HciControllerFirmware  # noqa: E402
from rfhoming.host import portspec  # noqa: E402
from rfhoming.host.drivers.hci import BumbleTransportPort, HciDriver, HciSetup, open_port  # noqa: E402
from rfhoming.host.drivers.hci import setup_from_spec as hci_setup  # noqa: E402
from rfhoming.host.drivers.rss import BleRssi  # noqa: E402
from rfhoming.protocol import ad, h4  # noqa: E402
from rfhoming.protocol.h4 import H4Splitter  # noqa: E402

EDDYSTONE_AD = bytes.fromhex("0201060303aafe")
h4_packets = st.one_of(
    st.binary(max_size=255).flatmap(lambda p: st.sampled_from([0x0C03, 0x2041, 0xFC00]).map(
        lambda op: b"\x01" + op.to_bytes(2, "little") + bytes([len(p)]) + p)),
    st.binary(min_size=1, max_size=255).map(lambda p: b"\x04\x3e" + bytes([len(p)]) + p),
    st.binary(max_size=600).map(lambda p: b"\x02\x01\x00" + len(p).to_bytes(2, "little") + p),
)


@given(st.lists(h4_packets, max_size=12), st.lists(st.integers(1, 50), max_size=5))
def test_h4_packets_come_out_whole_in_any_chunking(packets: list[bytes], sizes: list[int]) -> None:
    splitter, out = H4Splitter(), []
    for piece in chunked(b"".join(packets), sizes):
        out += splitter.feed(piece)
    assert out == packets


def test_h4_junk_is_a_counted_drop_and_the_next_packet_survives() -> None:
    splitter = H4Splitter()
    out = splitter.feed(b"\xff\x00\x99" + b"\x04\x0e\x04\x01\x03\x0c\x00")
    assert [getattr(i, "reason", None) for i in out] == ["indicator", None] and out[1] == b"\x04\x0e\x04\x01\x03\x0c\x00"
    assert splitter.counters["drop.indicator"] == 1


# Packets of a host's stream in which no byte but the first is an H4 indicator (1..5), so the
# only plausible packet starts are the real ones and junk decides alone what is lost.
MAX_DATA = 64  # a small bound, so that examples are short
_body = st.binary(min_size=6, max_size=255).map(lambda b: bytes(max(6, x) for x in b))
clean_to_host = st.one_of(
    _body.map(lambda p: b"\x04\x3e" + bytes([len(p)]) + p),
    _body.map(lambda p: b"\x04\x0e" + bytes([len(p)]) + p),
    _body.map(lambda p: b"\x02\x40\x20" + len(p[:MAX_DATA]).to_bytes(2, "little") + p[:MAX_DATA]),
)
HOLD = max(1 + 2 + 255, 1 + 4 + MAX_DATA)  # the most one plausible header can claim
junk_bytes = st.lists(st.one_of(  # random bytes, indicators with random headers, torn packets
    st.binary(min_size=1, max_size=8),
    st.tuples(st.sampled_from([1, 2, 3, 4, 5]), st.binary(min_size=4, max_size=4)).map(lambda t: bytes([t[0]]) + t[1]),
    st.tuples(clean_to_host, st.integers(1, 300)).map(lambda t: t[0][t[1] % len(t[0]):])), min_size=1, max_size=6).map(b"".join)


@given(st.lists(clean_to_host, max_size=4), junk_bytes, st.lists(clean_to_host, max_size=30),
       st.lists(st.integers(1, 300), max_size=4))
def test_h4_valid_packets_around_junk_are_recovered(before: list[bytes], junk: bytes, after: list[bytes],
                                                    sizes: list[int]) -> None:
    """Junk (a stray byte, a stream joined mid-packet) costs at most HOLD bytes after it: a
    header with a bogus length is bounded, never a wait for 65,539 bytes."""
    data = b"".join(before) + junk + b"".join(after)
    splitter, out = H4Splitter(h4.TO_HOST, max_data=MAX_DATA), []
    for piece in chunked(data, sizes):
        out += splitter.feed(piece)
    packets = [i for i in out if isinstance(i, bytes)]
    assert packets[: len(before)] == before
    start, safe = 0, []
    for p in after:
        if start >= HOLD:
            safe.append(p)
        start += len(p)
    assert packets[len(packets) - len(safe):] == safe
    assert splitter.pending <= HOLD + 5 + h4.MAX_JUNK - 1  # a claimed packet, the next header, junk


# Packets whose payloads may hold anything, false headers included (as advertising reports do).
any_to_host = st.one_of(
    st.binary(min_size=1, max_size=255).map(lambda p: b"\x04\x3e" + bytes([len(p)]) + p),
    st.binary(min_size=3, max_size=255).map(lambda p: b"\x04\x0e" + bytes([len(p)]) + p),
    st.binary(max_size=MAX_DATA).map(lambda p: b"\x02\x40\x20" + len(p).to_bytes(2, "little") + p),
)


@pytest.mark.slow
@given(st.lists(any_to_host, max_size=3), st.integers(6, 0x59), st.integers(6, 255),
       st.lists(any_to_host, min_size=2, max_size=20), st.lists(st.integers(1, 300), max_size=4))
def test_h4_after_junk_a_header_is_taken_only_when_the_next_one_confirms_it(
        before: list[bytes], code: int, length: int, after: list[bytes], sizes: list[int]) -> None:
    """The fuzzed loss (58 in 10^6 streams): after junk, an event header with a bogus length
    was trusted, landed the splitter inside a packet, and headers in payloads kept it misframed
    past the bound. Now, while hunting, a header counts only if the bytes after the packet it
    claims begin a header too; so when they do not, nothing after the junk is lost, whatever
    the payloads hold."""
    bogus = bytes([h4.EVENT, code, length])
    tail = b"".join(after)
    end = len(bogus) + length  # where the bogus event claims to end, in bogus + tail
    assume(end < len(bogus) + len(tail))
    landing = (bogus + tail)[end:]
    kind = landing[0]
    size = h4.HEADERS[kind][0] if kind in h4.TO_HOST else 0
    assume(not size or len(landing) <= size or not h4.plausible(kind, landing[1 : 1 + size], MAX_DATA))
    data = b"".join(before) + b"\x00" + bogus + tail  # 0x00 starts no packet: the splitter hunts
    splitter, out = H4Splitter(h4.TO_HOST, max_data=MAX_DATA), []
    for piece in chunked(data, sizes):
        out += splitter.feed(piece)
    assert [i for i in out if isinstance(i, bytes)] == before + after


def test_h4_the_resets_the_spec_resynchronises_on_come_out_at_once_after_junk() -> None:
    """Vol 4 Part A's recovery: a host resynchronises on HCI_Reset's Command Complete, a
    controller on HCI_Reset; neither waits for a next packet to confirm it."""
    complete, reset = b"\x04\x0e\x04\x01\x03\x0c\x00", b"\x01\x03\x0c\x00"
    assert H4Splitter(h4.TO_HOST).feed(b"\x00" + complete)[-1] == complete
    assert H4Splitter(h4.TO_CONTROLLER).feed(b"\x00" + reset)[-1] == reset
    other = b"\x04\x0e\x04\x01\x05\x10\x00"  # another Command Complete waits for the next header
    assert [i for i in H4Splitter(h4.TO_HOST).feed(b"\x00" + other) if isinstance(i, bytes)] == []


def test_h4_a_bogus_data_length_holds_no_more_than_the_bound() -> None:
    """The fuzzed case: 0x02 then a header claiming 65,535 bytes; the event after it survives."""
    complete = b"\x04\x0e\x04\x01\x03\x0c\x00"
    out = H4Splitter(h4.TO_HOST).feed(b"\x02\x01\x00\xff\xff" + complete)
    assert out[-1] == complete and out[0].kind == "drop"


@given(st.binary(max_size=3000), st.lists(st.integers(1, 400), min_size=1, max_size=5))
def test_h4_any_bytes_split_the_same_in_any_chunking(data: bytes, sizes: list[int]) -> None:
    whole, cut = H4Splitter(h4.TO_HOST), H4Splitter(h4.TO_HOST)
    out = whole.feed(data)
    out_cut = [i for piece in chunked(data, sizes) for i in cut.feed(piece)]
    assert out == out_cut and whole.counters == cut.counters and whole.pending == cut.pending


def _driver() -> HciDriver:
    from rfhoming.host.ports import HostPort

    return HciDriver(HostPort("/dev/null", name="hci"))


ADV_REPORT = bytes(hci.HCI_LE_Advertising_Report_Event([hci.HCI_LE_Advertising_Report_Event.Report(
    event_type=hci.HCI_LE_Advertising_Report_Event.EventType.ADV_NONCONN_IND, address_type=0,
    address=hci.Address("AC:00:00:00:00:01"), data=EDDYSTONE_AD, rssi=-60)]))


@pytest.mark.parametrize("packet", [b"\x02\x01\x00\x02\x00ab", b"\x03\x01\x00\x02ab",
                                    b"\x05\x01\x00\x02\x00ab", b"\x05\x01\x00\x08\x00abcdefgh",
                                    b"\x04\x3e\x03\x02\x05\x00"])
def test_a_data_or_malformed_packet_is_a_counted_drop_and_the_receiver_goes_on(packet: bytes) -> None:
    """Before: bumble's ACL/SCO/ISO packets have no ``name``; the AttributeError ended the
    driver's task for good."""
    driver, seen = _driver(), []
    driver.listeners.append(lambda device, t, item: seen.append(item))
    driver.on_chunk(packet + ADV_REPORT, 1.0)
    assert driver.counters["bad_packets"] == 1 and [i.kind for i in seen] == ["drop", "advertisement"]
    assert driver.out.get_nowait() == BleRssi(1.0, 0, "AC0000000001", -60)


def test_an_exception_handling_one_packet_is_counted_and_the_next_is_handled() -> None:
    driver, calls = _driver(), []

    def listener(device: str, t: float, item: object) -> None:
        calls.append(item)
        if len(calls) == 1:
            raise RuntimeError("a listener's bug")

    driver.listeners.append(listener)
    driver.on_chunk(ADV_REPORT + ADV_REPORT, 2.0)
    assert driver.counters["drop.error"] == 1 and driver.counters["reports"] == 2
    assert driver.out.get_nowait() == BleRssi(2.0, 0, "AC0000000001", -60)


IBEACON = bytes.fromhex("0201061aff4c000215") + bytes(16) + bytes.fromhex("00010002c5")
EDDYSTONE = EDDYSTONE_AD
NAMED = bytes.fromhex("020106") + b"\x07\x09Dock-1"


def test_advertising_content_filters() -> None:
    assert ad.is_ibeacon(IBEACON) and not ad.is_ibeacon(EDDYSTONE) and not ad.is_ibeacon(NAMED)
    assert ad.is_eddystone(EDDYSTONE) and not ad.is_eddystone(IBEACON)
    assert ad.local_name(NAMED) == "Dock-1" and ad.local_name(IBEACON) is None
    assert ad.local_name(b"\x09\x09trunc") is None  # a structure longer than the data is ignored
    setup = HciSetup(addresses=frozenset({"AC0000000001"}), content="eddystone")
    assert setup.keeps("AC0000000001", EDDYSTONE) and not setup.keeps("AC0000000002", EDDYSTONE)
    assert not setup.keeps("AC0000000001", IBEACON)


def commands(*cmds: hci.HCI_Command) -> bytes:
    return b"".join(bytes(c) for c in cmds)


def events(fw: HciControllerFirmware) -> list:
    return [hci.HCI_Packet.from_bytes(p) for p in H4Splitter().feed(fw.read())]


MASKS = (hci.HCI_Set_Event_Mask_Command(event_mask=((1 << 61) | 0x1FFFFFFFFFFF).to_bytes(8, "little")),
         hci.HCI_LE_Set_Event_Mask_Command(le_event_mask=(0x1002).to_bytes(8, "little")))
LEGACY = (hci.HCI_LE_Set_Scan_Parameters_Command(le_scan_type=0, le_scan_interval=160, le_scan_window=80,
                                                 own_address_type=0, scanning_filter_policy=0),
          hci.HCI_LE_Set_Scan_Enable_Command(le_scan_enable=1, filter_duplicates=1))


async def test_controller_model_scans_as_the_host_set_it() -> None:
    fw = HciControllerFirmware()
    fw.receive(commands(hci.HCI_Reset_Command(), *LEGACY))  # no event masks yet
    fw.on_advertisement(1_000, 37, "AC:00:00:00:00:01", -60.4, EDDYSTONE)
    assert fw.counters["masked"] == 1
    fw.receive(commands(*MASKS))
    fw.on_advertisement(2_000, 37, "AC:00:00:00:00:01", -60.4, EDDYSTONE)  # heard
    fw.on_advertisement(3_000, 37, "AC:00:00:00:00:01", -60.4, EDDYSTONE)  # a duplicate
    fw.on_advertisement(60_000, 37, "AC:00:00:00:00:02", -60.0, EDDYSTONE)  # outside the 50 ms window
    fw.on_advertisement(101_000, 37, "AC:00:00:00:00:02", -60.0, EDDYSTONE)  # interval 2 listens on 38
    out = events(fw)
    reports = [r for e in out if isinstance(e, hci.HCI_LE_Advertising_Report_Event) for r in e.reports]
    assert [(r.rssi, bytes(r.data)) for r in reports] == [(-60, EDDYSTONE)]
    assert all(isinstance(e, (hci.HCI_Command_Complete_Event, hci.HCI_LE_Advertising_Report_Event)) for e in out)
    assert {k: fw.counters[k] for k in ("duplicate", "duty_cycle", "wrong_channel", "reported")} == dict.fromkeys(
        ("duplicate", "duty_cycle", "wrong_channel", "reported"), 1)
    fw.receive(commands(hci.HCI_Reset_Command()))  # a reset stops scanning
    fw.on_advertisement(202_000, 39, "AC:00:00:00:00:01", -60.0, EDDYSTONE)
    assert fw.counters["duty_cycle"] == 2


async def test_controller_model_rejects_a_window_longer_than_the_interval() -> None:
    fw = HciControllerFirmware()
    fw.receive(commands(hci.HCI_LE_Set_Scan_Parameters_Command(
        le_scan_type=0, le_scan_interval=80, le_scan_window=160, own_address_type=0, scanning_filter_policy=0)))
    (complete,) = events(fw)
    assert complete.return_parameters.status == hci.HCI_ErrorCode.INVALID_COMMAND_PARAMETERS_ERROR


def test_port_specs_name_bumble_transports_and_scan_settings() -> None:
    spec = portspec.parse("hci:serial:/dev/ttyACM0,1000000,active=yes,interval=60,window=30,extended=off,"
                          "mac=ac:00:00:00:00:01,content=ibeacon")
    assert spec.where == "serial:/dev/ttyACM0,1000000"
    setup = hci_setup(spec)
    assert (setup.active, setup.interval_ms, setup.window_ms, setup.extended) == (True, 60.0, 30.0, "off")
    assert setup.addresses == {"AC0000000001"} and setup.content == "ibeacon"
    port = open_port(spec.where)
    assert (port.spec, port.baud) == ("/dev/ttyACM0", 1_000_000)
    assert open_port("serial:/dev/ttyACM0,115200,rtscts").rtscts
    with pytest.raises(ValueError, match="SPEED and rtscts"):
        open_port("serial:/dev/ttyACM0,fast")
    assert open_port("tcp-client:127.0.0.1:9000").spec == "socket://127.0.0.1:9000"
    assert isinstance(open_port("usb:0"), BumbleTransportPort)
    with pytest.raises(portspec.PortSpecError, match="extended"):
        portspec.parse("hci:usb:0,extended=maybe")


async def readings_for(driver: HciDriver, count: int) -> list[BleRssi]:
    task = asyncio.create_task(driver.run())
    got: list[BleRssi] = []
    try:
        while len(got) < count:
            got.append(await asyncio.wait_for(driver.out.get(), 10))
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    return got


async def test_legacy_scanning_through_a_bumble_tcp_transport(tmp_path: Path) -> None:
    em = Emulator(load("s3-arena", seed=2, receiver="hci"), transport="tcp", seed=2, speed=math.inf)
    endpoints = {e["device"]: e for e in await em.start()}
    world = asyncio.create_task(em.run(30.0))
    try:
        where = "tcp-client:" + endpoints["ble"]["url"].removeprefix("socket://")
        driver = HciDriver(BumbleTransportPort(where), HciSetup(extended="off"))
        got = await readings_for(driver, 20)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    assert driver.extended is False and not em.device("ble").firmware.controller.extended
    anchors = {t.id for t in em.world.targets}
    assert {r.address for r in got} <= anchors and all(-100 <= r.rssi_dbm <= 20 for r in got)
    assert endpoints["ble"]["kind"] == "hci" and endpoints["ble"]["protocol"] == "h4"


async def test_s3_homes_on_hci_reports_and_the_capture_replays_them_exactly(tmp_path: Path) -> None:
    live = await s3_live(tmp_path, "hci", "hci")
    assert live["outcome"].arrived and live["error"] < 1.0
    assert live["sensor"].extended is True and live["sensor"].counters["setups"] == 1
    assert len(live["readings"]) > 50
    replayed = await s3_replay(tmp_path, live, "hci")
    assert replayed["readings"] == live["readings"]
    assert replayed["log"] == live["log"]


@pytest.mark.slow
def test_demo_runs_s3_on_an_hci_controller(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "rfhoming", "demo", "--scenario", "s3-arena", "--receiver", "hci",
                           "--radio", "ideal", "--json", "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["success"] and "hci" in summary["links"]


def test_hci_items_print_as_json_lines() -> None:
    """The items the driver shows ``listen``/``replay``: plain JSON, bytes as hex."""
    from rfhoming.host.drivers.hci import Advertisement, HciPacket
    from rfhoming.protocol.jsonable import as_dict

    rows = [as_dict(Advertisement("AC0000000001", 0, -61, True, b"\x02\x01\x06")),
            as_dict(HciPacket("HCI_COMMAND_COMPLETE_EVENT", b"\x04\x0e\x04\x01\x03\x0c\x00"))]
    assert rows == [{"kind": "advertisement", "address": "AC0000000001", "address_type": 0, "rssi_dbm": -61,
                     "extended": True, "data": "020106"},
                    {"kind": "hci", "name": "HCI_COMMAND_COMPLETE_EVENT", "raw": "040e0401030c00"}]


EXTENDED = (hci.HCI_LE_Set_Extended_Scan_Parameters_Command(
    own_address_type=0, scanning_filter_policy=0, scanning_phys=1, scan_types=[0], scan_intervals=[160],
    scan_windows=[160]),
    hci.HCI_LE_Set_Extended_Scan_Enable_Command(enable=1, filter_duplicates=0, duration=0, period=0))


class _NoPort:
    name = "hci-test"
    counters = {"bytes_in": 0}


@pytest.mark.parametrize("truncate", [False, True])
async def test_fragmented_extended_reports_are_reassembled(truncate: bool) -> None:
    """One advertisement in several extended-report fragments is one reading, and a name in a
    later fragment still passes adname= (data status, Core v5.4 Vol 4 Part E 7.7.65.13)."""
    name_last = bytes.fromhex("020106") + bytes.fromhex("0303aafe") + bytes([9, 0x09]) + b"Beacon-1"
    fw = HciControllerFirmware(fragment_bytes=8, truncate=truncate)
    fw.receive(commands(hci.HCI_Reset_Command(), *MASKS, *EXTENDED))
    fw.read()
    fw.on_advertisement(1_000, 37, "AC:00:00:00:00:01", -60.0, name_last)
    fw.on_advertisement(2_000, 37, "AC:00:00:00:00:01", -61.0, name_last)
    wire = fw.read()
    assert sum(len(e.reports) for e in (hci.HCI_Packet.from_bytes(p) for p in H4Splitter().feed(wire))) == 6 - 2 * truncate
    driver = HciDriver(_NoPort(), HciSetup(name="Beacon-1"))  # type: ignore[arg-type]
    shown: list = []
    driver.listeners.append(lambda _port, _t, item: shown.append(item))
    driver.on_chunk(wire, 0.0)
    advertisements = [i for i in shown if getattr(i, "kind", "") == "advertisement"]
    assert [a.data for a in advertisements] == [name_last[:16] if truncate else name_last] * 2
    assert len(driver.out) == (0 if truncate else 2)  # a truncated report lost its name
    assert driver.counters["truncated"] == 2 * truncate and driver.counters["fragments"] == 4 - 2 * truncate
