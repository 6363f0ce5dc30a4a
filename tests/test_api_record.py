"""The Python API records, carries raw bytes and reads streams the caller opened.

Checked with programs rfhoming did not write: tshark reads the API's capture (its own pcapng
reader; every item's raw bytes are in the inbound packets it shows, in order) and pyserial
opens the streams (``loop://`` and the emulator's pty) that :class:`rfhoming.Reader` decodes.
``rfhoming replay`` decodes the capture again to the items the API yielded.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st
from strategies import chunked

import rfhoming
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.replay import load_capture
from rfhoming.protocol.espat import ScanReport, encode_scan
from rfhoming.protocol.frames import FrameDecoder, encode_frame
from rfhoming.protocol.h4 import H4Splitter
from rfhoming.protocol.uconnect import UConnectDecoder
from rfhoming.protocol.espat import EspAtDecoder
from rfhoming.reader import Framer, ReaderError

ROOT = Path(__file__).resolve().parent.parent
AOA_SESSION = ROOT / "tests" / "golden" / "xplr_aoa_session.raw"
RSS_STREAM = ROOT / "tests" / "golden" / "rss_node_stream.raw"


@pytest.fixture
def emulator(emulated):
    """``rfhoming emulate s0-open``: device name -> its pty path."""
    return emulated("s0-open", "--seed", "3").paths


def tshark_packets(path: Path) -> list[tuple[str, str, bytes]]:
    """(interface description, direction in/out, bytes) of every packet, as tshark reads them."""
    done = subprocess.run(["tshark", "-r", str(path), "-T", "json", "-x"], capture_output=True, text=True,
                          env={**os.environ, "HOME": str(path.parent)}, timeout=120)
    assert done.returncode == 0, done.stderr
    out = []
    for packet in json.loads(done.stdout):
        layers = packet["_source"]["layers"]
        frame = layers["frame"]
        direction = {"0x00000001": "in", "0x00000002": "out"}[frame["frame.packet_flags_tree"]["frame.packet_flags_direction"]]
        out.append((frame["frame.interface_id_tree"]["frame.interface_description"], direction,
                    bytes.fromhex(layers["frame_raw"][0])))
    return out


def in_order(raws: list[bytes], stream: bytes, shared: int = 0) -> bool:
    """Every raw is in ``stream``, each after the one before (``shared``: bytes two neighbours
    may share, the zero between two COBS frames)."""
    at = 0
    for raw in raws:
        found = stream.find(raw, at)
        if found < 0:
            return False
        at = found + len(raw) - shared
    return True


# -- 1. recording -------------------------------------------------------------------------
@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark is not installed (apt-get install tshark)")
@pytest.mark.slow
def test_open_records_what_rfhoming_capture_records(emulator, tmp_path: Path) -> None:
    api_file, cli_file = tmp_path / "api.pcapng", tmp_path / "cli.pcapng"
    with rfhoming.open(f"xplr-aoa:{emulator['aoa']}", f"base:{emulator['base']}", duration=3.0,
                       capture=api_file) as devices:
        got = list(devices)
    assert devices.recording is None  # closed with the stream, not left to the garbage collector
    interfaces, packets, torn = load_capture(api_file)
    assert torn == 0 and sum(map(len, packets.values())) > 10

    # the command line on the same devices, for what its file holds
    done = subprocess.run([sys.executable, "-m", "rfhoming", "capture", f"xplr-aoa:{emulator['aoa']}",
                           f"base:{emulator['base']}", "--duration", "3", "-o", str(cli_file)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    api, cli = tshark_packets(api_file), tshark_packets(cli_file)
    assert sorted({d for d, _, _ in api}) == sorted({d for d, _, _ in cli})  # protocol=, kind=, label=
    assert {d for d, _, _ in api} == {"protocol=uconnect kind=xplr-aoa label=aoa", "protocol=frames kind=base label=base"}
    cli_dialects = subprocess.run(["tshark", "-r", str(cli_file), "-T", "fields", "-e", "frame.comment"],
                                  capture_output=True, text=True, timeout=60).stdout.split()
    api_dialects = subprocess.run(["tshark", "-r", str(api_file), "-T", "fields", "-e", "frame.comment"],
                                  capture_output=True, text=True, timeout=60).stdout.split()
    assert [c for c in api_dialects if c.startswith("dialect=")] == [c for c in cli_dialects if c.startswith("dialect=")]
    assert any(c.startswith("dialect=") for c in api_dialects)
    assert {d for _, d, _ in api} == {"in", "out"}  # the set-up's commands are in it too

    # every item's raw bytes are in the inbound packets tshark shows, in order, per device
    for description, name in (("protocol=uconnect kind=xplr-aoa label=aoa", emulator["aoa"]),
                              ("protocol=frames kind=base label=base", emulator["base"])):
        inbound = b"".join(data for d, direction, data in api if d == description and direction == "in")
        raws = [g.raw for g in got if g.device == name]
        assert raws and in_order(raws, inbound, shared=1 if "frames" in description else 0), name

    # and `rfhoming replay` decodes the file to what the API yielded (a last chunk or two may
    # have reached the file after the stream ended)
    replayed = subprocess.run([sys.executable, "-m", "rfhoming", "replay", str(api_file), "--json"],
                              capture_output=True, text=True, timeout=120)
    assert replayed.returncode == 0, replayed.stderr
    lines = [json.loads(line) for line in replayed.stdout.splitlines()]
    for name in emulator.values():
        items = [line for line in lines if line.get("device") == name and line["kind"] not in ("counters", "echo", "info", "final")]
        ours = [g.to_dict() for g in got if g.device == name]
        assert ours and items[: len(ours)] == ours
        assert len(items) - len(ours) < 10


def test_leaving_the_loop_early_closes_the_capture(emulator, tmp_path: Path) -> None:
    """No duration: the stream runs until the program stops reading; a ``break`` out of a
    ``with`` block ends it and closes the file, whole."""
    path = tmp_path / "early.pcapng"
    with rfhoming.open(f"xplr-aoa:{emulator['aoa']}", kinds={"angle"}, capture=path) as devices:
        for n, _ in enumerate(devices):
            if n == 10:
                break
    assert devices.recording is None
    interfaces, packets, torn = load_capture(path)
    assert torn == 0 and len(UConnectDecoder().feed(b"".join(p.data for p in packets[0]))) > 10


def test_a_capture_writer_given_is_flushed_and_left_open(emulator, tmp_path: Path) -> None:
    writer = CaptureWriter(tmp_path / "mine.pcapng")
    with rfhoming.open(f"xplr-aoa:{emulator['aoa']}", kinds={"angle"}, duration=1.5, capture=writer) as devices:
        angles = list(devices)
    assert angles and writer.packets > 0 and not writer._file.closed
    writer.close()
    interfaces, packets, torn = load_capture(tmp_path / "mine.pcapng")
    assert torn == 0 and [i.name for i in interfaces] == [emulator["aoa"]]


# -- 2. raw bytes on every item --------------------------------------------------------------
@pytest.mark.slow
def test_every_item_carries_its_wire_bytes(emulator) -> None:
    from rfhoming.protocol.uconnect.encoder import Dialect, encode_angle_event

    got = list(rfhoming.read(f"xplr-aoa:{emulator['aoa']}", f"base:{emulator['base']}", duration=2.0))
    angles = [g for g in got if g.kind == "angle"]
    records = [g for g in got if g.device == emulator["base"]]
    assert angles and records and all(g.raw for g in got), [g for g in got if not g.raw][:3]
    dialect = Dialect("1.2")
    # +UUDF:...\r\n: the URC's line; the blank line the board sends before it is no item's. A line
    # is handed on at its \r: when the read ends there, its \n comes with the next read's bytes
    bad = [(g.raw, encode_angle_event(g.item, dialect)) for g in angles
           if g.raw.removesuffix(b"\n") != encode_angle_event(g.item, dialect)[2:].removesuffix(b"\n")]
    assert not bad, bad[:2]
    assert all(g.raw == encode_frame(g.item) for g in records)  # 00 | COBS | 00


CASES = {
    "uconnect": (AOA_SESSION.read_bytes(), UConnectDecoder, 0),
    "frames": (RSS_STREAM.read_bytes(), FrameDecoder, 1),
    "esp-at": (b"AT+BLESCAN=1\r\r\nOK\r\n" + encode_scan(ScanReport("C0FFEE000001", -61, b"\x02\x01\x06", b"", 0)) * 3
               + b"garbage\xff\r\n" + b"x" * 800 + b"\r\n+BLESCANDONE\r\n", EspAtDecoder, 0),
    "h4": (bytes.fromhex("040e0401030c00") + b"\x99\x98" + bytes.fromhex("043e0c0201000112345678abcd00c5"),
           H4Splitter, 0),
}


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(sorted(CASES)), st.lists(st.integers(1, 97), min_size=1, max_size=8))
def test_raw_bytes_do_not_depend_on_the_chunking(protocol: str, sizes: list[int]) -> None:
    """The framer gives the decoder's items for any chunking, each with bytes taken in order
    from the stream; a line or frame is cut the same whatever the chunking, except a CR LF
    whose LF arrives in the next read."""
    data, decoder, shared = CASES[protocol]
    reference = decoder()
    want = reference.feed(data) + (reference.flush() if hasattr(reference, "flush") else [])
    framer = Framer(protocol)
    pairs = [pair for piece in chunked(data, sizes) for pair in framer.feed(piece)] + framer.flush()
    assert [item for _, item in pairs] == want
    assert in_order([raw for raw, _ in pairs], data, shared)
    whole = Framer(protocol)
    one_read = whole.feed(data) + whole.flush()
    for (raw, item), (raw1, _) in zip(pairs, one_read):
        if not isinstance(item, tuple) or item.kind != "drop" or item.reason not in ("overlong", "oversize"):
            # (an overlong line's drop has the bytes held when it was dropped)
            assert raw.rstrip(b"\r\n") == raw1.rstrip(b"\r\n")


# -- 3. a reader over a stream the caller opened ----------------------------------------------
def test_reader_over_pyserial_loop() -> None:
    data = AOA_SESSION.read_bytes()
    port = serial.serial_for_url("loop://", timeout=1)
    writer = threading.Thread(target=lambda: [port.write(p) for p in chunked(data, [7, 64, 3])])
    writer.start()
    want = UConnectDecoder().feed(data)
    got = []
    for item in rfhoming.Reader(port, protocol="uconnect"):
        got.append(item)
        if len(got) == len(want):
            break
    writer.join()
    port.close()
    assert [g.item for g in got] == want and all(g.device == "loop://" for g in got)
    assert in_order([g.raw for g in got], data)


def test_reader_over_the_emulators_pty_after_the_callers_own_setup(emulator) -> None:
    """The Reader sends nothing: the caller enables the board's +UUDF stream itself."""
    with serial.Serial(emulator["aoa"], 115200, rtscts=True, timeout=5) as port:
        port.write(b"AT+UDFENABLE=1\r")
        got = []
        for item in rfhoming.Reader(port, protocol="xplr-aoa"):
            got.append(item)
            if item.kind == "startup":  # the board (re)started as the port opened: say it again
                port.write(b"AT+UDFENABLE=1\r")
            kinds = [g.kind for g in got]
            if "final" in kinds and kinds.count("angle") >= 20:
                break
    assert [g.raw for g in got if g.kind == "final"][0] == b"OK\r\n"  # its answer, which open() would hide
    assert [g.raw for g in got if g.kind == "echo"][0] == b"AT+UDFENABLE=1\r"
    assert all(g.raw.endswith(b"\r\n") or g.raw.endswith(b"\r") for g in got)
    assert all(g.raw.startswith(b"+UUDF:") for g in got if g.kind == "angle")


def test_reader_over_a_binary_file_and_a_socket() -> None:
    data = RSS_STREAM.read_bytes()
    decoder = FrameDecoder()
    want = decoder.feed(data) + decoder.flush()
    with open(RSS_STREAM, "rb") as f:
        from_file = list(rfhoming.Reader(f, protocol="frames"))
    assert [g.item for g in from_file] == want
    assert all(g.raw == encode_frame(g.item) for g in from_file if g.kind != "drop")
    assert from_file[0].device == str(RSS_STREAM)

    ours, theirs = socket.socketpair()
    threading.Thread(target=lambda: (ours.sendall(data), ours.close())).start()
    from_socket = list(rfhoming.Reader(theirs, protocol="rss-node", kinds={"antenna_set", "status"}))
    theirs.close()
    assert [g.item for g in from_socket] == [i for i in want if i.kind in ("antenna_set", "status")]


def test_reader_refuses_what_it_cannot_read(tmp_path: Path) -> None:
    text = tmp_path / "t.txt"
    text.write_text("OK\r\n")
    with open(text) as f, pytest.raises(ReaderError, match="binary mode"):
        rfhoming.Reader(f)
    with pytest.raises(ReaderError, match="not a byte stream"):
        rfhoming.Reader(open(RSS_STREAM, "rb"), protocol="ros2")
    with pytest.raises(rfhoming.Error, match="unknown protocol 'nmea'"):
        rfhoming.Reader(open(RSS_STREAM, "rb"), protocol="nmea")
    with pytest.raises(ReaderError, match="timeout=0"):
        rfhoming.Reader(serial.serial_for_url("loop://", timeout=0))


def test_items_from_rfhoming_serve_come_without_device_bytes() -> None:
    """A serve client's items are the server's JSON, not the device's bytes: raw is empty,
    and tracking it does not fail (serve is no kind of the device table)."""
    from rfhoming.host.ports import HostPort
    from rfhoming.host.drivers.serve_client import ServeDriver
    from rfhoming.reader import track

    driver = ServeDriver(HostPort("socket://127.0.0.1:9", name="serve"))
    tracker = track(driver)
    seen = []
    driver.listeners.append(lambda device, t, item: seen.append((item.kind, tracker.current)))
    driver.on_chunk(b'{"kind": "final", "device": "aoa", "t": 1.0, "ok": true}\n', 1.0)
    assert seen == [("final", b"")]
